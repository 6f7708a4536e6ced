//! Closed-form and cross checks of the propagators: MFT against FFT on the
//! same samples, Parseval over one period, the Airy pattern and the
//! diffraction-limited MTF.

use super::*;
use crate::pupil::{PupilGrid, pupil_field};

/// J1 by its integral representation (1/π)∫₀^π cos(τ − x sin τ) dτ; the
/// trapezoid rule on this periodic analytic integrand converges exponentially.
fn bessel_j1(x: f64) -> f64 {
    let n = 2000;
    let h = PI / n as f64;
    let f = |t: f64| (t - x * t.sin()).cos();
    let mut s = 0.5 * (f(0.0) + f(PI));
    for i in 1..n {
        s += f(i as f64 * h);
    }
    s * h / PI
}

/// A pupil of `samples_across` samples across the diameter, with the cell
/// chosen so that the period λ/Δs is exactly `period` cells.
fn setup(samples_across: f64, period: usize) -> (PupilGrid, f64, f64, f64) {
    let r = 5e-3;
    let lambda = 530e-9;
    let grid = PupilGrid::covering(r, 2.0 * r / samples_across);
    let cell = lambda / (grid.step_m * period as f64);
    (grid, r, lambda, cell)
}

#[test]
fn mft_and_fft_agree_to_round_off() {
    let (grid, r, lambda, cell) = setup(40.0, 37);
    // A defocused pupil with a rough phase screen, so nothing is symmetric.
    let n = grid.samples;
    let screen: Vec<f64> = (0..n * n)
        .map(|i| ((i * 7919) % 113) as f64 * 0.05)
        .collect();
    let q = pupil_field(grid, r, 9.0, Some(&screen));
    for sub in [1, 2, 3] {
        let period = fft_period_cells(&q, grid, lambda, cell, sub).expect("whole period");
        let window = 37;
        let by_fft = crop_centred(&period, 37, window);
        let by_mft = mft_cells(&q, grid, lambda, window, cell, sub);
        let max = by_fft.iter().cloned().fold(0.0, f64::max);
        for (a, b) in by_fft.iter().zip(&by_mft) {
            assert!(
                (a - b).abs() < 1e-12 * max.max(1e-300) + 1e-15,
                "sub {sub}: {a} vs {b}"
            );
        }
    }
}

#[test]
fn parseval_one_period_holds_all_the_light() {
    let (grid, r, lambda, cell) = setup(60.0, 25);
    let n = grid.samples;
    let screen: Vec<f64> = (0..n * n)
        .map(|i| ((i * 104729) % 97) as f64 * 0.3)
        .collect();
    let q = pupil_field(grid, r, -40.0, Some(&screen));
    // m·P ≥ N: the midpoint sum over the period is exact.
    let sub = n.div_ceil(25);
    let period = fft_period_cells(&q, grid, lambda, cell, sub).expect("whole period");
    let total: f64 = period.iter().sum();
    assert!((total - 1.0).abs() < 1e-12, "period holds {total}");
    // A window smaller than the period holds less, never more.
    let energies = centred_window_energies(&period, 25);
    assert!(energies.windows(2).all(|w| w[1] >= w[0]));
    assert!((energies.last().copied().unwrap_or(0.0) - total).abs() < 1e-12);
}

#[test]
fn in_focus_psf_is_the_airy_pattern() {
    // Fine cells (sub = 1: centre samples) so cell/Δθ² is the density.
    let (grid, r, lambda, cell) = setup(1024.0, 4000);
    let q = pupil_field(grid, r, 0.0, None);
    let window = 81;
    let cells = mft_cells(&q, grid, lambda, window, cell, 1);
    let peak_density = PI * r * r / (lambda * lambda);
    let c = (window - 1) / 2;
    let mut worst: f64 = 0.0;
    for y in 0..window {
        for x in 0..window {
            let theta = (x as f64 - c as f64).hypot(y as f64 - c as f64) * cell;
            let arg = 2.0 * PI * r * theta / lambda;
            let airy = if arg == 0.0 {
                1.0
            } else {
                (2.0 * bessel_j1(arg) / arg).powi(2)
            };
            let got = cells[y * window + x] / (cell * cell) / peak_density;
            worst = worst.max((got - airy).abs());
        }
    }
    assert!(
        worst < 1e-3,
        "largest deviation from Airy (relative to peak) {worst}"
    );
}

