//! Camera-to-panel registration for `calib psfs` (docs/calibration.md §2):
//! a homography from panel pixels to camera pixels, first from the panel's
//! edges in a flat field, then from the checkerboard's inner corners, each
//! found as the saddle of a quadratic fitted around its predicted place.

use crate::calib_capture::Frame;

/// x' = (h0 x + h1 y + h2) / (h6 x + h7 y + 1), y' likewise with h3..h5.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Homography(pub [f64; 8]);

impl Homography {
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let h = &self.0;
        let w = h[6] * x + h[7] * y + 1.0;
        (
            (h[0] * x + h[1] * y + h[2]) / w,
            (h[3] * x + h[4] * y + h[5]) / w,
        )
    }

    /// The least-squares homography (algebraic error, Hartley's
    /// normalisation) taking each `from` to its `to`; None under 4 points
    /// or for points in a degenerate layout.
    pub fn fit(from: &[(f64, f64)], to: &[(f64, f64)]) -> Option<Self> {
        if from.len() < 4 || from.len() != to.len() {
            return None;
        }
        let (nf, tf) = normaliser(from);
        let (nt, tt) = normaliser(to);
        let mut ata = [[0.0f64; 8]; 8];
        let mut atb = [0.0f64; 8];
        for (&(x, y), &(u, v)) in from.iter().zip(to) {
            let (x, y) = nf(x, y);
            let (u, v) = nt(u, v);
            for (row, rhs) in [
                ([x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y], u),
                ([0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y], v),
            ] {
                for i in 0..8 {
                    atb[i] += row[i] * rhs;
                    for j in 0..8 {
                        ata[i][j] += row[i] * row[j];
                    }
                }
            }
        }
        let h = solve8(ata, atb)?;
        // Undo the normalisations: H = Tt⁻¹ · Hn · Tf.
        let hn = [[h[0], h[1], h[2]], [h[3], h[4], h[5]], [h[6], h[7], 1.0]];
        let (sf, mfx, mfy) = tf;
        let (st, mtx, mty) = tt;
        let tfm = [[sf, 0.0, -sf * mfx], [0.0, sf, -sf * mfy], [0.0, 0.0, 1.0]];
        let tti = [[1.0 / st, 0.0, mtx], [0.0, 1.0 / st, mty], [0.0, 0.0, 1.0]];
        let m = mul(&tti, &mul(&hn, &tfm));
        let s = m[2][2];
        if s.abs() < 1e-15 || !s.is_finite() {
            return None;
        }
        Some(Self([
            m[0][0] / s,
            m[0][1] / s,
            m[0][2] / s,
            m[1][0] / s,
            m[1][1] / s,
            m[1][2] / s,
            m[2][0] / s,
            m[2][1] / s,
        ]))
    }

    /// The inverse map (camera to panel).
    pub fn inverse(&self) -> Option<Self> {
        let h = &self.0;
        let m = [[h[0], h[1], h[2]], [h[3], h[4], h[5]], [h[6], h[7], 1.0]];
        let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
        if det.abs() < 1e-300 {
            return None;
        }
        let c = |a: usize, b: usize, c_: usize, d: usize| m[a][b] * m[c_][d] - m[a][d] * m[c_][b];
        let inv = [
            [c(1, 1, 2, 2), -c(0, 1, 2, 2), c(0, 1, 1, 2)],
            [-c(1, 0, 2, 2), c(0, 0, 2, 2), -c(0, 0, 1, 2)],
            [c(1, 0, 2, 1), -c(0, 0, 2, 1), c(0, 0, 1, 1)],
        ];
        let s = inv[2][2];
        (s.abs() > 1e-300).then(|| {
            Self([
                inv[0][0] / s,
                inv[0][1] / s,
                inv[0][2] / s,
                inv[1][0] / s,
                inv[1][1] / s,
                inv[1][2] / s,
                inv[2][0] / s,
                inv[2][1] / s,
            ])
        })
    }
}

type Normaliser = (Box<dyn Fn(f64, f64) -> (f64, f64)>, (f64, f64, f64));

/// Centroid to the origin, mean distance √2.
fn normaliser(p: &[(f64, f64)]) -> Normaliser {
    let n = p.len() as f64;
    let (mx, my) = (
        p.iter().map(|q| q.0).sum::<f64>() / n,
        p.iter().map(|q| q.1).sum::<f64>() / n,
    );
    let d = p
        .iter()
        .map(|q| ((q.0 - mx).powi(2) + (q.1 - my).powi(2)).sqrt())
        .sum::<f64>()
        / n;
    let s = if d > 0.0 { 2f64.sqrt() / d } else { 1.0 };
    (
        Box::new(move |x, y| ((x - mx) * s, (y - my) * s)),
        (s, mx, my),
    )
}

