//! The sharpness measure against closed forms (identity, a Gaussian's MTF,
//! a sinusoid's contrast), the curve analysis on synthetic curves, and the
//! conventional display's focus from rendered images.

use super::*;
use crate::cache::PsfCache;
use crate::sim::convolve::convolve_symmetric;
use crate::sim::{Method, Simulator};
use nedrt_core::calib::Calibration;

/// The default calibration's retinal step, radians (0.5236 arcmin).
fn cell_rad() -> f64 {
    Calibration::default_embedded()
        .expect("calib")
        .retinal_step_rad()
}

/// Cycles per cell of `cpd` on the default grid.
fn cycles_per_cell(cpd: f64) -> f64 {
    cpd * cell_rad() / (std::f64::consts::PI / 180.0)
}

/// Deterministic white noise in [0, 1] (an LCG), one plane per channel.
fn noise(width: usize, height: usize, seed: u64) -> Image {
    let mut state = seed;
    let planes = (0..3)
        .map(|_| {
            (0..width * height)
                .map(|_| {
                    state = state
                        .wrapping_mul(6_364_136_223_846_793_005)
                        .wrapping_add(1_442_695_040_888_963_407);
                    (state >> 40) as f32 / (1u64 << 24) as f32
                })
                .collect()
        })
        .collect();
    Image::from_planes(width, height, planes)
}

fn gaussian_kernel(sigma_cells: f64) -> (Vec<f64>, usize) {
    let half = (4.0 * sigma_cells).ceil() as usize;
    let k = 2 * half + 1;
    let taps: Vec<f64> = (0..k)
        .map(|i| {
            let x = i as f64 - half as f64;
            (-x * x / (2.0 * sigma_cells * sigma_cells)).exp()
        })
        .collect();
    let mut kernel: Vec<f64> = (0..k * k).map(|i| taps[i / k] * taps[i % k]).collect();
    let sum: f64 = kernel.iter().sum();
    kernel.iter_mut().for_each(|v| *v /= sum);
    (kernel, k)
}

fn blurred(image: &Image, sigma_cells: f64) -> Image {
    let (kernel, k) = gaussian_kernel(sigma_cells);
    let planes = image
        .planes()
        .map(|p| convolve_symmetric(p, image.width, image.height, &kernel, k))
        .collect();
    Image::from_planes(image.width, image.height, planes)
}

#[test]
fn the_sharp_image_against_itself_is_exactly_one() {
    let sharp = noise(96, 80, 1);
    let meter = SharpnessMeter::new(96, 80, cell_rad(), &FOCUS_FREQUENCIES_CPD);
    assert!(
        meter.band_bins().iter().all(|n| *n > 10),
        "{:?}",
        meter.band_bins()
    );
    let p = meter.band_powers(&sharp);
    assert_eq!(sharpness(&p, &p), vec![Some(1.0), Some(1.0)]);
}

#[test]
fn a_gaussian_blur_reads_its_mtf() {
    let (w, h) = (256, 256);
    let sharp = noise(w, h, 7);
    let meter = SharpnessMeter::new(w, h, cell_rad(), &FOCUS_FREQUENCIES_CPD);
    let sharp_p = meter.band_powers(&sharp);
    for (fi, &f) in FOCUS_FREQUENCIES_CPD.iter().enumerate() {
        // σ chosen so that the Gaussian's MTF at f is 0.6.
        let nu = cycles_per_cell(f);
        let mtf_at_f = 0.6f64;
        let sigma = (-mtf_at_f.ln() / (2.0 * std::f64::consts::PI.powi(2) * nu * nu)).sqrt();
        let s =
            sharpness(&meter.band_powers(&blurred(&sharp, sigma)), &sharp_p)[fi].expect("defined");
        // What a flat spectrum gives over the half-octave annulus: the RMS
        // of the MTF with the annulus's ring weights (u = (ν/f)², uniform).
        let (u0, u1) = (2f64.powf(-0.5), 2f64.powf(0.5));
        let a = -2.0 * mtf_at_f.ln();
        let band_rms = (((-a * u0).exp() - (-a * u1).exp()) / (a * (u1 - u0))).sqrt();
        assert!(
            (s - mtf_at_f).abs() < 0.03 * mtf_at_f,
            "{f} CPD: S {s:.4} vs MTF {mtf_at_f}"
        );
        assert!(
            (s - band_rms).abs() < 0.01 * band_rms,
            "{f} CPD: S {s:.4} vs band RMS {band_rms:.4}"
        );
    }
}

