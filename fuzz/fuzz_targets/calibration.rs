//! Calibration TOML → validated `Calibration`: any text either loads into a
//! calibration whose derived quantities are finite, or is refused with an
//! error that names the file and stays short.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nedrt_core::calib::Calibration;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match Calibration::from_toml(text, "fuzz.toml", None) {
        Ok(calib) => {
            for c in 0..calib.channels.len() {
                assert!(calib.focal_length_m(c).is_finite());
                assert!(calib.doe_phase_per_m(c).is_finite());
            }
            assert!(calib.retinal_step_rad().is_finite());
            let _ = calib.optics_fingerprint();
        }
        Err(e) => {
            let message = e.to_string();
            assert!(message.contains("fuzz.toml"), "{message}");
            assert!(message.len() < 4096, "a {}-byte error", message.len());
        }
    }
});
