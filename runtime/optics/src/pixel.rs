//! A lit display pixel on the retinal grid (docs/model.md §12): up2 spreads
//! it over 2×2 cells, so what a camera sees of one pixel is the PSF summed
//! over those four cells, its *pixel response*. A measured response is
//! turned back into the PSF the simulator convolves with by dividing out
//! the 2×2 box in frequency, with a floor under |B|²: the box has a zero at
//! the retinal grid's Nyquist frequency, where no display image has
//! content and a measurement only noise.

use num_complex::Complex64 as c64;
use rustfft::FftPlanner;

use crate::psf::Psf;

/// Regularisation of the division, as a share of the box's largest |B|²
/// (16): where |B|² falls under it (next to the Nyquist row and column,
/// where |B| → 0) the division is by that floor instead, a gain of at most
/// 1/√(16·share) (2.5 at 1 %, 10× the gain at 0); everywhere else it is
/// exact.
pub const DECONVOLUTION_SHARE: f64 = 0.01;

/// The pixel response of `psf`: `window + 1` cells across, g[k] = Σ over
/// d ∈ {0, 1}² of psf[k − d], so that index (R, R), R the PSF's half
/// window, is the pixel's first cell (the top-left of its 2×2). Its cells
/// sum to 4 × (1 − veil): a full-white pixel is 1 on each of its 4 cells.
pub fn pixel_response(psf: &Psf) -> (usize, Vec<f64>) {
    let n = psf.window;
    let m = n + 1;
    let mut g = vec![0.0; m * m];
    for y in 0..n {
        for x in 0..n {
            let v = psf.cells[y * n + x];
            for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                g[(y + dy) * m + x + dx] += v;
            }
        }
    }
    (m, g)
}

/// The inverse of [`pixel_response`]: the m×m response (m even) back to an
/// (m−1)×(m−1) PSF's cells, by regularised division in frequency
/// ([`DECONVOLUTION_SHARE`]).
pub fn psf_cells_from_response(m: usize, g: &[f64]) -> Vec<f64> {
    let n = m - 1;
    // Room for the linear (not circular) convolution, and some more.
    let l = m + 32;
    let mut planner = FftPlanner::<f64>::new();
    let fwd = planner.plan_fft_forward(l);
    let inv = planner.plan_fft_inverse(l);
    let mut grid = vec![c64::new(0.0, 0.0); l * l];
    for y in 0..m {
        for x in 0..m {
            grid[y * l + x] = c64::new(g[y * m + x], 0.0);
        }
    }
    let fft2 = |grid: &mut Vec<c64>, f: &std::sync::Arc<dyn rustfft::Fft<f64>>| {
        grid.chunks_mut(l).for_each(|row| f.process(row));
        let mut col = vec![c64::new(0.0, 0.0); l];
        for x in 0..l {
            for y in 0..l {
                col[y] = grid[y * l + x];
            }
            f.process(&mut col);
            for y in 0..l {
                grid[y * l + x] = col[y];
            }
        }
    };
    fft2(&mut grid, &fwd);
    let one = |k: usize| {
        c64::new(1.0, 0.0) + c64::from_polar(1.0, -std::f64::consts::TAU * k as f64 / l as f64)
    };
    let eps = 16.0 * DECONVOLUTION_SHARE;
    for ky in 0..l {
        let by = one(ky);
        for kx in 0..l {
            let b = by * one(kx);
            let v = &mut grid[ky * l + kx];
            *v = *v * b.conj() / b.norm_sqr().max(eps);
        }
    }
    fft2(&mut grid, &inv);
    let scale = 1.0 / (l * l) as f64;
    let mut cells = vec![0.0; n * n];
    for y in 0..n {
        for x in 0..n {
            cells[y * n + x] = grid[y * l + x].re * scale;
        }
    }
    cells
}

/// How far PSF `a` is from `b`, as a display shows them: ‖r(a) − r(b)‖₂ /
/// ‖r(b)‖₂ over their pixel responses r (both centred in the larger
/// window). The pixel response, not the PSF, because the 2×2 box erases
/// the PSF's Nyquist content: no display image can show it, and no
/// capture can measure it.
pub fn response_distance(a: &Psf, b: &Psf) -> f64 {
    let n = a.window.max(b.window);
    let pad = |p: &Psf| {
        Psf::weighted_sum([
            (p, 1.0),
            (
                &Psf {
                    window: n,
                    cells: vec![0.0; n * n],
                    veil: 0.0,
                },
                0.0,
            ),
        ])
    };
    let (Some(a), Some(b)) = (pad(a), pad(b)) else {
        return f64::INFINITY;
    };
    let (_, ra) = pixel_response(&a);
    let (_, rb) = pixel_response(&b);
    let diff: f64 = ra.iter().zip(&rb).map(|(x, y)| (x - y).powi(2)).sum();
    let norm: f64 = rb.iter().map(|y| y * y).sum();
    (diff / norm.max(1e-300)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_response_holds_four_cells_of_light_and_comes_back() {
        let psf = Psf::gaussian(2.5, 0.1);
        let (m, g) = pixel_response(&psf);
        assert_eq!(m, psf.window + 1);
        let sum: f64 = g.iter().sum();
        assert!((sum - 4.0 * 0.9).abs() < 1e-12, "{sum}");
        let c = m / 2;
        assert!((g[c * m + c] - g[(c - 1) * m + c - 1]).abs() < 1e-15);
        // Back: within the regularisation's loss at the highest frequencies.
        let back = psf_cells_from_response(m, &g);
        let err: f64 = back
            .iter()
            .zip(&psf.cells)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt();
        let norm: f64 = psf.cells.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(err / norm < 0.01, "relative L2 {}", err / norm);
        let total: f64 = back.iter().sum();
        assert!((total - 0.9).abs() < 1e-4, "{total}");
    }
}