#[test]
fn a_sinusoid_reads_its_contrast_ratio() {
    let (w, h) = (200, 120);
    let nu = cycles_per_cell(5.0);
    let grating = |amplitude: f64| {
        let plane: Vec<f32> = (0..w * h)
            .map(|i| {
                let x = (i % w) as f64;
                (0.5 + amplitude * (2.0 * std::f64::consts::PI * nu * x).cos()) as f32
            })
            .collect();
        Image::from_planes(w, h, vec![plane; 3])
    };
    let meter = SharpnessMeter::new(w, h, cell_rad(), &FOCUS_FREQUENCIES_CPD);
    let sharp = meter.band_powers(&grating(0.4));
    for amplitude in [0.4, 0.3, 0.1, 0.02] {
        let s = sharpness(&meter.band_powers(&grating(amplitude)), &sharp)[0].expect("defined");
        assert!(
            (s - amplitude / 0.4).abs() < 1e-5,
            "amplitude {amplitude}: S {s}"
        );
    }
    // A flat frame has nothing in any band: undefined, not 0/0.
    let flat = Image::from_planes(w, h, vec![vec![0.5; w * h]; 3]);
    let flat_p = meter.band_powers(&flat);
    assert_eq!(sharpness(&flat_p, &flat_p), vec![None, None]);
    assert_eq!(mean_defined([None, Some(0.5), Some(1.0)]), Some(0.75));
    assert_eq!(mean_defined([None]), None);
}

/// Samples `f` at 0, 0.1, …, 3 D.
fn sampled(f: impl Fn(f64) -> f64) -> Curve {
    let depths: Vec<f64> = (0..=30).map(|i| i as f64 / 10.0).collect();
    let values: Vec<Option<f64>> = depths.iter().map(|d| Some(f(*d))).collect();
    Curve::new(&depths, &values)
}

#[test]
fn focus_cue_score_on_synthetic_curves() {
    let tent = sampled(|d| 1.0 - (d - 1.5).abs());
    assert!((tent.focus_cue_score(1.5, CUE_OFFSET_D).expect("fc") - 0.5).abs() < 1e-12);
    // A flat curve gives no cue; a ramp gives none in the middle.
    let flat = sampled(|_| 0.7);
    assert_eq!(flat.focus_cue_score(1.5, CUE_OFFSET_D), Some(0.0));
    let ramp = sampled(|d| d / 3.0);
    assert!(ramp.focus_cue_score(1.5, CUE_OFFSET_D).expect("fc").abs() < 1e-12);
    // Near the end the one side that exists: S(2.8) − S(2.3).
    let fc = ramp.focus_cue_score(2.8, CUE_OFFSET_D).expect("fc");
    assert!((fc - 0.5 / 3.0).abs() < 1e-12, "{fc}");
    let fc = ramp.focus_cue_score(0.2, CUE_OFFSET_D).expect("fc");
    assert!((fc + 0.5 / 3.0).abs() < 1e-12, "{fc}");
    // Off-grid offsets interpolate linearly; outside the range: none.
    assert!((ramp.at(1.25).expect("at") - 1.25 / 3.0).abs() < 1e-12);
    assert_eq!(ramp.at(3.2), None);
    assert_eq!(ramp.at(-0.01), None);
    // Three bumps at the main depths: a positive cue at each, none between.
    let bumps = sampled(|d| {
        [0.5, 1.5, 2.5]
            .iter()
            .map(|m| (-(d - m) * (d - m) / (2.0 * 0.15 * 0.15)).exp())
            .sum::<f64>()
    });
    for m in [0.5, 1.5, 2.5] {
        assert!(bumps.focus_cue_score(m, CUE_OFFSET_D).expect("fc") > 0.9);
    }
    assert!(bumps.focus_cue_score(1.0, CUE_OFFSET_D).expect("fc") < -0.9);
    // Undefined samples are left out, not read as zeros.
    let depths = [0.0, 0.5, 1.0, 1.5];
    let gappy = Curve::new(&depths, &[Some(0.0), None, Some(1.0), Some(0.5)]);
    assert!((gappy.at(0.5).expect("at") - 0.5).abs() < 1e-12);
}

