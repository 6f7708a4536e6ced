//! Closed-form checks of the derived quantities (docs/model.md §3–§5, §19) and of the
//! validation messages.

use super::*;
use proptest::prelude::*;

fn default() -> Calibration {
    Calibration::default_embedded().expect("default calibration is valid")
}

fn with(edit: impl Fn(&str) -> String) -> Result<Calibration, CalibError> {
    Calibration::from_toml(&edit(DEFAULT_CALIBRATION_TOML), "test.toml", None)
}

/// The shipped calibration with its `[eye]` table replaced by `eye`.
fn with_eye(eye: &str) -> Result<Calibration, CalibError> {
    with(|s| {
        format!(
            "{}\n[eye]\n{eye}\n",
            &s[..s.find("\n[eye]").unwrap_or(s.len())]
        )
    })
}

#[test]
fn vergences_match_optics_md_section_2() {
    let c = default();
    assert!(
        (c.vergence_d(0) - 1.705).abs() < 1e-3,
        "V_R = {}",
        c.vergence_d(0)
    );
    assert!(
        (c.vergence_d(1) - 1.487).abs() < 1e-3,
        "V_G = {}",
        c.vergence_d(1)
    );
    assert!(
        (c.vergence_d(2) - 1.123).abs() < 1e-3,
        "V_B = {}",
        c.vergence_d(2)
    );
    let lca = c.vergence_d(0) - c.vergence_d(2);
    assert!(
        (lca - 0.58).abs() < 0.005,
        "longitudinal chromatic aberration {lca}"
    );
}

#[test]
fn psi_values_match_optics_md_section_3() {
    let c = default();
    assert!(
        (c.psi_rad(1, 1.5) - (-2.0)).abs() < 0.05,
        "{}",
        c.psi_rad(1, 1.5)
    );
    assert!(
        (c.psi_rad(0, 0.0) - 223.2).abs() < 0.05,
        "{}",
        c.psi_rad(0, 0.0)
    );
    assert!(
        (c.psi_rad(2, 3.0) - (-327.6)).abs() < 0.05,
        "{}",
        c.psi_rad(2, 3.0)
    );
    assert!((c.psi_for_vergence(1, 0.5) - 74.1).abs() < 0.05);
    let max = (0..3)
        .flat_map(|ch| [0.0, 3.0].map(|d| c.psi_rad(ch, d).abs()))
        .fold(0.0, f64::max);
    assert!((max - 328.0).abs() < 0.5, "largest |Ψ| over 0–3 D = {max}");
}

#[test]
fn retinal_step_and_wave_height() {
    let c = default();
    let arcmin = c.retinal_step_rad().to_degrees() * 60.0;
    assert!((arcmin - 0.5234).abs() < 1e-3, "Δθ = {arcmin} arcmin");
    assert!((c.doe_wave_height_m() * 1e6 - 1.150).abs() < 1e-3);
}

#[test]
fn depth_classification() {
    let c = default();
    assert!(c.is_main_depth(1.5));
    assert!(!c.is_main_depth(1.0));
    assert_eq!(
        c.evaluation_depths_d(),
        vec![0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
    );
    assert_eq!(c.depth_sweep_d(0.1).len(), 31);
}

#[test]
fn panel_beyond_focal_length_is_rejected_with_reason() {
    let e = with(|s| s.replace("lens_distance_mm = 28.57", "lens_distance_mm = 29.9")).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("test.toml"), "{msg}");
    assert!(msg.contains("panel.lens_distance_mm"), "{msg}");
    assert!(msg.contains("no virtual image"), "{msg}");
}

#[test]
fn negative_pitch_is_rejected() {
    let e = with(|s| s.replace("pixel_pitch_um = 8.7", "pixel_pitch_um = -8.7")).unwrap_err();
    assert!(e.to_string().contains("panel.pixel_pitch_um"), "{e}");
}

