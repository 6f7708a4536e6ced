//! Golden vectors of the radial path for the trainer's radial model
//! (tests/golden/radial.json, written by `examples/make_radial_golden.rs`):
//! the three-lens DOE of the default calibration as a radial profile at the
//! design pitch, and a few PSFs of it and of the lens alone, each by
//! nedrt's 2-D exact path at a ≈ 3 µm pupil step, by the radial path at a
//! ≈ 3 µm step, and by the radial path on the profile's own nodes (Δρ = the
//! design pitch, the discretisation a trainer parameterised at those nodes
//! uses). Every number needed to reproduce them is in the file.
//!
//! Layout of the JSON (all lengths in metres, angles in radians):
//! - `window`: W (odd); `cells` arrays are W×W, row-major, rows along θy,
//!   cell (i, j) centred at ((j − (W−1)/2)·Δθ, (i − (W−1)/2)·Δθ), Δθ =
//!   `retinal_step_rad`; each the fraction of the light through the aperture
//!   falling in the cell; `veil` = 1 − Σ cells.
//! - `doe`: `profile` "radial", `pitch_m`, `samples` N, `height_m` (N values,
//!   sample n at ρ = (n + ½)·pitch), `max_height_m`, the interpolation rule.
//! - `psfs[]`: `channel`, `wavelength_m`, `index`, `accommodation_d`,
//!   `psi_rad`, `optics` ("lens+doe" or "lens"), and one object per
//!   propagator run — `two_d`, `radial`, `radial_design_nodes` — each with
//!   `propagator`, `pupil_step_m`, `pupil_samples` (grid side, or radial
//!   nodes), `cells`, `veil`; plus `max_abs_radial_minus_two_d_of_peak`.

use serde_json::{Value, json};

use super::doe::HeightMap;
use super::propagate::{crop_centred, exact_period_cells};
use super::pupil::{PupilGrid, pupil_field};
use super::radial::{ANNULI_PER_CELL, RadialGrid, WindowCells, angular_density, pupil_profile};
use super::sampling::channel_sampling;
use super::{OpticsError, Psf};
use nedrt_core::calib::Calibration;

/// PSF window of the vectors (cells): the trainer's CPU preset's window.
pub const WINDOW: usize = 61;
/// Pupil step both paths are run at (at most; the 2-D path rounds it down
/// to a whole period, the radial path to r / ⌈r / step⌉), metres.
pub const PUPIL_STEP_M: f64 = 3e-6;

/// One PSF of the vectors: channel name, accommodation (D), with the DOE.
const ENTRIES: [(&str, f64, bool); 5] = [
    ("G", 0.5, true),
    ("G", 1.5, true),
    ("B", 3.0, true),
    ("R", 0.0, true),
    ("G", 1.5, false),
];

/// A PSF by one propagator, with the step it ran at.
struct Run {
    propagator: &'static str,
    step_m: f64,
    samples: usize,
    psf: Psf,
}

/// 10 significant digits: far below any tolerance, a smaller file.
fn round(v: f64) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let scale = 10f64.powi(9 - v.abs().log10().floor() as i32);
    (v * scale).round() / scale
}

fn run_json(r: &Run) -> Value {
    json!({
        "propagator": r.propagator, "pupil_step_m": r.step_m, "pupil_samples": r.samples,
        "cells": r.psf.cells.iter().map(|v| round(*v)).collect::<Vec<_>>(),
        "veil": r.psf.veil,
    })
}

fn with_veil(cells: Vec<f64>) -> Psf {
    let veil = 1.0 - cells.iter().sum::<f64>();
    Psf {
        window: WINDOW,
        cells,
        veil,
    }
}

/// The 2-D exact path on the profile's own surface (d(√(s² + t²)) at every
/// grid sample), at the whole-period step just under [`PUPIL_STEP_M`].
fn two_d(
    calib: &Calibration,
    doe: Option<&HeightMap>,
    ch: usize,
    psi: f64,
) -> Result<Run, OpticsError> {
    let s = channel_sampling(calib, ch, PUPIL_STEP_M, WINDOW)?;
    let grid: PupilGrid = s.grid.into();
    let phase = doe.map(|d| d.phase_on(grid, calib, ch));
    let q = pupil_field(grid, calib.aperture_radius_m, psi, phase.as_deref());
    let lambda = calib.channels[ch].wavelength_m;
    let period = exact_period_cells(&q, grid, lambda, calib.retinal_step_rad())
        .ok_or_else(|| OpticsError::BadSpec("period is not whole".into()))?;
    Ok(Run {
        propagator: "2d",
        step_m: grid.step_m,
        samples: grid.samples,
        psf: with_veil(crop_centred(&period, s.period_cells, WINDOW)),
    })
}

