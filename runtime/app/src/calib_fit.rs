//! Extraction for `calib psfs`: each dot's camera pixels gathered at their
//! places on the retinal grid, one least-squares fit of the response to
//! all of them, and the response turned into a PSF.

use rayon::prelude::*;

use crate::calib_capture::Frame;
use crate::calib_register::Homography;
use nedrt_optics::pixel::psf_cells_from_response;
use nedrt_optics::psf::Psf;

/// Cells of the averaged response under this many standard deviations of
/// the background are set to 0 (their light goes to the veil).
pub const NOISE_FLOOR_SIGMAS: f64 = 3.0;

/// Half the side of the core fitted by least squares, retinal cells: the
/// in-focus order's core is a few cells across; beyond, the light is
/// smooth enough that resampling each dot at the cells' centres is exact
/// to the noise.
pub const CORE_CELLS: usize = 32;

/// The dots of one channel and accommodation: each dot resampled at the
/// cells' centres (summed in `outer`), and the camera pixels of each
/// dot's core, each at its place on the core's grid (fractional cell
/// index) with its value; values in units of the flat field (1 on each
/// cell of a full-white pixel), each dot's background removed.
#[derive(Debug)]
pub struct Samples {
    half: usize,
    core: usize,
    at: Vec<[f64; 2]>,
    value: Vec<f32>,
    outer: Vec<f64>,
    dots: usize,
}

impl Samples {
    /// For responses of 2·half + 2 cells across.
    pub fn new(half: usize) -> Self {
        let m = 2 * half + 2;
        Self {
            half,
            core: CORE_CELLS.min(half.saturating_sub(1)),
            at: Vec::new(),
            value: Vec::new(),
            outer: vec![0.0; m * m],
            dots: 0,
        }
    }

    /// How many dots were gathered.
    pub fn dots(&self) -> usize {
        self.dots
    }

    /// Adds `other`'s dots (gathered for responses of the same size).
    pub fn absorb(&mut self, other: &Samples) {
        self.at.extend_from_slice(&other.at);
        self.value.extend_from_slice(&other.value);
        self.outer
            .iter_mut()
            .zip(&other.outer)
            .for_each(|(a, b)| *a += b);
        self.dots += other.dots;
    }
}