#[test]
fn unknown_key_is_rejected() {
    let e = with(|s| s.replace("[panel]", "[panel]\npixel_pich_um = 3")).unwrap_err();
    assert!(matches!(e, CalibError::Parse { .. }), "{e}");
    assert!(e.to_string().contains("pixel_pich_um"), "{e}");
}

#[test]
fn malformed_toml_names_the_file() {
    let e = with(|s| s.replace("[lens]", "[lens")).unwrap_err();
    assert!(
        e.to_string().starts_with("test.toml: malformed TOML"),
        "{e}"
    );
}

#[test]
fn depth_overlap_and_order_are_rejected() {
    let e = with(|s| {
        s.replace(
            "intermediate_d = [0.0, 1.0, 2.0, 3.0]",
            "intermediate_d = [0.0, 1.5]",
        )
    })
    .unwrap_err();
    assert!(e.to_string().contains("also a main depth"), "{e}");
    let e = with(|s| s.replace("main_d = [0.5, 1.5, 2.5]", "main_d = [1.5, 0.5]")).unwrap_err();
    assert!(e.to_string().contains("strictly increasing"), "{e}");
    let e = with(|s| s.replace("main_d = [0.5, 1.5, 2.5]", "main_d = [0.5, 4.5]")).unwrap_err();
    assert!(e.to_string().contains("outside depths.range_d"), "{e}");
}

#[test]
fn unknown_design_channel_is_rejected() {
    let e = with(|s| s.replace("design_channel = \"G\"", "design_channel = \"Y\"")).unwrap_err();
    assert!(e.to_string().contains("doe.design_channel"), "{e}");
}

#[test]
fn doe_file_resolves_against_the_calibration_folder() {
    let text = DEFAULT_CALIBRATION_TOML.replace("file = \"\"", "file = \"doe.safetensors\"");
    let c = Calibration::from_toml(&text, "x.toml", Some(Path::new("/some/dir"))).unwrap();
    assert_eq!(
        c.doe_file.as_deref(),
        Some(Path::new("/some/dir/doe.safetensors"))
    );
}

#[test]
fn fingerprint_tracks_optics_not_wiener() {
    let a = default();
    let b = with(|s| s.replace("ai_k = 0.01", "ai_k = 0.02")).unwrap();
    let c = with(|s| s.replace("aperture_radius_mm = 5.0", "aperture_radius_mm = 4.0")).unwrap();
    assert_eq!(a.optics_fingerprint(), b.optics_fingerprint());
    assert_ne!(a.optics_fingerprint(), c.optics_fingerprint());
}

#[test]
fn propagator_is_parsed_strictly() {
    assert_eq!(default().simulation.propagator, PropagatorSetting::Auto);
    let two_d = with(|s| s.replace("propagator = \"auto\"", "propagator = \"2d\"")).unwrap();
    assert_eq!(two_d.simulation.propagator, PropagatorSetting::TwoD);
    assert_ne!(default().optics_fingerprint(), two_d.optics_fingerprint());
    let e = with(|s| s.replace("propagator = \"auto\"", "propagator = \"hankel\"")).unwrap_err();
    assert!(e.to_string().contains("simulation.propagator"), "{e}");
}

proptest! {
    // Any single numeric value replaced by any float gives Ok or a clean error, never a panic.
    #[test]
    fn arbitrary_numbers_never_panic(line in 0usize..200, value in prop::num::f64::ANY) {
        let lines: Vec<&str> = DEFAULT_CALIBRATION_TOML.lines().collect();
        let i = line % lines.len();
        let edited: String = lines.iter().enumerate().map(|(j, l)| {
            if j == i && l.contains(" = ") && !l.trim_start().starts_with('#') {
                let key = l.split(" = ").next().unwrap_or("");
                format!("{key} = {value:?}\n")
            } else {
                format!("{l}\n")
            }
        }).collect();
        let _ = Calibration::from_toml(&edited, "p.toml", None);
    }

    // Arbitrary bytes in place of the file: an error, never a panic.
    #[test]
    fn arbitrary_text_never_panics(text in ".{0,400}") {
        let _ = Calibration::from_toml(&text, "p.toml", None);
    }
}