/// The radial path on `grid` (its nodes, and the DOE's Keys profile there).
fn radial(
    calib: &Calibration,
    doe: Option<&HeightMap>,
    ch: usize,
    psi: f64,
    grid: RadialGrid,
    propagator: &'static str,
) -> Result<Run, OpticsError> {
    let phase = match doe {
        Some(d) => Some(
            d.phase_at_radii(&grid.sample_radii_m(), calib, ch)
                .ok_or_else(|| OpticsError::BadSpec("the DOE is not radial".into()))?,
        ),
        None => None,
    };
    let q = pupil_profile(grid, psi, phase.as_deref());
    let cells = WindowCells::new((WINDOW - 1) / 2, calib.retinal_step_rad(), ANNULI_PER_CELL);
    let density = angular_density(
        grid,
        calib.channels[ch].wavelength_m,
        &[q],
        &cells.angles_rad(),
    );
    Ok(Run {
        propagator,
        step_m: grid.step_m,
        samples: grid.nodes(),
        psf: with_veil(cells.cells(&density[0])),
    })
}

fn max_difference_of_peak(a: &Psf, b: &Psf) -> f64 {
    let peak = b.cells.iter().cloned().fold(0.0, f64::max);
    a.cells
        .iter()
        .zip(&b.cells)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
        / peak
}

