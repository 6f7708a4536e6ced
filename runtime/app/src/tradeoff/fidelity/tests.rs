//! Tests of the fidelity study's model pieces.

use super::*;

#[test]
fn five_point_rule_integrates_the_normal_moments() {
    let n = spectral_nodes(5);
    let moment = |k: i32| n.iter().map(|(x, w)| w * x.powi(k)).sum::<f64>();
    assert!((moment(0) - 1.0).abs() < 1e-12);
    assert!(moment(1).abs() < 1e-12);
    assert!((moment(2) - 1.0).abs() < 1e-12);
    assert!((moment(4) - 3.0).abs() < 1e-12);
    assert!((moment(8) - 105.0).abs() < 1e-9);
    assert_eq!(spectral_nodes(1), vec![(0.0, 1.0)]);
}

#[test]
fn zero_shift_is_the_calibration_and_dispersion_is_normal() {
    let c = Calibration::default_embedded().expect("calib");
    assert_eq!(shifted_calibration(&c, 0.0).channels, c.channels);
    let (_, b) = cauchy_fit(&c);
    assert!(b > 0.0, "index falls with wavelength");
    let up = shifted_calibration(&c, 1.0);
    for (a, z) in c.channels.iter().zip(&up.channels) {
        assert!(z.wavelength_m > a.wavelength_m && z.index < a.index);
    }
}

fn ring_psf(window: usize) -> Psf {
    let c = (window / 2) as isize;
    let mut cells: Vec<f64> = (0..window * window)
        .map(|i| {
            let (x, y) = ((i % window) as isize - c, (i / window) as isize - c);
            1.0 / (1.0 + (x * x + y * y) as f64)
        })
        .collect();
    let s: f64 = cells.iter().sum();
    cells.iter_mut().for_each(|v| *v *= 0.98 / s);
    Psf {
        window,
        cells,
        veil: 0.02,
    }
}

#[test]
fn shrinking_keeps_the_energy_and_meets_the_target() {
    let p = ring_psf(41);
    let s = shrink_window(&p, 0.9);
    assert!(s.window < 41 && s.window % 2 == 1);
    let total = s.cells.iter().sum::<f64>() + s.veil;
    assert!((total - 1.0).abs() < 1e-12);
    assert!(s.cells.iter().sum::<f64>() >= 0.9 - 1e-12);
    let smaller = shrink_window(&p, 0.0);
    assert_eq!(smaller.window, 1);
    // A target the window cannot hold keeps the whole window.
    assert_eq!(shrink_window(&p, 0.999).window, 41);
}

#[test]
fn mixing_centres_windows_and_conserves_energy() {
    let m = mix(&[(ring_psf(5), 0.25), (ring_psf(9), 0.75)]);
    assert_eq!(m.window, 9);
    assert!((m.cells.iter().sum::<f64>() + m.veil - 1.0).abs() < 1e-12);
    let peak = m.cells.iter().copied().fold(0.0, f64::max);
    assert_eq!(m.cells[4 * 9 + 4], peak);
}

#[test]
fn one_arcmin_perception_of_a_point_psf_is_the_display_image() {
    let mut cells = vec![0.0; 9];
    cells[4] = 1.0;
    let psf = Psf {
        window: 3,
        cells,
        veil: 0.0,
    };
    let planes: Vec<Vec<f32>> = (0..3)
        .map(|c| {
            (0..64)
                .map(|i| ((i * (c + 2)) % 11) as f32 / 10.0)
                .collect()
        })
        .collect();
    let im = Image::from_planes(8, 8, planes);
    let out = perceive_one_arcmin(&im, &[psf.clone(), psf.clone(), psf]);
    let up = im.up2();
    for (a, b) in out.data().iter().zip(up.data().iter()) {
        assert!((a - b).abs() < 1e-5);
    }
}