#[test]
fn the_panel_defaults_are_the_real_panel_and_bad_values_are_named() {
    let p = default().panel;
    assert_eq!((p.width_px, p.height_px), (1920, 1080));
    assert_eq!(p.refresh_hz, 90.0);
    assert_eq!(p.transfer_gamma, vec![2.2, 2.2, 2.2]);
    for (from, to, field, why) in [
        (
            "width_px = 1920",
            "width_px = 0",
            "panel.width_px",
            "1..=16384",
        ),
        (
            "height_px = 1080",
            "height_px = 99999",
            "panel.height_px",
            "1..=16384",
        ),
        (
            "refresh_hz = 90.0",
            "refresh_hz = 0.0",
            "panel.refresh_hz",
            "1–1000 Hz",
        ),
        (
            "refresh_hz = 90.0",
            "refresh_hz = nan",
            "panel.refresh_hz",
            "1–1000 Hz",
        ),
        (
            "transfer_gamma = [2.2, 2.2, 2.2]",
            "transfer_gamma = [2.2, 2.2]",
            "panel.transfer_gamma",
            "one exponent per primary",
        ),
        (
            "transfer_gamma = [2.2, 2.2, 2.2]",
            "transfer_gamma = [2.2, 9.0, 2.2]",
            "panel.transfer_gamma",
            "not a display gamma",
        ),
    ] {
        let e = with(|s| s.replace(from, to)).unwrap_err().to_string();
        assert!(e.contains(field) && e.contains(why), "{to}: {e}");
    }
    // A missing panel key is an error naming it, not a silent default.
    let e = with(|s| s.replace("refresh_hz = 90.0\n", ""))
        .unwrap_err()
        .to_string();
    assert!(e.contains("refresh_hz"), "{e}");
}

#[test]
fn the_small_test_panel_differs_from_the_default_only_in_its_panel() {
    let small = Calibration::load(Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/data/small-panel.toml"
    )))
    .expect("tests/data/small-panel.toml");
    let mut d = default();
    assert_eq!((small.panel.width_px, small.panel.height_px), (64, 48));
    d.panel = small.panel.clone();
    d.source = small.source.clone();
    assert_eq!(small, d);
}

#[test]
fn wiener_constants_must_be_positive_and_finite() {
    for bad in ["0.0", "-0.01", "nan", "inf"] {
        let e = with(|s| s.replace("ai_k = 0.031623", &format!("ai_k = {bad}")))
            .expect_err(bad)
            .to_string();
        assert!(e.contains("wiener.ai_k"), "{bad}: {e}");
    }
    let e = with(|s| s.replace("doe_k = 0.031623", "doe_k = 0"))
        .expect_err("zero")
        .to_string();
    assert!(e.contains("wiener.doe_k"), "{e}");
}

#[test]
fn eye_lca_is_thibos_1992_at_the_three_wavelengths() {
    // R(λ) = 1.68524 − 0.63346/(λ/µm − 0.21410) by hand at 600, 530, 450 nm
    // (0.043727, −0.320015, −1.000050 D), relative to the design's 530 nm.
    let c = with_eye("lca = \"thibos1992\"").unwrap();
    let expected = [0.363742, 0.0, -0.680035];
    for (ch, want) in expected.iter().enumerate() {
        let got = c.eye_lca_d(ch);
        assert!(
            (got - want).abs() < 2e-6,
            "channel {ch}: {got} D, want {want} D"
        );
        // It enters as a shift of the vergence the eye sees in focus.
        let focus = c.vergence_d(ch) + got;
        assert!(c.psi_rad(ch, focus).abs() < 1e-9);
    }
    // The published span: about 2.1 D from 400 to 700 nm; zero at
    // c + q/p = 590.0 nm (the sodium line the model refers to).
    let span = thibos_refraction_d(700e-9) - thibos_refraction_d(400e-9);
    assert!((span - 2.1038).abs() < 1e-3, "{span}");
    assert!(thibos_refraction_d(590.0e-9).abs() < 1e-4);
    // Off: the paper's eye, psi unchanged.
    let d = default();
    assert_eq!(d.eye, EyeSettings::default());
    assert_eq!(
        d.psi_rad(2, 1.0),
        d.psi_for_vergence(2, d.vergence_d(2) - 1.0)
    );
}

