//! Golden vectors shared with the Python trainer (tests/golden/vectors.json):
//! small PSFs of the three-lens DOE at a few wavelengths and depths, the lens
//! alone, the target blur, and a small perceived image with its target, all
//! with the exact sampling that produced them, so any implementation of
//! docs/model.md can reproduce them. Written by `examples/make_golden.rs`.

use serde_json::{Value, json};

use crate::propagate::mft_cells;
use crate::pupil::{PupilGrid, pupil_field};
use crate::sim::{Image, perceive};
use crate::{HeightMap, Psf};
use nedrt_core::calib::Calibration;

/// PSF window (cells) and sub-samples per cell axis of the vectors.
pub const WINDOW: usize = 31;
pub const SUB_SAMPLES: usize = 4;
/// Side of the small input image (display pixels).
pub const IMAGE_SIDE: usize = 16;

/// The input image of the perceived-image vector: smooth gradients plus a
/// sharp edge and a bright dot in each channel.
pub fn input_image() -> Image {
    let n = IMAGE_SIDE;
    let planes = (0..3)
        .map(|c| {
            (0..n * n)
                .map(|i| {
                    let (x, y) = ((i % n) as f32, (i / n) as f32);
                    let edge = if x + c as f32 > 8.0 { 0.6 } else { 0.1 };
                    let dot = if (x - 4.0).abs() < 1.0 && (y - 11.0).abs() < 1.0 {
                        0.3
                    } else {
                        0.0
                    };
                    (edge + 0.02 * y + dot).min(1.0)
                })
                .collect()
        })
        .collect();
    Image::from_planes(n, n, planes)
}

struct Entry {
    channel: usize,
    accommodation_d: Option<f64>,
    psi_rad: f64,
    with_doe: bool,
}

fn psf_on_doe_grid(calib: &Calibration, doe: &HeightMap, e: &Entry) -> Psf {
    let grid: PupilGrid = doe.grid();
    let phase = e.with_doe.then(|| doe.phase_on(grid, calib, e.channel));
    let q = pupil_field(grid, calib.aperture_radius_m, e.psi_rad, phase.as_deref());
    let lambda = calib.channels[e.channel].wavelength_m;
    let cells = mft_cells(
        &q,
        grid,
        lambda,
        WINDOW,
        calib.retinal_step_rad(),
        SUB_SAMPLES,
    );
    let veil = 1.0 - cells.iter().sum::<f64>();
    Psf {
        window: WINDOW,
        cells,
        veil,
    }
}

fn planes_json(im: &Image) -> Value {
    json!(im.planes().collect::<Vec<_>>())
}