/// Builds the radial golden vectors for a calibration (the default one is
/// shipped). The 2-D runs take minutes on two cores.
pub fn vectors(calib: &Calibration) -> Result<Value, OpticsError> {
    let doe = HeightMap::three_lens_radial(calib, calib.doe_design_pitch_m);
    let r = calib.aperture_radius_m;
    let fine = RadialGrid::with_nodes(r, (r / PUPIL_STEP_M - 1e-9).ceil() as usize);
    let nodes = RadialGrid {
        step_m: doe.pitch_m,
        radius_m: r,
    };
    let mut psfs = Vec::new();
    for (name, d, with_doe) in ENTRIES {
        let ch = calib
            .channels
            .iter()
            .position(|c| c.name == name)
            .ok_or_else(|| OpticsError::BadSpec(format!("no channel {name}")))?;
        let psi = calib.psi_rad(ch, d);
        let element = with_doe.then_some(&doe);
        let runs = [
            two_d(calib, element, ch, psi)?,
            radial(calib, element, ch, psi, fine, "radial")?,
            radial(calib, element, ch, psi, nodes, "radial")?,
        ];
        let c = &calib.channels[ch];
        psfs.push(json!({
            "channel": c.name, "wavelength_m": c.wavelength_m, "index": c.index,
            "accommodation_d": d, "psi_rad": psi,
            "optics": if with_doe { "lens+doe" } else { "lens" },
            "two_d": run_json(&runs[0]),
            "radial": run_json(&runs[1]),
            "radial_design_nodes": run_json(&runs[2]),
            "max_abs_radial_minus_two_d_of_peak": max_difference_of_peak(&runs[1].psf, &runs[0].psf),
        }));
    }
    Ok(json!({
        "description": "nedrt radial golden vectors: the three-lens DOE as a radial profile and PSFs by the 2-D exact path and the radial (Hankel) path",
        "generator": format!("nedrt {} examples/make_radial_golden.rs", env!("CARGO_PKG_VERSION")),
        "calibration": calib.source,
        "layout": "cells: window×window, row-major, rows along θy, cell (i, j) centred at ((j − (W−1)/2)·Δθ, (i − (W−1)/2)·Δθ); fractions of the light through the aperture; veil = 1 − Σ cells",
        "conventions": {
            "doe": "heights d_n at ρ_n = (n + 1/2)·pitch_m; between samples Keys cubic (a = −1/2) in ρ/pitch − 1/2 with the half-sample even extension at the axis (sample −1−k = sample k) and the last sample repeated beyond the end, clamped to [0, max_height_m]; three-lens: d = wrap(arg Σ_i exp(−jΨ_λ0(D_i)ρ²/r²), [0, 2π))·λ0/(2π(n_λ0 − 1))",
            "phase": "Φ_λ = 2π(n_λ − 1)·d/λ; pupil Q = exp(j(Φ_λ + Ψ·ρ²/r²)) inside ρ < r",
            "two_d": "nedrt's 2-D exact path: square grid N = ceil(2r/Δs) + 2 at s_n = (n − (N−1)/2)·Δs, Δs = λ/(P·Δθ) for the smallest 5-smooth whole period P with Δs ≤ 3 µm, A = clamp((r − ρ)/Δs + 1/2, 0, 1), heights d(√(s² + t²)) on the grid; every cell the exact integral of the sampled transform over its square (docs/optics-model.md)",
            "radial": "U(t) = Σ_n (Q_n − Q_r)·w_n·J0(2π ρ_n t/λ) + Q_r·2π r² J1(x)/x, x = 2π r t/λ, ρ_n = (n + 1/2)Δρ for every n with nΔρ < r, w_n = π(min((n+1)Δρ, r)² − (nΔρ)²), Q_r = Q at ρ = r; p(t) = |U|²/(λ² Σ|Q_n|² w_n); cell = (4·C(m) − C(m/2))/3 with C(m) = Σ_i p((i + 1/2)δ)·area(cell ∩ annulus [iδ, (i+1)δ)), δ = Δθ/m, m = annuli_per_cell, areas exact",
            "radial_pupil_step": "radial: Δρ = r/ceil(r/3 µm); radial_design_nodes: Δρ = doe.pitch_m (the profile's own nodes, the last annulus cut at r)",
        },
        "retinal_step_rad": calib.retinal_step_rad(),
        "aperture_radius_m": r,
        "window": WINDOW,
        "annuli_per_cell": ANNULI_PER_CELL,
        "doe": {
            "profile": "radial", "pitch_m": doe.pitch_m, "samples": doe.samples,
            "max_height_m": doe.max_height_m, "material": doe.material,
            "design_wavelength_m": doe.design_wavelength_m, "height_m": doe.height_m,
        },
        "psfs": psfs,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn committed() -> Value {
        serde_json::from_str(include_str!("../../../tests/golden/radial.json"))
            .expect("tests/golden/radial.json")
    }

    fn cells(v: &Value) -> Vec<f64> {
        serde_json::from_value(v["cells"].clone()).expect("cells")
    }

    /// The committed profile and radial PSFs are what the code computes now
    /// (the 2-D runs take minutes; the 2-D path has its own tests), and in
    /// the file the two paths agree within 0.5 % of the peak.
    #[test]
    fn committed_radial_vectors_match_the_code_and_the_2d_path() {
        let calib = Calibration::default_embedded().expect("calib");
        let file = committed();
        let doe = HeightMap::three_lens_radial(&calib, calib.doe_design_pitch_m);
        let heights: Vec<f64> =
            serde_json::from_value(file["doe"]["height_m"].clone()).expect("heights");
        assert_eq!(heights.len(), doe.height_m.len());
        assert!(
            heights
                .iter()
                .zip(&doe.height_m)
                .all(|(a, b)| (a - b).abs() < 1e-18)
        );
        let r = calib.aperture_radius_m;
        let fine = RadialGrid::with_nodes(r, (r / PUPIL_STEP_M - 1e-9).ceil() as usize);
        let entries = file["psfs"].as_array().expect("psfs");
        assert_eq!(entries.len(), ENTRIES.len());
        for (e, (name, d, with_doe)) in entries.iter().zip(ENTRIES) {
            let ch = calib
                .channels
                .iter()
                .position(|c| c.name == name)
                .expect("channel");
            let now = radial(
                &calib,
                with_doe.then_some(&doe),
                ch,
                calib.psi_rad(ch, d),
                fine,
                "radial",
            )
            .expect("radial");
            let (radial_file, two_d_file) = (cells(&e["radial"]), cells(&e["two_d"]));
            let peak = two_d_file.iter().cloned().fold(0.0, f64::max);
            for (a, b) in now.psf.cells.iter().zip(&radial_file) {
                assert!((a - b).abs() <= 1e-9 * peak, "{name} {d}: {a} vs {b}");
            }
            let diff = radial_file
                .iter()
                .zip(&two_d_file)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(diff < 5e-3 * peak, "{name} {d}: {}", diff / peak);
            let veil = |v: &Value| v["veil"].as_f64().expect("veil");
            assert!((veil(&e["radial"]) - veil(&e["two_d"])).abs() < 2e-3);
        }
    }
}