#[test]
fn the_eye_stop_is_the_pupil_projected_along_the_image_rays() {
    let c = with_eye("pupil_diameter_mm = 4.0\nrelief_mm = 15.0\nfield_deg = 20.0").unwrap();
    for ch in 0..3 {
        let stop = c
            .eye_stop(ch)
            .expect("a 4 mm pupil limits a 10 mm aperture");
        // Chief ray to the pupil's centre: e·tanθ; rim rays from the image
        // point at 1/V before the lens: r_eye·(1/V)/(1/V + e).
        assert!((stop.centre_m - 15e-3 * 20f64.to_radians().tan()).abs() < 1e-12);
        let z = 1.0 / c.vergence_d(ch);
        assert!((stop.radius_m - 2e-3 * z / (z + 15e-3)).abs() < 1e-12);
    }
    assert!(c.eye_stop_off_axis());
    // A pupil whose projection covers the aperture does not limit: the
    // paper's model exactly (and its cache keys).
    let wide = with_eye("pupil_diameter_mm = 11.0\nrelief_mm = 0.0").unwrap();
    assert!(wide.eye_stop(1).is_none() && !wide.eye_stop_off_axis());
    // The paper's eye keeps the fingerprint of a file without [eye].
    let explicit = with_eye("relief_mm = 12.0\nfield_deg = 10.0").unwrap();
    assert_eq!(
        explicit.optics_fingerprint(),
        default().optics_fingerprint()
    );
    assert_ne!(c.optics_fingerprint(), default().optics_fingerprint());
}

#[test]
fn bad_eye_fields_are_refused_by_name() {
    for (line, field) in [
        ("pupil_diameter_mm = 0.0", "eye.pupil_diameter_mm"),
        ("pupil_diameter_mm = 0.5", "eye.pupil_diameter_mm"),
        ("pupil_diameter_mm = 20.0", "eye.pupil_diameter_mm"),
        ("relief_mm = -1.0", "eye.relief_mm"),
        ("field_deg = 90.0", "eye.field_deg"),
        ("lca = \"sometimes\"", "eye.lca"),
        ("iris = 3", "iris"),
        // 30° at 15 mm: 8.7 mm off axis, past the 5 mm aperture and the pupil.
        (
            "pupil_diameter_mm = 3.0\nfield_deg = 30.0",
            "no light reaches the eye",
        ),
    ] {
        let e = with_eye(line).unwrap_err().to_string();
        assert!(e.contains("test.toml") && e.contains(field), "{line}: {e}");
    }
    // The command line's overrides go through the same checks.
    let mut c = default();
    let bad = EyeOverrides {
        pupil_diameter_mm: Some(Some(f64::NAN)),
        ..Default::default()
    };
    let e = bad.apply(&mut c).unwrap_err().to_string();
    assert!(
        e.contains("the command line") && e.contains("eye.pupil_diameter_mm"),
        "{e}"
    );
    let good = EyeOverrides {
        pupil_diameter_mm: Some(Some(3.0)),
        lca: Some(EyeLca::Thibos1992),
        ..Default::default()
    };
    good.apply(&mut c).unwrap();
    assert_eq!(c.eye.pupil_diameter_m, Some(3e-3));
    assert_eq!(c.eye.relief_m, 15e-3);
    // `Some(None)` takes a calibration's pupil away: the paper's eye.
    let paper = EyeOverrides {
        pupil_diameter_mm: Some(None),
        ..Default::default()
    };
    paper.apply(&mut c).unwrap();
    assert_eq!(c.eye.pupil_diameter_m, None);
    // The file names the model: "on" is the command line's word only.
    let e = with_eye("lca = \"on\"").unwrap_err().to_string();
    assert!(e.contains("eye.lca"), "{e}");
}
