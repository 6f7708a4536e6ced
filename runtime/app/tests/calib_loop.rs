//! The calibration's closed loop at a small size (issue 57): patterns,
//! synthetic captures through three built displays, PSFs recovered from
//! them, and the Wiener prefilter from the recovered PSFs scored against
//! the design's and the oracle's through the built optics.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use nedrt_app::calib_capture::Camera;
use nedrt_app::calib_synth::{SynthOptions, TRUTH_DIR};
use nedrt_app::{CommonOptions, calib_loop, calib_patterns, calib_psfs, calib_synth};
use nedrt_core::image::Image;
use nedrt_optics::bundle::PsfBundle;
use nedrt_optics::perturb::Perturbation;
use nedrt_optics::pixel::response_distance;
use nedrt_optics::sim::{Method, Simulator};
use nedrt_stages::preprocess::Prefilter;

/// The recovered PSFs' largest distance from the true ones, relative L2
/// of the pixel responses (docs/calibration.md §5): the camera's noise
/// after 16 frames and 8 dots leaves about 1 %, the decentred cores 2 %;
/// interpolating each dot twice (the extraction before its least-squares
/// fit) gave 6–27 %, so a broken extraction fails.
const MAX_DISTANCE: f64 = 0.04;
/// The share of the oracle's gain the recovered PSFs must keep (issue 57).
const MIN_RECOVERED_SHARE: f64 = 0.9;
/// A gain of the oracle over the design this small is nothing to keep:
/// the recovered PSFs' score differs from the oracle's by up to 0.009 dB
/// either way, the same over noise seeds to 0.001 dB (docs/calibration.md
/// §5). There the recovered score must lie within this of the oracle's.
const GAIN_RESOLUTION_DB: f64 = 0.005;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn images() -> Vec<Image> {
    ["airport.png", "coast.png"]
        .iter()
        .map(|f| {
            let img = nedrt_core::image_io::load(&repo().join("data/images/val").join(f))
                .expect("a validation image")
                .image;
            img.crop(120, 120, 96, 96)
        })
        .collect()
}

/// What knowing the built optics earns each prefilter (no captures).
#[test]
#[ignore = "an exploration: cargo test --release -p nedrt-app --test calib_loop -- --ignored --nocapture"]
fn oracle_gains() {
    let dir = tempfile::tempdir().expect("tmp");
    let common = CommonOptions {
        calib: Some(
            std::env::var("NEDRT_LOOP_CALIB")
                .map(PathBuf::from)
                .unwrap_or(repo().join("tests/data/calib-loop.toml")),
        ),
        cache_dir: Some(dir.path().join("cache")),
        ..Default::default()
    };
    let design = Simulator::new(common.calibration().expect("calib"), None, common.cache())
        .expect("the design");
    let imgs = images();
    let depths: Vec<f64> = (0..=5).map(|i| i as f64 * 0.5).collect();
    for p in cases() {
        let built = Simulator::with_doe(
            p.1.calibration(&design.calib),
            p.1.doe(&design.doe, design.calib.doe_wave_height_m()),
            common.cache(),
        );
        for step in [0.5, 0.25] {
            let accs: Vec<f64> = (0..=(3.0 / step) as usize)
                .map(|k| k as f64 * step)
                .collect();
            let prepared = built
                .prepare(&[Method::DoeOnly], &accs, common.progress())
                .expect("psfs");
            let psfs = accs
                .iter()
                .flat_map(|d| prepared.system_psfs(Method::DoeOnly, *d).expect("psfs"))
                .collect();
            let truth = PsfBundle::new("t", accs.clone(), vec![600.0, 530.0, 450.0], psfs, None)
                .expect("bundle");
            let truth = Arc::new(truth);
            for f in ["native", "refine:10@sharp"] {
                let s = calib_loop::scores(
                    &common,
                    &design,
                    &built,
                    Some(truth.clone()),
                    Method::DoeWiener,
                    f.parse().expect("f"),
                    &imgs,
                    &depths,
                )
                .expect("scores");
                eprintln!(
                    "{}: {f}: design {:.3}, truth every {step} D {:.3}, oracle {:.3} dB ({:+.3})",
                    p.0,
                    s.design,
                    s.measured.unwrap_or(f64::NAN),
                    s.oracle,
                    s.oracle - s.design
                );
            }
        }
    }
}