#[test]
fn in_focus_mtf_is_the_diffraction_limited_otf() {
    // Period ≥ 2N: the PSF's DFT is the pupil autocorrelation without wrap.
    // The grey edge's energy falls short of its area by ≈ 2/(3N), which lifts
    // the normalised MTF by about that much (docs/optics-model.md): at
    // N = 1024 (the 6 µm design grid has N ≈ 1670) that is 6.5e-4.
    let (grid, r, lambda, _) = setup(1024.0, 1);
    let p = 2 * grid.samples + 1;
    let cell = lambda / (grid.step_m * p as f64);
    let q = pupil_field(grid, r, 0.0, None);
    let psf = fft_period_cells(&q, grid, lambda, cell, 1).expect("whole period");
    let marginal: Vec<f64> = (0..p)
        .map(|x| (0..p).map(|y| psf[y * p + x]).sum())
        .collect();
    let c = (p / 2) as f64;
    let cutoff = 2.0 * r / lambda; // cycles per radian
    let mut worst: f64 = 0.0;
    for k in 0..=40 {
        let nu = k as f64 / 40.0;
        let f = nu * cutoff;
        let (mut re, mut im) = (0.0, 0.0);
        for (x, v) in marginal.iter().enumerate() {
            let a = -2.0 * PI * f * (x as f64 - c) * cell;
            re += v * a.cos();
            im += v * a.sin();
        }
        let mtf = re.hypot(im);
        let exact = if nu >= 1.0 {
            0.0
        } else {
            2.0 / PI * (nu.acos() - nu * (1.0 - nu * nu).sqrt())
        };
        worst = worst.max((mtf - exact).abs());
    }
    assert!(worst < 1e-3, "largest MTF deviation {worst}");
}

#[test]
fn window_energies_and_crop_are_centred() {
    let p = 5;
    let mut period = vec![0.0; 25];
    period[2 * 5 + 2] = 0.5; // on axis
    period[5 + 3] = 0.25; // one ring out
    period[0] = 0.25; // corner, two rings out
    assert_eq!(centred_window_energies(&period, p), vec![0.5, 0.75, 1.0]);
    let crop = crop_centred(&period, p, 3);
    assert_eq!(crop[4], 0.5);
    assert_eq!(crop[2], 0.25);
}

#[test]
fn non_whole_period_is_refused() {
    let grid = PupilGrid {
        samples: 8,
        step_m: 1e-3,
    };
    assert!(whole_period_cells(grid, 500e-9, 1.3e-4).is_none());
    assert!(fft_period_cells(&[c64::new(1.0, 0.0); 64], grid, 500e-9, 1.3e-4, 1).is_none());
}

#[test]
fn exact_cells_are_the_limit_of_the_midpoint_rule() {
    let (grid, r, lambda, cell) = setup(48.0, 23);
    let n = grid.samples;
    let screen: Vec<f64> = (0..n * n)
        .map(|i| ((i * 7919) % 113) as f64 * 0.05)
        .collect();
    let q = pupil_field(grid, r, 6.0, Some(&screen));
    let exact = exact_period_cells(&q, grid, lambda, cell).expect("whole period");
    assert!((exact.iter().sum::<f64>() - 1.0).abs() < 1e-12, "Parseval");
    let err = |sub: usize| -> f64 {
        let m = fft_period_cells(&q, grid, lambda, cell, sub).expect("period");
        m.iter().zip(&exact).map(|(a, b)| (a - b).abs()).sum()
    };
    // The midpoint rule converges to the exact cells at second order.
    let (e4, e8, e16) = (err(4), err(8), err(16));
    assert!(e16 < 1e-3, "m = 16 still {e16}");
    assert!(
        (e4 / e8 - 4.0).abs() < 0.6 && (e8 / e16 - 4.0).abs() < 0.6,
        "orders {} {}",
        e4 / e8,
        e8 / e16
    );
    // And agrees with the MFT's sub-sampled cells on a window.
    let mft = mft_cells(&q, grid, lambda, 23, cell, 16);
    let exact_window = crop_centred(&exact, 23, 23);
    let l1: f64 = mft
        .iter()
        .zip(&exact_window)
        .map(|(a, b)| (a - b).abs())
        .sum();
    assert!(
        (l1 - e16).abs() < 1e-9,
        "MFT and FFT midpoint sums are the same samples"
    );
}

#[test]
fn the_in_place_transpose_is_the_copying_one() {
    // Sizes on, off and across the blocks' edges.
    for n in [1, 5, 32, 33, 70] {
        let data: Vec<c64> = (0..n * n)
            .map(|k| c64::new(k as f64, -(k as f64) / 3.0))
            .collect();
        let mut inplace = data.clone();
        transpose_in_place(&mut inplace, n);
        assert_eq!(inplace, transpose(&data, n), "n = {n}");
        transpose_in_place(&mut inplace, n);
        assert_eq!(inplace, data, "twice is the identity, n = {n}");
    }
}