/// Adds the dot at panel pixel (px, py) to `samples`. Its background is
/// the median of its resampled cells on the window's outer two rings.
pub fn gather(
    frame: &Frame,
    reg: &Homography,
    inverse: &Homography,
    (px, py): (f64, f64),
    level: f64,
    samples: &mut Samples,
) {
    let (half, core) = (samples.half, samples.core);
    let m = 2 * half + 2;
    // Cell k of the pixel's first cell has its centre at panel p + k/2 − 1/4.
    let panel = |k: f64| k / 2.0 - 0.25;
    let cut: Vec<f64> = (0..m * m)
        .into_par_iter()
        .map(|i| {
            let (kx, ky) = ((i % m) as f64 - half as f64, (i / m) as f64 - half as f64);
            let (u, v) = reg.apply(px + panel(kx), py + panel(ky));
            frame.sample(u, v) / level
        })
        .collect();
    let mut ring: Vec<f64> = (0..m * m)
        .filter(|i| {
            let (x, y) = (i % m, i / m);
            x.min(y) < 2 || x.max(y) >= m - 2
        })
        .map(|i| cut[i])
        .collect();
    ring.sort_by(f64::total_cmp);
    let background = ring.get(ring.len() / 2).copied().unwrap_or(0.0);
    samples
        .outer
        .iter_mut()
        .zip(&cut)
        .for_each(|(o, c)| *o += c - background);
    samples.dots += 1;
    // The core's camera pixels, on the core's grid of 2·core + 2 cells.
    let mc = 2 * core + 2;
    let (lo, hi) = (panel(-(core as f64) - 1.0), panel(core as f64 + 2.0));
    let corners = [
        reg.apply(px + lo, py + lo),
        reg.apply(px + hi, py + lo),
        reg.apply(px + lo, py + hi),
        reg.apply(px + hi, py + hi),
    ];
    let clamp = |v: f64, n: usize| v.clamp(0.0, n as f64 - 1.0) as usize;
    let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (u, v) in corners {
        (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
    }
    let top = (mc - 1) as f64;
    let offset = (half - core) as f64;
    for v in clamp(v0.floor(), frame.height)..=clamp(v1.ceil(), frame.height) {
        for u in clamp(u0.floor(), frame.width)..=clamp(u1.ceil(), frame.width) {
            let (x, y) = inverse.apply(u as f64, v as f64);
            let i = 2.0 * (x - px) + 0.5 + half as f64 - offset;
            let j = 2.0 * (y - py) + 0.5 + half as f64 - offset;
            if i >= 0.0 && j >= 0.0 && i < top && j < top {
                samples.at.push([i, j]);
                samples
                    .value
                    .push((frame.values[v * frame.width + u] as f64 / level - background) as f32);
            }
        }
    }
}

/// Conjugate-gradient steps of the least-squares fit below.
const FIT_ITERATIONS: usize = 60;

/// The mean response of the dots: resampled at the cells' centres, and in
/// the core the response whose bilinear interpolation best matches every
/// camera pixel of every dot (least squares, conjugate gradients on the
/// normal equations): the dots' many sub-cell phases put back on the
/// retinal grid without interpolating twice.
pub fn fit_response(s: &Samples) -> Vec<f64> {
    let m = 2 * s.half + 2;
    let mc = 2 * s.core + 2;
    let mut out: Vec<f64> = s.outer.iter().map(|v| v / s.dots.max(1) as f64).collect();
    let fitted = least_squares(mc, &s.at, &s.value);
    let offset = s.half - s.core;
    // The core grid's own edge has samples on one side only: kept resampled.
    for y in 1..mc - 1 {
        for x in 1..mc - 1 {
            out[(y + offset) * m + x + offset] = fitted[y * mc + x];
        }
    }
    out
}

fn least_squares(m: usize, at: &[[f64; 2]], value: &[f32]) -> Vec<f64> {
    let weights = |at: [f64; 2]| {
        let [i, j] = at;
        let (i0, j0) = (i.floor(), j.floor());
        let (fi, fj) = (i - i0, j - j0);
        let k = j0 as usize * m + i0 as usize;
        [
            (k, (1.0 - fi) * (1.0 - fj)),
            (k + 1, fi * (1.0 - fj)),
            (k + m, (1.0 - fi) * fj),
            (k + m + 1, fi * fj),
        ]
    };
    let forward = |x: &[f64]| -> Vec<f64> {
        at.par_iter()
            .map(|&a| weights(a).iter().map(|&(k, w)| w * x[k]).sum())
            .collect()
    };
    let adjoint = |r: &[f64]| -> Vec<f64> {
        at.par_iter()
            .zip(r.par_iter())
            .fold(
                || vec![0.0f64; m * m],
                |mut acc, (&a, &v)| {
                    for (k, w) in weights(a) {
                        acc[k] += w * v;
                    }
                    acc
                },
            )
            .reduce(
                || vec![0.0f64; m * m],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    a
                },
            )
    };
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let y: Vec<f64> = value.iter().map(|v| *v as f64).collect();
    let mut x = vec![0.0f64; m * m];
    let mut r = adjoint(&y);
    let mut p = r.clone();
    let mut rr = dot(&r, &r);
    for _ in 0..FIT_ITERATIONS {
        if rr <= 0.0 {
            break;
        }
        let q = adjoint(&forward(&p));
        let alpha = rr / dot(&p, &q).max(1e-300);
        x.iter_mut().zip(&p).for_each(|(a, b)| *a += alpha * b);
        r.iter_mut().zip(&q).for_each(|(a, b)| *a -= alpha * b);
        let next = dot(&r, &r);
        let beta = next / rr;
        rr = next;
        p.iter_mut().zip(&r).for_each(|(a, b)| *a = b + beta * *a);
    }
    x
}

/// The averaged response to a PSF: the noise floor (cells under
/// [`NOISE_FLOOR_SIGMAS`] × the outer rings' spread set to 0), the pixel
/// divided out, negatives clipped, the light the window misses as veil.
/// Also the floor, as a share of the PSF's light per cell.
pub fn response_to_psf(m: usize, mut g: Vec<f64>) -> (Psf, f64) {
    let ring: Vec<f64> = (0..m * m)
        .filter(|i| {
            let (x, y) = (i % m, i / m);
            x.min(y) < 2 || x.max(y) >= m - 2
        })
        .map(|i| g[i])
        .collect();
    let mean = ring.iter().sum::<f64>() / ring.len() as f64;
    let sd = (ring.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / ring.len() as f64).sqrt();
    let floor = NOISE_FLOOR_SIGMAS * sd;
    g.iter_mut().for_each(|v| {
        if *v < floor {
            *v = 0.0
        }
    });
    // Not clipped at 0: the division leaves small negative lobes around a
    // sharp core (its content next to the Nyquist frequency), and clipping
    // them would add light that no capture saw.
    let mut cells = psf_cells_from_response(m, &g);
    let total: f64 = cells.iter().sum();
    let veil = if total > 1.0 {
        cells.iter_mut().for_each(|v| *v /= total);
        0.0
    } else {
        1.0 - total
    };
    (
        Psf {
            window: m - 1,
            cells,
            veil,
        },
        floor / 4.0,
    )
}
