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
}