fn mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut m = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

/// Gaussian elimination with partial pivoting.
fn solve8(mut a: [[f64; 8]; 8], mut b: [f64; 8]) -> Option<[f64; 8]> {
    solve(&mut a, &mut b)?;
    Some(b)
}

fn solve<const N: usize>(a: &mut [[f64; N]; N], b: &mut [f64; N]) -> Option<()> {
    for col in 0..N {
        let pivot = (col..N).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col].abs() < 1e-12 {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        for row in col + 1..N {
            let f = a[row][col] / a[col][col];
            let pivot_row = a[col];
            for (x, p) in a[row][col..].iter_mut().zip(&pivot_row[col..]) {
                *x -= f * p;
            }
            b[row] -= f * b[col];
        }
    }
    for col in (0..N).rev() {
        let s: f64 = (col + 1..N).map(|k| a[col][k] * b[k]).sum();
        b[col] = (b[col] - s) / a[col][col];
    }
    Some(())
}

/// The panel's outline in a flat field (dark subtracted): each edge's
/// half-level crossings along the middle 60 % of its length, a line
/// fitted to them, the corners where the lines meet; the homography from
/// the panel's corners (its pixels' outer edges) to those. None if the
/// panel does not lie wholly inside the frame.
pub fn from_flat(flat: &Frame, width_px: usize, height_px: usize) -> Option<Homography> {
    let (w, h) = (flat.width, flat.height);
    let at = |x: usize, y: usize| flat.values[y * w + x] as f64;
    let mut centre: Vec<f64> = (h * 2 / 5..h * 3 / 5)
        .flat_map(|y| (w * 2 / 5..w * 3 / 5).map(move |x| (x, y)))
        .map(|(x, y)| at(x, y))
        .collect();
    centre.sort_by(f64::total_cmp);
    let level = *centre.get(centre.len() / 2)?;
    if level <= 0.0 {
        return None;
    }
    let half = level / 2.0;
    // Walking from the centre outwards along a line of samples, the
    // fractional index where the values fall below half; None if never.
    let crossing = |values: &mut dyn Iterator<Item = f64>| -> Option<f64> {
        let mut prev = None;
        for (i, v) in values.enumerate() {
            if v < half {
                let p: f64 = prev?;
                return Some(i as f64 - 1.0 + (p - half) / (p - v));
            }
            prev = Some(v);
        }
        None
    };
    let (cx, cy) = (w / 2, h / 2);
    // The panel's extent along the centre lines, to know where to walk.
    let left = cx as f64 - crossing(&mut (0..=cx).rev().map(|x| at(x, cy)))?;
    let right = cx as f64 + crossing(&mut (cx..w).map(|x| at(x, cy)))?;
    let top = cy as f64 - crossing(&mut (0..=cy).rev().map(|y| at(cx, y)))?;
    let bottom = cy as f64 + crossing(&mut (cy..h).map(|y| at(cx, y)))?;
    let span = |a: f64, b: f64| {
        let l = b - a;
        (
            (a + 0.2 * l).ceil() as usize,
            (b - 0.2 * l).floor() as usize,
        )
    };
    let (y0, y1) = span(top, bottom);
    let (x0, x1) = span(left, right);
    let mut edges: [Vec<(f64, f64)>; 4] = Default::default();
    for y in y0..=y1 {
        edges[0].push((
            y as f64,
            cx as f64 - crossing(&mut (0..=cx).rev().map(|x| at(x, y)))?,
        ));
        edges[1].push((
            y as f64,
            cx as f64 + crossing(&mut (cx..w).map(|x| at(x, y)))?,
        ));
    }
    for x in x0..=x1 {
        edges[2].push((
            x as f64,
            cy as f64 - crossing(&mut (0..=cy).rev().map(|y| at(x, y)))?,
        ));
        edges[3].push((
            x as f64,
            cy as f64 + crossing(&mut (cy..h).map(|y| at(x, y)))?,
        ));
    }
    // Lines: left/right as x = a y + b, top/bottom as y = a x + b.
    let fit = |pts: &[(f64, f64)]| -> Option<(f64, f64)> {
        let n = pts.len() as f64;
        if n < 2.0 {
            return None;
        }
        let (mx, my) = (
            pts.iter().map(|p| p.0).sum::<f64>() / n,
            pts.iter().map(|p| p.1).sum::<f64>() / n,
        );
        let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
        let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        (sxx > 0.0).then(|| (sxy / sxx, my - sxy / sxx * mx))
    };
    let (l, r, t, b) = (
        fit(&edges[0])?,
        fit(&edges[1])?,
        fit(&edges[2])?,
        fit(&edges[3])?,
    );
    // x = a1 y + b1 meets y = a2 x + b2.
    let meet = |(a1, b1): (f64, f64), (a2, b2): (f64, f64)| {
        let y = (a2 * b1 + b2) / (1.0 - a1 * a2);
        (a1 * y + b1, y)
    };
    let (wp, hp) = (width_px as f64, height_px as f64);
    let panel = [
        (-0.5, -0.5),
        (wp - 0.5, -0.5),
        (wp - 0.5, hp - 0.5),
        (-0.5, hp - 0.5),
    ];
    let camera = [meet(l, t), meet(r, t), meet(r, b), meet(l, b)];
    Homography::fit(&panel, &camera)
}