fn cases() -> Vec<(&'static str, Perturbation)> {
    vec![
        (
            "etch +8 %",
            Perturbation {
                etch_scale: 1.08,
                ..Default::default()
            },
        ),
        (
            "8 levels",
            Perturbation {
                levels: 8,
                ..Default::default()
            },
        ),
        (
            "decentre 0.1 mm",
            Perturbation {
                decentre_mm: [0.1, 0.0],
                ..Default::default()
            },
        ),
        // Beyond the three: the one error here whose oracle gain is
        // large (docs/tolerance.md), so that the 90 % line is tested where
        // it means something.
        (
            "decentre 0.3 mm",
            Perturbation {
                decentre_mm: [0.3, 0.0],
                ..Default::default()
            },
        ),
    ]
}

#[test]
fn recovered_psfs_keep_the_oracles_gain() {
    let dir = tempfile::tempdir().expect("tmp");
    let common = CommonOptions {
        calib: Some(repo().join("tests/data/calib-loop.toml")),
        cache_dir: Some(dir.path().join("cache")),
        ..Default::default()
    };
    let patterns = dir.path().join("patterns");
    calib_patterns::write(&common, &patterns, 1.0, 1).expect("patterns");
    let design = Simulator::new(common.calibration().expect("calib"), None, common.cache())
        .expect("the design");
    let imgs = images();
    let depths: Vec<f64> = (0..=5).map(|i| i as f64 * 0.5).collect();
    let cases = cases();
    let mut failures = Vec::new();
    for (i, (name, p)) in cases.iter().enumerate() {
        let captures = dir.path().join(format!("captures-{i}"));
        let bundle = dir.path().join(format!("bundle-{i}"));
        calib_synth::write(
            &common,
            &SynthOptions {
                patterns_dir: patterns.clone(),
                out: captures.clone(),
                accommodations_d: (0..=6).map(|k| k as f64 * 0.5).collect(),
                perturbation: *p,
                camera: Camera::default(),
                seed: 11 + i as u64,
                field_zones: (1, 1),
            },
        )
        .expect("captures");
        calib_psfs::write(&common, &captures, &bundle, (1, 1)).expect("PSFs");
        let recovered = PsfBundle::load(&bundle).expect("the recovered bundle");
        let truth = PsfBundle::load(&captures.join(TRUTH_DIR)).expect("the truth");
        let mut worst: f64 = 0.0;
        for (a, _) in recovered.accommodations_d().iter().enumerate() {
            for c in 0..3 {
                worst = worst.max(response_distance(
                    recovered.measured(a, c),
                    truth.measured(a, c),
                ));
            }
        }
        let built = Simulator::with_doe(
            p.calibration(&design.calib),
            p.doe(&design.doe, design.calib.doe_wave_height_m()),
            common.cache(),
        );
        let s = calib_loop::scores(
            &common,
            &design,
            &built,
            Some(Arc::new(recovered)),
            Method::DoeWiener,
            Prefilter::Native,
            &imgs,
            &depths,
        )
        .expect("scores");
        let share = s.recovered_share().unwrap_or(f64::NAN);
        let measured = s.measured.expect("a measured score");
        eprintln!(
            "{name}: worst distance {worst:.4}; vs sharp design {:.3}, recovered {:.3}, oracle {:.3} dB: {:.1} % of the gain",
            s.design,
            s.measured.unwrap_or(f64::NAN),
            s.oracle,
            100.0 * share
        );
        let kept = if s.oracle - s.design >= GAIN_RESOLUTION_DB {
            share >= MIN_RECOVERED_SHARE
        } else {
            (measured - s.oracle).abs() <= GAIN_RESOLUTION_DB
        };
        if worst > MAX_DISTANCE || !kept {
            failures.push(format!(
                "{name}: distance {worst:.4}, design {:.4}, recovered {measured:.4}, oracle {:.4} dB",
                s.design, s.oracle
            ));
        }
        // Each case's captures and bundle take hundreds of MB, and CI's disk
        // is limited (a CI run ran out of it here): only one case at a time.
        for d in [&captures, &bundle] {
            std::fs::remove_dir_all(d).expect("the case's files removed");
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

/// Field zones (issue 57, item 2): where the eye's pupil is the stop the
/// PSF changes across the field. Captures of the design seen by a 2 mm
/// pupil 5 mm behind the lens, each dot through its zone's true PSFs (2 × 1
/// zones, their centres 0.37 mm of pupil decentre either side), give back
/// each zone's PSFs within the loop's bound, and not the other zone's
/// (green, in focus at 1.5 D, differs little between them; red and blue,
/// out of focus, much).
#[test]
fn field_zones_are_recovered_zone_by_zone() {
    let dir = tempfile::tempdir().expect("tmp");
    let text = std::fs::read_to_string(repo().join("tests/data/calib-loop.toml"))
        .expect("the loop calibration");
    let calib = dir.path().join("eye.toml");
    std::fs::write(
        &calib,
        format!("{text}\n[eye]\npupil_diameter_mm = 2.0\nrelief_mm = 5.0\n"),
    )
    .expect("write");
    let common = CommonOptions {
        calib: Some(calib),
        cache_dir: Some(dir.path().join("cache")),
        ..Default::default()
    };
    let patterns = dir.path().join("patterns");
    calib_patterns::write(&common, &patterns, 1.0, 1).expect("patterns");
    let captures = dir.path().join("captures");
    calib_synth::write(
        &common,
        &SynthOptions {
            patterns_dir: patterns,
            out: captures.clone(),
            accommodations_d: vec![1.5],
            perturbation: Perturbation::default(),
            camera: Camera::default(),
            seed: 5,
            field_zones: (2, 1),
        },
    )
    .expect("captures");
    let bundle = dir.path().join("bundle");
    calib_psfs::write(&common, &captures, &bundle, (2, 1)).expect("PSFs");
    let recovered = PsfBundle::load(&bundle).expect("the recovered bundle");
    let truth = PsfBundle::load(&captures.join(TRUTH_DIR)).expect("the truth");
    assert_eq!((recovered.zones(), truth.zones()), ((2, 1), (2, 1)));
    let zone = |b: &PsfBundle, i: usize| b.zone(i, 0).expect("a zone");
    let (mut report, mut differing) = (Vec::new(), 0);
    for c in 0..3 {
        let d =
            |a: &PsfBundle, b: &PsfBundle| response_distance(a.measured(0, c), b.measured(0, c));
        let (t0, t1) = (zone(&truth, 0), zone(&truth, 1));
        let (r0, r1) = (zone(&recovered, 0), zone(&recovered, 1));
        let (own0, own1, apart, crossed) = (d(&r0, &t0), d(&r1, &t1), d(&t0, &t1), d(&r0, &t1));
        let whole = d(&recovered, &truth);
        eprintln!(
            "channel {c}: zones from their truth {own0:.4} / {own1:.4}; the truths apart {apart:.4}; \
             zone 0 from zone 1's truth {crossed:.4}; the whole field {whole:.4}"
        );
        // Where the zones' truths differ, the recovered zone must be its
        // own, not the other's nor their mean.
        if own0.max(own1).max(whole) > MAX_DISTANCE
            || (apart >= 2.0 * MAX_DISTANCE && crossed <= MAX_DISTANCE)
        {
            report.push(c);
        }
        differing += (apart >= 2.0 * MAX_DISTANCE) as usize;
    }
    assert!(report.is_empty(), "channels {report:?} (see above)");
    assert!(
        differing > 0,
        "no channel's zones differ: nothing was tested"
    );
    // A bundle in more zones than the patterns' dots can fill is refused.
    let e = calib_psfs::write(&common, &captures, &dir.path().join("b2"), (8, 8))
        .expect_err("empty zones");
    assert!(e.to_string().contains("holds no dot"), "{e}");
    assert!(!dir.path().join("b2").exists());
}
