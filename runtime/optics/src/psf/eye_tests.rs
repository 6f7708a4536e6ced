//! The eye's pupil in the PSF planner (docs/model.md §4a) against closed
//! forms: in focus, a pupil smaller than the eyepiece's aperture gives the
//! Airy pattern of the pupil (radial and 2-D paths); off axis, a pupil
//! shifted by e·tanθ over a diffractive lens of power P sees the prism
//! P·e·tanθ (Prentice's rule), and the lens alone sees no shift at all.

use std::f64::consts::PI;

use super::radial_tests::psfs;
use super::*;
use crate::doe::Profile;

fn eye(pupil_mm: f64, relief_mm: f64, field_deg: f64, two_d: bool) -> Calibration {
    let shipped = nedrt_core::calib::DEFAULT_CALIBRATION_TOML;
    let text = format!(
        "{}\n[eye]\npupil_diameter_mm = {pupil_mm}\nrelief_mm = {relief_mm}\nfield_deg = {field_deg}\n",
        &shipped[..shipped.find("\n[eye]").unwrap_or(shipped.len())]
    );
    let mut c = Calibration::from_toml(&text, "eye.toml", None).expect("calibration");
    if two_d {
        c.simulation.propagator = PropagatorSetting::TwoD;
    }
    c
}

/// The Airy pattern of a pupil of radius `a_m` integrated over each cell of
/// the central `w`×`w` (24×24 midpoint samples a cell): the share of the light.
fn airy_cells(a_m: f64, lambda: f64, dtheta: f64, w: usize) -> Vec<f64> {
    let sub = 24;
    let peak = PI * a_m * a_m / (lambda * lambda);
    let h = (w / 2) as f64;
    let mut out = vec![0.0; w * w];
    for (k, v) in out.iter_mut().enumerate() {
        let (cy, cx) = ((k / w) as f64 - h, (k % w) as f64 - h);
        let mut sum = 0.0;
        for i in 0..sub {
            for j in 0..sub {
                let ty = (cy + (i as f64 + 0.5) / sub as f64 - 0.5) * dtheta;
                let tx = (cx + (j as f64 + 0.5) / sub as f64 - 0.5) * dtheta;
                let x = 2.0 * PI * a_m * tx.hypot(ty) / lambda;
                sum += if x == 0.0 {
                    1.0
                } else {
                    (2.0 * libm::j1(x) / x).powi(2)
                };
            }
        }
        *v = peak * sum * (dtheta / sub as f64).powi(2);
    }
    out
}

#[test]
fn in_focus_a_small_pupil_gives_its_own_airy_pattern() {
    for two_d in [false, true] {
        let c = eye(3.0, 0.0, 0.0, two_d);
        let g = 1;
        let set = psfs(
            &c,
            &[PsfSpec {
                channel: g,
                psi_rad: 0.0,
            }],
            None,
        );
        let want = airy_cells(1.5e-3, c.channels[g].wavelength_m, c.retinal_step_rad(), 21);
        let psf = &set.psfs[0];
        let got = crop_centred(&psf.cells, psf.window, 21);
        let peak = want.iter().cloned().fold(0.0, f64::max);
        let worst = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            worst < 2e-3 * peak,
            "{}: largest deviation {:.2e} of the peak",
            set.report.propagator,
            worst / peak
        );
        // The eyepiece's 10 mm pupil would put 2.2× the light in the centre.
        assert!((got[10 * 21 + 10] - want[10 * 21 + 10]).abs() < 0.01 * peak);
    }
}

/// A diffractive lens of power `power_d` at the design wavelength as a
/// radial profile at `pitch_m`: phase −(π/λ0) P ρ² wrapped to one wave.
fn diffractive_lens(c: &Calibration, power_d: f64, pitch_m: f64) -> HeightMap {
    let lambda0 = c.channels[c.design_channel].wavelength_m;
    let wave = c.doe_wave_height_m();
    let samples = (c.aperture_radius_m / pitch_m).ceil() as usize + 1;
    let height_m = (0..samples)
        .map(|n| {
            let rho = (n as f64 + 0.5) * pitch_m;
            (-PI / lambda0 * power_d * rho * rho).rem_euclid(2.0 * PI) / (2.0 * PI) * wave
        })
        .collect();
    HeightMap {
        profile: Profile::Radial,
        samples,
        pitch_m,
        height_m,
        max_height_m: wave,
        levels: 0,
        material: c.material_name.clone(),
        design_wavelength_m: lambda0,
        description: format!("{power_d} D diffractive lens"),
    }
}

