//! Round trip and rejection of inconsistent DOE files; arbitrary bytes never panic.

use super::*;
use proptest::prelude::*;

fn calib() -> Calibration {
    Calibration::default_embedded().expect("default calibration")
}

fn small_map(c: &Calibration) -> HeightMap {
    HeightMap::three_lens_init(c, 100e-6)
}

fn with_meta(map: &HeightMap, edit: impl Fn(&mut HashMap<String, String>)) -> Vec<u8> {
    let bytes = to_bytes(map).expect("encode");
    let (_, header) = SafeTensors::read_metadata(&bytes).expect("header");
    let mut meta = header.metadata().clone().expect("metadata");
    edit(&mut meta);
    let t = SafeTensors::deserialize(&bytes).expect("tensors");
    let v = t.tensor(TENSOR).expect("tensor");
    safetensors::serialize([(TENSOR, v)], Some(meta)).expect("encode")
}

fn reason(bytes: &[u8]) -> String {
    parse(bytes, "d.safetensors", &calib())
        .expect_err("must be rejected")
        .to_string()
}

#[test]
fn round_trip_keeps_grid_and_heights() {
    let c = calib();
    let m = small_map(&c);
    let back = parse(&to_bytes(&m).expect("encode"), "d", &c).expect("valid");
    assert_eq!(back.samples, m.samples);
    assert!((back.pitch_m - m.pitch_m).abs() < 1e-18);
    assert_eq!(back.levels, 0);
    for (a, b) in back.height_m.iter().zip(&m.height_m) {
        assert!(
            (a - b).abs() < 1e-12,
            "f32 storage holds heights to 1e-6 µm"
        );
    }
}

#[test]
fn save_is_atomic_and_loadable() {
    let c = calib();
    let dir = tempfile::tempdir().expect("tmp");
    let p = dir.path().join("doe.safetensors");
    save(&small_map(&c), &p).expect("save");
    assert!(load(&p, &c).is_ok());
    let names: Vec<_> = std::fs::read_dir(dir.path()).expect("dir").collect();
    assert_eq!(names.len(), 1, "no temporary file left behind");
}

#[test]
fn inconsistent_files_are_rejected_with_reasons() {
    let c = calib();
    let m = small_map(&c);
    assert!(
        reason(&with_meta(&m, |h| {
            h.remove("pitch_um");
        }))
        .contains("`pitch_um` is missing")
    );
    assert!(
        reason(&with_meta(&m, |h| {
            h.insert("pitch_um".into(), "-3".into());
        }))
        .contains("must be positive")
    );
    assert!(
        reason(&with_meta(&m, |h| {
            h.insert("pitch_um".into(), "abc".into());
        }))
        .contains("not a number")
    );
    // A grid too coarse to cover the aperture.
    assert!(
        reason(&with_meta(&m, |h| {
            h.insert("pitch_um".into(), "50".into());
        }))
        .contains("does not cover")
    );
    // Heights above the stated maximum.
    assert!(
        reason(&with_meta(&m, |h| {
            h.insert("max_height_um".into(), "0.5".into());
        }))
        .contains("outside [0, max_height_um")
    );
    assert!(
        reason(&with_meta(&m, |h| {
            h.insert("material".into(), "PMMA".into());
        }))
        .contains("differs from the calibration")
    );
    assert!(
        reason(&with_meta(&m, |h| {
            h.insert("levels".into(), "4".into());
        }))
        .contains("not one of the 4 levels")
    );
    assert!(
        reason(&with_meta(&m, |h| {
            h.insert("format".into(), "other".into());
        }))
        .contains("format")
    );
    assert!(reason(b"not a safetensors file at all").contains("not a safetensors file"));
}

#[test]
fn non_square_and_non_finite_are_rejected() {
    let c = calib();
    let m = small_map(&c);
    let bytes = to_bytes(&m).expect("encode");
    let (_, header) = SafeTensors::read_metadata(&bytes).expect("header");
    let meta = header.metadata().clone();
    let data: Vec<u8> = (0..m.samples * (m.samples - 1))
        .flat_map(|_| 0.1f32.to_le_bytes())
        .collect();
    let v = safetensors::tensor::TensorView::new(Dtype::F32, vec![m.samples, m.samples - 1], &data)
        .expect("view");
    let b = safetensors::serialize([(TENSOR, v)], meta.clone()).expect("encode");
    assert!(reason(&b).contains("square"));
    let mut data: Vec<u8> = (0..m.samples * m.samples)
        .flat_map(|_| 0.1f32.to_le_bytes())
        .collect();
    data[40..44].copy_from_slice(&f32::NAN.to_le_bytes());
    let v = safetensors::tensor::TensorView::new(Dtype::F32, vec![m.samples, m.samples], &data)
        .expect("view");
    let b = safetensors::serialize([(TENSOR, v)], meta).expect("encode");
    assert!(reason(&b).contains("not finite"));
}

#[test]
fn quantised_profiles_are_accepted_on_their_levels() {
    let c = calib();
    let mut m = small_map(&c);
    let step = m.max_height_m / 3.0;
    m.height_m
        .iter_mut()
        .for_each(|h| *h = (*h / step).round() * step);
    m.levels = 4;
    assert!(parse(&to_bytes(&m).expect("encode"), "q", &c).is_ok());
}

fn radial(c: &Calibration) -> HeightMap {
    HeightMap::three_lens_radial(c, 50e-6)
}