/// Builds the golden vectors for a calibration (the default one is shipped).
pub fn vectors(calib: &Calibration) -> Value {
    let doe = HeightMap::three_lens_init(calib, calib.doe_design_pitch_m);
    let ch = |name: &str| {
        calib
            .channels
            .iter()
            .position(|c| c.name == name)
            .unwrap_or(0)
    };
    let mut entries = Vec::new();
    for (name, d) in [
        ("R", 0.5),
        ("G", 0.5),
        ("G", 1.0),
        ("B", 2.5),
        ("R", 1.0),
        ("B", 1.0),
    ] {
        let c = ch(name);
        entries.push(Entry {
            channel: c,
            accommodation_d: Some(d),
            psi_rad: calib.psi_rad(c, d),
            with_doe: true,
        });
    }
    let g = ch("G");
    entries.push(Entry {
        channel: g,
        accommodation_d: Some(1.0),
        psi_rad: calib.psi_rad(g, 1.0),
        with_doe: false,
    });
    for c in 0..calib.channels.len() {
        entries.push(Entry {
            channel: c,
            accommodation_d: None,
            psi_rad: calib.target_blur_psi_rad,
            with_doe: false,
        });
    }
    let psfs: Vec<Psf> = entries
        .iter()
        .map(|e| psf_on_doe_grid(calib, &doe, e))
        .collect();
    let psf_json: Vec<Value> = entries
        .iter()
        .zip(&psfs)
        .map(|(e, p)| {
            let c = &calib.channels[e.channel];
            json!({
                "channel": c.name, "wavelength_m": c.wavelength_m, "index": c.index,
                "accommodation_d": e.accommodation_d, "psi_rad": e.psi_rad,
                "optics": if e.with_doe { "lens+doe" } else { "lens" },
                "window": WINDOW, "sub_samples": SUB_SAMPLES,
                "cells": p.cells, "veil": p.veil,
            })
        })
        .collect();

    // Perceived image at 1.0 D through lens + DOE and its target (h_b blur).
    let at = 1.0;
    let system: Vec<Psf> = (0..3)
        .map(|c| {
            psf_on_doe_grid(
                calib,
                &doe,
                &Entry {
                    channel: c,
                    accommodation_d: Some(at),
                    psi_rad: calib.psi_rad(c, at),
                    with_doe: true,
                },
            )
        })
        .collect();
    let blur: Vec<Psf> = psfs[psfs.len() - 3..].to_vec();
    let input = input_image();
    let perceived = perceive(&input, &system);
    let target = perceive(&input, &blur);

    let probe: Vec<Value> = [
        (0usize, 0usize),
        (834, 834),
        (834, 1000),
        (100, 834),
        (1200, 1500),
        (1667, 3),
    ]
    .iter()
    .filter(|(i, j)| *i < doe.samples && *j < doe.samples)
    .map(|&(i, j)| json!([i, j, doe.height_m[i * doe.samples + j]]))
    .collect();
    json!({
        "description": "nedrt golden vectors (optics.md): PSFs of the three-lens DOE, the lens and the target blur, and a perceived image",
        "generator": format!("nedrt {} examples/make_golden.rs", env!("CARGO_PKG_VERSION")),
        "calibration": calib.source,
        "conventions": {
            "pupil_grid": "square, N = round-up(2r/Δs) + 1 samples at s_n = (n − (N−1)/2)·Δs, the DOE's own grid (no resampling)",
            "aperture": "A = clamp((r − ρ)/Δs + 1/2, 0, 1)",
            "pupil": "Q = A·exp(j(Φ_λ + Ψ·ρ²)), ρ² = (s² + t²)/r², Φ_λ = 2π(n_λ − 1)·d/λ",
            "doe": "three-lens initialisation, d = wrap(arg Σ_i exp(−jΨ_λ0(D_i)ρ²), [0, 2π))·λ0/(2π(n_λ0 − 1))",
            "psf": "U(θ) = Σ Q exp(−j2π(sθx + tθy)/λ); cell = Σ over sub×sub midpoints of |U|²·(Δθ/sub)²·Δs²/(λ²·Σ|Q|²); window cells centred on the axis at (c − (W−1)/2)·Δθ; sub-sample i of a cell at offset ((i + 1/2)/sub − 1/2)·Δθ",
            "veil": "1 − Σ cells: light outside the window, added uniformly as veil·mean(input)",
            "perceived": "up2(input) ∗ h (symmetric half-sample padding by the kernel half-width, output cropped) + veil·mean(input), per channel",
            "image_layout": "planes[channel][row·width + column], channels R, G, B",
        },
        "retinal_step_rad": calib.retinal_step_rad(),
        "aperture_radius_m": calib.aperture_radius_m,
        "doe": { "pitch_m": doe.pitch_m, "samples": doe.samples, "probe_row_col_height_m": probe },
        "psfs": psf_json,
        "perceived": {
            "accommodation_d": at, "optics": "lens+doe",
            "width": IMAGE_SIDE, "height": IMAGE_SIDE,
            "input": planes_json(&input),
            "perceived": planes_json(&perceived),
            "target": planes_json(&target),
            "system_veil": system.iter().map(|p| p.veil).collect::<Vec<_>>(),
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The committed vectors are what the code computes now: a change to the
    /// optics that moves them must regenerate them on purpose
    /// (`cargo run --release --example make_golden`) and say why.
    #[test]
    fn committed_vectors_match_the_code() {
        let committed: Value =
            serde_json::from_str(include_str!("../../../tests/golden/vectors.json"))
                .expect("tests/golden/vectors.json");
        let now = vectors(&Calibration::default_embedded().expect("calib"));
        let (a, b) = (&committed["psfs"], &now["psfs"]);
        assert_eq!(a.as_array().map(Vec::len), b.as_array().map(Vec::len));
        for (pa, pb) in a
            .as_array()
            .expect("psfs")
            .iter()
            .zip(b.as_array().expect("psfs"))
        {
            let ca: Vec<f64> = serde_json::from_value(pa["cells"].clone()).expect("cells");
            let cb: Vec<f64> = serde_json::from_value(pb["cells"].clone()).expect("cells");
            let peak = ca.iter().cloned().fold(0.0, f64::max);
            for (x, y) in ca.iter().zip(&cb) {
                assert!(
                    (x - y).abs() <= 1e-9 * peak,
                    "{} {}: {x} vs {y}",
                    pa["channel"],
                    pa["psi_rad"]
                );
            }
        }
        for key in ["perceived", "target"] {
            let pa: Vec<Vec<f32>> =
                serde_json::from_value(committed["perceived"][key].clone()).expect(key);
            let pb: Vec<Vec<f32>> =
                serde_json::from_value(now["perceived"][key].clone()).expect(key);
            for (x, y) in pa.iter().flatten().zip(pb.iter().flatten()) {
                assert!((x - y).abs() < 1e-5, "{key}: {x} vs {y}");
            }
        }
    }
}