/// The centroid of the PSF's brightest 7×7 cells, in cells from the axis (x, y).
fn peak_centroid(psf: &Psf) -> (f64, f64) {
    let w = psf.window;
    let k = (0..w * w)
        .max_by(|&a, &b| psf.cells[a].total_cmp(&psf.cells[b]))
        .unwrap_or(0);
    let (py, px) = ((k / w) as i64, (k % w) as i64);
    let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
    for y in py - 3..=py + 3 {
        for x in px - 3..=px + 3 {
            let v = psf.cells[(y as usize) * w + x as usize];
            sx += v * x as f64;
            sy += v * y as f64;
            s += v;
        }
    }
    let h = (w / 2) as f64;
    (sx / s - h, sy / s - h)
}

#[test]
fn off_axis_the_pupil_sees_the_prism_of_its_decentration() {
    // Prentice's rule: a lens of power P seen through a pupil decentred by
    // c deviates the beam by P·c towards its axis; c = e·tanθ.
    let power_d = 2.0;
    let (relief_mm, field_deg) = (15.0, 10.0);
    let c = eye(3.0, relief_mm, field_deg, false);
    let g = c.design_channel;
    let doe = diffractive_lens(&c, power_d, 3e-6);
    // In focus for the lens's first order: image vergence V − P.
    let spec = PsfSpec {
        channel: g,
        psi_rad: c.psi_rad(g, c.vergence_d(g) - power_d),
    };
    let set = psfs(&c, &[spec], Some(&doe));
    assert_eq!(set.report.propagator, Propagator::TwoD);
    let (x, y) = peak_centroid(&set.psfs[0]);
    let decentration_m = relief_mm * 1e-3 * field_deg.to_radians().tan();
    let want = -power_d * decentration_m / c.retinal_step_rad();
    assert!(
        (x - want).abs() < 0.5 && y.abs() < 0.1,
        "peak at ({x:.2}, {y:.2}) cells, Prentice {want:.2}"
    );
    // On axis the same element does not deviate.
    let on_axis = eye(3.0, relief_mm, 0.0, true);
    let (x0, y0) = peak_centroid(&psfs(&on_axis, &[spec], Some(&doe)).psfs[0]);
    assert!(x0.abs() < 0.1 && y0.abs() < 0.1, "({x0}, {y0})");
}

#[test]
fn off_axis_the_lens_alone_blurs_as_on_axis() {
    // The eye focuses about its own pupil's centre, on the chief ray: the
    // lens alone seen through a decentred pupil has the on-axis defocus, so
    // away from vignetting the PSF is the on-axis one.
    let specs: Vec<PsfSpec> = [0.5, 1.5, 2.5]
        .iter()
        .map(|&d| PsfSpec {
            channel: 1,
            psi_rad: eye(3.0, 15.0, 0.0, true).psi_rad(1, d),
        })
        .collect();
    let on = psfs(&eye(3.0, 15.0, 0.0, true), &specs, None);
    // 10°: decentred 2.64 mm, the 2.93 mm stop well inside the 10 mm aperture.
    let off = psfs(&eye(3.0, 15.0, 10.0, true), &specs, None);
    // Equal but for where the stop's ramped edge falls on the grid (the
    // decentration is no whole number of steps): measured 6e-5 of the peak.
    let diff = max_difference_of_peak(&off, &on);
    assert!(diff < 2e-4, "{diff}");
    // 17°: decentred 4.59 mm, the eyepiece's rim cuts the stop: it is not.
    let rim = psfs(&eye(3.0, 15.0, 17.0, true), &specs, None);
    assert!(max_difference_of_peak(&rim, &on) > 0.01);
}

#[test]
fn a_vertical_field_is_the_horizontal_one_turned_a_quarter() {
    // The lens and a radial DOE are rotationally symmetric: the PSF looked
    // at 10° above the axis is the one 10° to its side, transposed; its
    // Prentice shift is vertical. (A field zone's PSFs: sim::zones.)
    let power_d = 2.0;
    let side = eye(3.0, 15.0, 10.0, false);
    let mut above = eye(3.0, 15.0, 0.0, true);
    above.eye.field_y_rad = 10f64.to_radians();
    let g = side.design_channel;
    let doe = diffractive_lens(&side, power_d, 3e-6);
    let spec = PsfSpec {
        channel: g,
        psi_rad: side.psi_rad(g, side.vergence_d(g) - power_d),
    };
    let (a, b) = (
        &psfs(&side, &[spec], Some(&doe)).psfs[0],
        &psfs(&above, &[spec], Some(&doe)).psfs[0],
    );
    assert_eq!(a.window, b.window);
    let w = a.window;
    let peak = a.cells.iter().copied().fold(0.0, f64::max);
    let worst = (0..w * w)
        .map(|k| (a.cells[k] - b.cells[(k % w) * w + k / w]).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-3 * peak, "{worst} of a {peak} peak");
    let (x, y) = peak_centroid(b);
    let want = -power_d * 15e-3 * 10f64.to_radians().tan() / side.retinal_step_rad();
    assert!(
        (y - want).abs() < 0.5 && x.abs() < 0.1,
        "({x:.2}, {y:.2}), want y {want:.2}"
    );
}
