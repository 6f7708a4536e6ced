//! Pupil → PSF in angle (docs/model.md §6): pure functions from a sampled pupil
//! to retinal cells, each cell holding ∫_cell |U|² dθ divided by the light
//! through the aperture, with U(θ) = Σ Q(s) exp(−j2π s·θ/λ).
//!
//! Two propagators compute the same samples and are tested against each other:
//! - [`mft_cells`]: matrix Fourier transform (Soummer et al. 2007) on an
//!   arbitrary window, U = E_y · Q · E_xᵀ, two complex matrix products (faer).
//! - [`fft_period_cells`]: one FFT over a whole period λ/Δs of the sampled
//!   transform, then exact m×m binning. Cheaper whenever the window is more
//!   than a few cells wide, and it sees all the light, so the energy window
//!   can be chosen afterwards.
//!
//! Each cell is integrated by the midpoint rule on m×m sub-samples (the
//! caller raises m until the result converges).

use std::f64::consts::PI;
use std::sync::Arc;

use faer::{Accum, Mat, MatRef, Par};
use num_complex::Complex64 as c64;
use rayon::prelude::*;
use rustfft::{Fft, FftPlanner};

use super::pupil::{PupilGrid, pupil_energy};

/// Angle of sub-sample `i` (of `sub`) inside cell `c` of a window of `cells`
/// cells centred on the axis: the cell centres lie at (c − (W−1)/2)·Δθ.
fn sub_sample_angle(c: usize, i: usize, cells: usize, sub: usize, cell_rad: f64) -> f64 {
    (c as f64 - (cells as f64 - 1.0) / 2.0 + (i as f64 + 0.5) / sub as f64 - 0.5) * cell_rad
}

/// Factor from Σ_sub |U_discrete|² to the cell's share of the light: the
/// continuous field is U·Δs², its angular energy density |U|²Δs⁴/(λ² Σ|Q|²Δs²),
/// integrated with weight (Δθ/m)² per sub-sample.
fn cell_scale(grid: PupilGrid, wavelength_m: f64, cell_rad: f64, sub: usize, energy: f64) -> f64 {
    let d = cell_rad / sub as f64;
    d * d * grid.step_m * grid.step_m / (wavelength_m * wavelength_m * energy)
}

/// PSF on a `window`×`window` block of retinal cells of width `cell_rad`,
/// centred on the axis (odd `window` puts a cell centre on the axis), by MFT
/// with `sub`×`sub` sub-samples per cell. `pupil` is N×N on `grid`.
/// Returns row-major cell values (fractions of the light through the aperture).
pub fn mft_cells(
    pupil: &[c64],
    grid: PupilGrid,
    wavelength_m: f64,
    window: usize,
    cell_rad: f64,
    sub: usize,
) -> Vec<f64> {
    let n = grid.samples;
    let k = window * sub;
    // E[k, n] = exp(−j 2π θ_k s_n / λ); the same matrix serves both axes.
    let e = Mat::<c64>::from_fn(k, n, |row, col| {
        let theta = sub_sample_angle(row / sub, row % sub, window, sub, cell_rad);
        let arg = -2.0 * PI * theta * grid.coord_m(col) / wavelength_m;
        c64::from_polar(1.0, arg)
    });
    let q = MatRef::from_row_major_slice(pupil, n, n);
    let par = Par::rayon(0);
    let one = c64::new(1.0, 0.0);
    let mut eq = Mat::<c64>::zeros(k, n);
    faer::linalg::matmul::matmul(eq.as_mut(), Accum::Replace, e.as_ref(), q, one, par);
    let mut u = Mat::<c64>::zeros(k, k);
    faer::linalg::matmul::matmul(
        u.as_mut(),
        Accum::Replace,
        eq.as_ref(),
        e.transpose(),
        one,
        par,
    );

    let scale = cell_scale(grid, wavelength_m, cell_rad, sub, pupil_energy(pupil));
    let mut cells = vec![0.0; window * window];
    for (cy, row) in cells.chunks_mut(window).enumerate() {
        for (cx, out) in row.iter_mut().enumerate() {
            let mut acc = 0.0;
            for iy in 0..sub {
                for ix in 0..sub {
                    acc += u[(cy * sub + iy, cx * sub + ix)].norm_sqr();
                }
            }
            *out = acc * scale;
        }
    }
    cells
}

/// Number of retinal cells in one period λ/Δs of the sampled transform, if
/// it is a whole number (within 1e-6); the FFT propagator needs that.
pub fn whole_period_cells(grid: PupilGrid, wavelength_m: f64, cell_rad: f64) -> Option<usize> {
    let p = wavelength_m / (grid.step_m * cell_rad);
    let rounded = p.round();
    ((p - rounded).abs() < 1e-6 && rounded >= 1.0).then_some(rounded as usize)
}