/// The saddle of a quadratic fitted to `frame` over a (2r+1)² window
/// around (u, v), iterated until it moves under 0.01 px; None if the fit
/// is no saddle or wanders out of its window.
pub fn saddle(frame: &Frame, u: f64, v: f64, r: usize) -> Option<(f64, f64)> {
    let (mut cu, mut cv) = (u, v);
    for _ in 0..20 {
        let (iu, iv) = (cu.round() as isize, cv.round() as isize);
        let ri = r as isize;
        if iu - ri < 0
            || iv - ri < 0
            || iu + ri >= frame.width as isize
            || iv + ri >= frame.height as isize
        {
            return None;
        }
        // Coordinates from the current estimate, weighted by a Gaussian
        // centred on it: the fit is then symmetric about the estimate, and
        // a corner's non-quadratic shape biases it no more one way than the
        // other (the integer window of plain least squares did, by 0.07 px).
        let sigma2 = (r as f64 / 2.0).powi(2);
        let mut ata = [[0.0f64; 6]; 6];
        let mut atb = [0.0f64; 6];
        for dy in -ri..=ri {
            for dx in -ri..=ri {
                let z = frame.values[(iv + dy) as usize * frame.width + (iu + dx) as usize] as f64;
                let (x, y) = ((iu + dx) as f64 - cu, (iv + dy) as f64 - cv);
                let w = (-(x * x + y * y) / (2.0 * sigma2)).exp();
                let row = [x * x, x * y, y * y, x, y, 1.0];
                for i in 0..6 {
                    atb[i] += w * row[i] * z;
                    for j in 0..6 {
                        ata[i][j] += w * row[i] * row[j];
                    }
                }
            }
        }
        solve(&mut ata, &mut atb)?;
        let [a, b, c, d, e, _] = atb;
        let det = 4.0 * a * c - b * b;
        if det >= 0.0 {
            return None;
        }
        let x = (-2.0 * c * d + b * e) / det;
        let y = (-2.0 * a * e + b * d) / det;
        if x.abs() > r as f64 || y.abs() > r as f64 {
            return None;
        }
        let (nu, nv) = (cu + x, cv + y);
        let moved = ((nu - cu).powi(2) + (nv - cv).powi(2)).sqrt();
        (cu, cv) = (nu, nv);
        if moved < 0.01 {
            break;
        }
    }
    Some((cu, cv))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_homography_is_recovered_from_its_points() {
        let h = Homography([1.9, 0.05, 12.0, -0.04, 2.1, -7.0, 1e-5, -2e-5]);
        let from: Vec<(f64, f64)> = (0..5)
            .flat_map(|i| (0..4).map(move |j| (i as f64 * 200.0, j as f64 * 150.0)))
            .collect();
        let to: Vec<_> = from.iter().map(|&(x, y)| h.apply(x, y)).collect();
        let fit = Homography::fit(&from, &to).expect("a fit");
        for (&(x, y), &(u, v)) in from.iter().zip(&to) {
            let (a, b) = fit.apply(x, y);
            assert!((a - u).abs() < 1e-6 && (b - v).abs() < 1e-6);
        }
        let back = fit.inverse().expect("invertible");
        let (x, y) = back.apply(to[7].0, to[7].1);
        assert!((x - from[7].0).abs() < 1e-6 && (y - from[7].1).abs() < 1e-6);
        assert!(Homography::fit(&from[..3], &to[..3]).is_none());
    }

    #[test]
    fn a_saddle_is_found_off_the_grid() {
        let (cx, cy) = (20.3, 18.7);
        let mut f = Frame::new(40, 40);
        for y in 0..40 {
            for x in 0..40 {
                let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                // A blurred corner of a checkerboard.
                f.values[y * 40 + x] = (50.0 + 40.0 * (dx / 2.0).tanh() * (dy / 2.0).tanh()) as f32;
            }
        }
        let (u, v) = saddle(&f, 19.0, 20.0, 4).expect("a saddle");
        assert!((u - cx).abs() < 0.02 && (v - cy).abs() < 0.02, "{u} {v}");
    }
}