#[test]
fn local_maxima_are_located_between_samples() {
    // A bump centred off the grid is found by the parabola, not the sample.
    let off = sampled(|d| (-(d - 1.53) * (d - 1.53) / (2.0 * 0.3 * 0.3)).exp());
    let peaks = off.local_maxima();
    assert_eq!(peaks.len(), 1, "{peaks:?}");
    assert!((peaks[0].accommodation_d - 1.53).abs() < 0.01, "{peaks:?}");
    assert!(!peaks[0].at_range_end);
    // Three bumps: the nearest to each main depth is its own.
    let bumps = sampled(|d| {
        [0.48, 1.5, 2.57]
            .iter()
            .map(|m| (-(d - m) * (d - m) / (2.0 * 0.2 * 0.2)).exp())
            .sum::<f64>()
    });
    assert_eq!(bumps.local_maxima().len(), 3);
    for (main, want) in [(0.5, 0.48), (1.5, 1.5), (2.5, 2.57)] {
        let p = bumps.nearest_peak(main).expect("peak");
        assert!((p.accommodation_d - want).abs() < 0.02, "{main}: {p:?}");
    }
    // A ramp peaks at its end, flagged as such.
    let ramp = sampled(|d| d);
    let peaks = ramp.local_maxima();
    assert_eq!(peaks.len(), 1);
    assert!(peaks[0].at_range_end && peaks[0].accommodation_d == 3.0);
    // A plateau is one maximum; a plateau that rises further is none.
    let depths = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5];
    let plateau = Curve::new(&depths, &[0.0, 1.0, 1.0, 0.5, 0.5, 2.0].map(Some));
    let peaks = plateau.local_maxima();
    assert_eq!(peaks.len(), 2, "{peaks:?}");
    assert!((peaks[0].accommodation_d - 0.15).abs() < 1e-12, "{peaks:?}");
    assert_eq!(peaks[1].accommodation_d, 0.5);
    let shelf = Curve::new(&depths[..4], &[1.0, 1.0, 2.0, 0.0].map(Some));
    let peaks = shelf.local_maxima();
    assert_eq!(peaks.len(), 1, "{peaks:?}");
    assert!((peaks[0].accommodation_d - 0.2).abs() < 0.05);
}

/// Physics: through the lens alone each colour is sharpest where the lens
/// images the panel, V_λ = 1/z_d − 1/f_λ (G ≈ 1.49 D, R above, B below),
/// measured from rendered images on the small-aperture calibration.
#[test]
fn the_conventional_display_is_sharpest_at_the_lens_focus() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/data/small-aperture.toml"
    );
    let calib = Calibration::load(std::path::Path::new(path)).expect("calib");
    let sim = Simulator::new(calib, None, PsfCache::disabled()).expect("sim");
    let depths = sim.calib.depth_sweep_d(SWEEP_STEP_D);
    let prepared = sim
        .prepare(
            &[Method::Conventional],
            &depths,
            &nedrt_core::progress::Silent,
        )
        .expect("prepare");
    let input = noise(64, 64, 3);
    let sharp = input.up2();
    let meter = SharpnessMeter::new(
        sharp.width,
        sharp.height,
        sim.calib.retinal_step_rad(),
        &[5.0],
    );
    let sharp_p = meter.band_powers(&sharp);
    // Per channel: S_5 at every depth.
    let mut per_channel = vec![Vec::new(); 3];
    for &d in &depths {
        let seen = prepared
            .perceived(Method::Conventional, &input, d)
            .expect("perceived");
        let p = meter.band_powers(&seen);
        for (ch, curve) in per_channel.iter_mut().enumerate() {
            curve.push(Some((p.band[ch][0] / sharp_p.band[ch][0]).sqrt()));
        }
    }
    let peak_d: Vec<f64> = per_channel
        .iter()
        .map(|values| {
            let curve = Curve::new(&depths, values);
            curve
                .local_maxima()
                .into_iter()
                .max_by(|a, b| a.value.total_cmp(&b.value))
                .expect("a maximum")
                .accommodation_d
        })
        .collect();
    for (ch, peak) in peak_d.iter().enumerate() {
        let focus = sim.calib.vergence_d(ch);
        assert!(
            (peak - focus).abs() < 0.03,
            "channel {ch}: S_5 peaks at {peak:.3} D, the lens focuses at {focus:.3} D"
        );
    }
    assert!(peak_d[0] > peak_d[1] && peak_d[1] > peak_d[2], "{peak_d:?}");
}