/// PSF over one whole period of the sampled transform: P×P cells, P = λ/(Δs Δθ)
/// (must be whole: see [`whole_period_cells`]), with the on-axis cell at
/// index (P/2, P/2) (integer division) and `sub`×`sub` sub-samples per cell.
/// The cells sum to 1 (Parseval) whenever m·P ≥ N; for smaller m the pupil is
/// folded onto the FFT grid, which is exact for the transform's samples but
/// leaves the midpoint rule its quadrature error. Returns `None` when the
/// period is not whole.
pub fn fft_period_cells(
    pupil: &[c64],
    grid: PupilGrid,
    wavelength_m: f64,
    cell_rad: f64,
    sub: usize,
) -> Option<Vec<f64>> {
    let p = whole_period_cells(grid, wavelength_m, cell_rad)?;
    let n = grid.samples;
    let m = sub * p;
    // Sub-sample (c, i) of cell c (period-centred index) sits at
    // (c·m + i)·Δθ/m + δ: the FFT grid shifted by δ, a tilt on the pupil.
    let delta = (0.5 / sub as f64 - 0.5) * cell_rad;
    let tilt: Vec<c64> = (0..n)
        .map(|i| c64::from_polar(1.0, -2.0 * PI * grid.coord_m(i) * delta / wavelength_m))
        .collect();
    // Cell c = −P/2 … lies at FFT index c·m (mod M); fold the pupil (exact
    // for the DFT samples) and apply the tilt.
    let mut field = vec![c64::new(0.0, 0.0); m * m];
    for i in 0..n {
        let dst_row = (i % m) * m;
        let src = &pupil[i * n..(i + 1) * n];
        for (j, z) in src.iter().enumerate() {
            if z.re != 0.0 || z.im != 0.0 {
                field[dst_row + j % m] += z * tilt[i] * tilt[j];
            }
        }
    }
    let fft = FftPlanner::<f64>::new().plan_fft_forward(m);
    fft_rows(&mut field, m, &fft);
    let mut transposed = transpose(&field, m);
    drop(field);
    fft_rows(&mut transposed, m, &fft);
    // `transposed` is indexed [qx][qy]; cell c holds FFT samples c·sub + i.
    let scale = 1.0 / ((m * m) as f64 * pupil_energy(pupil));
    Some(centred_cells(p, |c_y, c_x| {
        let mut acc = 0.0;
        for ix in 0..sub {
            let qx = c_x * sub + ix;
            let line = &transposed[qx * m..(qx + 1) * m];
            for iy in 0..sub {
                acc += line[c_y * sub + iy].norm_sqr();
            }
        }
        acc * scale
    }))
}

/// PSF over one whole period with each cell integrated *exactly*: the
/// m → ∞ limit of [`fft_period_cells`]. With u = θΔs/λ, |U(u)|² =
/// Σ_ℓ A_ℓ e^{−2πiℓ·u} where A is the pupil's autocorrelation, so a cell of
/// width 1/P centred on c/P integrates to (1/P²) Σ_ℓ A_ℓ sinc(ℓ_y/P)
/// sinc(ℓ_x/P) e^{−2πiℓ·c/P}: one FFT of size ≥ 2N − 1 gives A (through
/// |Q̂|²), the lags are weighted and folded modulo P, and one P×P FFT gives
/// every cell. The cells sum to 1 exactly (only ℓ = 0 survives the sum).
/// Same layout as [`fft_period_cells`]; `None` when the period is not whole.
pub fn exact_period_cells(
    pupil: &[c64],
    grid: PupilGrid,
    wavelength_m: f64,
    cell_rad: f64,
) -> Option<Vec<f64>> {
    let p = whole_period_cells(grid, wavelength_m, cell_rad)?;
    let n = grid.samples;
    let l = super::sampling::smooth_size_at_least((2 * n - 1) as f64);
    let mut planner = FftPlanner::<f64>::new();
    let fwd = planner.plan_fft_forward(l);
    let inv = planner.plan_fft_inverse(l);
    let mut field = vec![c64::new(0.0, 0.0); l * l];
    for (dst, src) in field.chunks_mut(l).zip(pupil.chunks(n)) {
        dst[..n].copy_from_slice(src);
    }
    // Rows beyond N are zero: transform only the first N rows.
    fft_rows(&mut field[..n * l], l, &fwd);
    // In place: one (2N)² buffer per PSF, where a copy per transpose held
    // three (the largest allocation of a wide aperture's PSF).
    transpose_in_place(&mut field, l);
    let mut spectrum = field;
    fft_rows(&mut spectrum, l, &fwd);
    // |Q̂|², then back: the autocorrelation A (times L²), indexed [ℓx][ℓy].
    spectrum
        .par_iter_mut()
        .for_each(|z| *z = c64::new(z.norm_sqr(), 0.0));
    fft_rows(&mut spectrum, l, &inv);
    transpose_in_place(&mut spectrum, l);
    let mut autocorr = spectrum;
    fft_rows(&mut autocorr, l, &inv);
    // autocorr is now [ℓy][ℓx] again (two transposes).
    let sinc = |x: f64| {
        if x == 0.0 {
            1.0
        } else {
            (PI * x).sin() / (PI * x)
        }
    };
    let lags: Vec<(usize, usize, f64)> = (-(n as isize - 1)..n as isize)
        .map(|lag| {
            (
                lag.rem_euclid(l as isize) as usize,
                lag.rem_euclid(p as isize) as usize,
                sinc(lag as f64 / p as f64),
            )
        })
        .collect();
    let folded_rows: Vec<Vec<c64>> = (0..p)
        .into_par_iter()
        .map(|ky| {
            let mut row = vec![c64::new(0.0, 0.0); p];
            for &(iy, _, wy) in lags.iter().filter(|t| t.1 == ky) {
                let src = &autocorr[iy * l..(iy + 1) * l];
                for &(ix, fx, wx) in &lags {
                    row[fx] += src[ix] * (wy * wx);
                }
            }
            row
        })
        .collect();
    drop(autocorr);
    let mut folded: Vec<c64> = folded_rows.into_iter().flatten().collect();
    let fwd_p = planner.plan_fft_forward(p);
    fft_rows(&mut folded, p, &fwd_p);
    let mut t = transpose(&folded, p);
    fft_rows(&mut t, p, &fwd_p);
    // t is indexed [cx][cy].
    let scale = 1.0 / ((p * p) as f64 * (l * l) as f64 * pupil_energy(pupil));
    Some(centred_cells(p, |c_y, c_x| t[c_x * p + c_y].re * scale))
}