#[test]
fn radial_round_trip_keeps_profile_and_heights() {
    let c = calib();
    let m = radial(&c);
    let bytes = to_bytes(&m).expect("encode");
    let t = SafeTensors::deserialize(&bytes).expect("tensors");
    assert_eq!(t.tensor(TENSOR).expect("tensor").shape(), [m.samples]);
    let back = parse(&bytes, "r", &c).expect("valid");
    assert_eq!(back.profile, Profile::Radial);
    assert_eq!(back.samples, m.samples);
    assert_eq!(back.content_hash().len(), 16);
    for (a, b) in back.height_m.iter().zip(&m.height_m) {
        assert!((a - b).abs() < 1e-12);
    }
    let dir = tempfile::tempdir().expect("tmp");
    let p = dir.path().join("radial.safetensors");
    save(&m, &p).expect("save");
    assert_eq!(load(&p, &c).expect("load").profile, Profile::Radial);
    // A map is written without the key, as before radial profiles existed.
    let map_bytes = to_bytes(&small_map(&c)).expect("encode");
    let (_, header) = SafeTensors::read_metadata(&map_bytes).expect("header");
    assert!(
        !header
            .metadata()
            .clone()
            .expect("meta")
            .contains_key(PROFILE)
    );
}

#[test]
fn radial_files_are_validated_like_maps() {
    let c = calib();
    let m = radial(&c);
    // `profile` contradicting the shape names the key; so does an unknown value.
    let mut r = reason(&with_meta(&m, |h| {
        h.remove(PROFILE);
    }));
    assert!(r.contains("1-D") && r.contains("`profile`"), "{r}");
    r = reason(&with_meta(&m, |h| {
        h.insert(PROFILE.into(), MAP.into());
    }));
    assert!(r.contains("1-D") && r.contains("`profile`"), "{r}");
    r = reason(&with_meta(&small_map(&c), |h| {
        h.insert(PROFILE.into(), RADIAL.into());
    }));
    assert!(r.contains("`profile`") && r.contains("1-D"), "{r}");
    r = reason(&with_meta(&m, |h| {
        h.insert(PROFILE.into(), "spiral".into());
    }));
    assert!(r.contains("`profile` = \"spiral\""), "{r}");
    assert!(r.starts_with("d.safetensors: "), "names the file: {r}");
    // Coverage: N·pitch must reach the aperture radius.
    r = reason(&with_meta(&m, |h| {
        h.insert("pitch_um".into(), "40".into());
    }));
    assert!(r.contains("does not cover"), "{r}");
    r = reason(&with_meta(&m, |h| {
        h.insert("max_height_um".into(), "0.5".into());
    }));
    assert!(
        r.contains("outside [0, max_height_um") && r.contains("sample"),
        "{r}"
    );
    r = reason(&with_meta(&m, |h| {
        h.insert("levels".into(), "4".into());
    }));
    assert!(r.contains("not one of the 4 levels"), "{r}");
    r = reason(&with_meta(&m, |h| {
        h.insert("material".into(), "PMMA".into());
    }));
    assert!(r.contains("differs from the calibration"), "{r}");
    // Too few samples.
    let short: Vec<u8> = [0.1f32; 3].iter().flat_map(|v| v.to_le_bytes()).collect();
    let (_, header) = SafeTensors::read_metadata(&to_bytes(&m).expect("e")).expect("header");
    let v = safetensors::tensor::TensorView::new(Dtype::F32, vec![3], &short).expect("view");
    let b = safetensors::serialize([(TENSOR, v)], header.metadata().clone()).expect("encode");
    assert!(reason(&b).contains("N ≥ 4"));
}

#[test]
fn radial_coverage_is_exactly_n_times_pitch() {
    let c = calib();
    let r_um = c.aperture_radius_m * 1e6;
    let mut m = radial(&c);
    // N samples at exactly r/N reach r: accepted; a hair less: refused.
    m.pitch_m = c.aperture_radius_m / m.samples as f64;
    assert!(parse(&to_bytes(&m).expect("e"), "ok", &c).is_ok());
    let b = with_meta(&m, |h| {
        h.insert(
            "pitch_um".into(),
            format!("{}", r_um / m.samples as f64 * (1.0 - 1e-6)),
        );
    });
    assert!(reason(&b).contains("does not cover"));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]
    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        let _ = parse(&bytes, "fuzz", &calib());
    }

    #[test]
    fn truncated_and_flipped_files_never_panic(cut in 0usize..4000, flip in 0usize..4000, bit in 0u8..8) {
        let c = calib();
        let mut bytes = to_bytes(&HeightMap::three_lens_init(&c, 400e-6)).expect("encode");
        let n = bytes.len();
        bytes[flip % n] ^= 1 << bit;
        bytes.truncate(cut % (n + 1));
        let _ = parse(&bytes, "fuzz", &c);
    }

    #[test]
    fn damaged_radial_files_never_panic(cut in 0usize..2000, flip in 0usize..2000, bit in 0u8..8) {
        let c = calib();
        let mut bytes = to_bytes(&HeightMap::three_lens_radial(&c, 400e-6)).expect("encode");
        let n = bytes.len();
        bytes[flip % n] ^= 1 << bit;
        bytes.truncate(cut % (n + 1));
        let _ = parse(&bytes, "fuzz", &c);
    }

    #[test]
    fn any_profile_value_is_accepted_or_refused_cleanly(value in ".{0,12}", radial in any::<bool>()) {
        let c = calib();
        let m = if radial { HeightMap::three_lens_radial(&c, 400e-6) } else { small_map(&c) };
        let bytes = with_meta(&m, |h| {
            h.insert(PROFILE.into(), value.clone());
        });
        let ok = parse(&bytes, "fuzz", &c).is_ok();
        prop_assert_eq!(ok, (value == RADIAL) == radial && (value == RADIAL || value == MAP));
    }
}
