//! DOE height-map files (safetensors + metadata), validated against the
//! shipped calibration: a map is accepted with finite heights inside the
//! fabrication range, or refused naming the file.
#![no_main]

use std::sync::LazyLock;

use libfuzzer_sys::fuzz_target;
use nedrt_core::calib::Calibration;

static CALIB: LazyLock<Calibration> =
    LazyLock::new(|| Calibration::default_embedded().expect("the shipped calibration loads"));

fuzz_target!(|data: &[u8]| {
    match nedrt_optics::doe_file::parse(data, "fuzz.safetensors", &CALIB) {
        Ok(map) => {
            let _ = nedrt_optics::doe_file::to_bytes(&map).expect("an accepted map re-encodes");
        }
        Err(e) => {
            let message = e.to_string();
            assert!(message.contains("fuzz.safetensors"), "{message}");
            assert!(message.len() < 4096, "a {}-byte error", message.len());
        }
    }
});