/// A P×P period laid out with the on-axis cell at (P/2, P/2): output (cy, cx)
/// is cell(c_y, c_x) of the period's natural order, c = (index − P/2) mod P.
fn centred_cells(p: usize, cell: impl Fn(usize, usize) -> f64 + Sync) -> Vec<f64> {
    let half = p / 2;
    let mut cells = vec![0.0; p * p];
    cells.par_chunks_mut(p).enumerate().for_each(|(cy, row)| {
        let c_y = (cy + p - half) % p;
        for (cx, out) in row.iter_mut().enumerate() {
            *out = cell(c_y, (cx + p - half) % p);
        }
    });
    cells
}

fn fft_rows(data: &mut [c64], len: usize, fft: &Arc<dyn Fft<f64>>) {
    data.par_chunks_mut(len * 16).for_each_init(
        || vec![c64::new(0.0, 0.0); fft.get_inplace_scratch_len()],
        |scratch, rows| fft.process_with_scratch(rows, scratch),
    );
}

fn transpose(data: &[c64], n: usize) -> Vec<c64> {
    const B: usize = 32;
    let mut out = vec![c64::new(0.0, 0.0); n * n];
    out.par_chunks_mut(n * B)
        .enumerate()
        .for_each(|(bi, block)| {
            // block holds output rows bi*B .. bi*B + B, i.e. input columns.
            let rows = block.len() / n;
            for j0 in (0..n).step_by(B) {
                for r in 0..rows {
                    let col = bi * B + r;
                    for j in j0..(j0 + B).min(n) {
                        block[r * n + j] = data[j * n + col];
                    }
                }
            }
        });
    out
}

/// Transposes the `n`×`n` matrix `data` in place, a block pair at a time
/// (the blocks keep both sides' rows in cache).
fn transpose_in_place(data: &mut [c64], n: usize) {
    const B: usize = 32;
    for i0 in (0..n).step_by(B) {
        for j0 in (i0..n).step_by(B) {
            for i in i0..(i0 + B).min(n) {
                let from = if i0 == j0 { i + 1 } else { j0 };
                for j in from..(j0 + B).min(n) {
                    data.swap(i * n + j, j * n + i);
                }
            }
        }
    }
}

/// Crops the centred `window`×`window` block (odd `window`) of a P×P period
/// array whose on-axis cell sits at (P/2, P/2).
pub fn crop_centred(period: &[f64], p: usize, window: usize) -> Vec<f64> {
    debug_assert!(window % 2 == 1 && window <= p);
    let start = p / 2 - (window - 1) / 2;
    let mut out = Vec::with_capacity(window * window);
    for row in period[start * p..(start + window) * p].chunks(p) {
        out.extend_from_slice(&row[start..start + window]);
    }
    out
}

/// Light inside each centred odd window: element k is the sum over the
/// (2k+1)×(2k+1) block around the on-axis cell (P/2, P/2), for every k whose
/// block fits inside the P×P period.
pub fn centred_window_energies(period: &[f64], p: usize) -> Vec<f64> {
    let c = p / 2;
    let kmax = c.min(p - 1 - c);
    let mut ring = vec![0.0; kmax + 1];
    for (y, row) in period.chunks(p).enumerate() {
        for (x, v) in row.iter().enumerate() {
            let k = y.abs_diff(c).max(x.abs_diff(c));
            if k <= kmax {
                ring[k] += v;
            }
        }
    }
    let mut acc = 0.0;
    ring.iter()
        .map(|r| {
            acc += r;
            acc
        })
        .collect()
}

#[cfg(test)]
mod tests;
