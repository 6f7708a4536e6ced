//! Image files through the project's validated loader (every format the
//! `image` crate is built with here: PNG, JPEG, TIFF, BMP, PNM), for the
//! shipped 1920×1080 panel as `sim`, `eval` and `run` load them.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    match nedrt_core::image_io::decode_for_panel(data, "fuzz.img", (1920, 1080)) {
        Ok(loaded) => {
            let image = loaded.image;
            assert!(image.width > 0 && image.height > 0);
            assert!(image.data().iter().all(|v| (0.0..=1.0).contains(v)));
        }
        Err(e) => {
            let message = e.to_string();
            assert!(message.contains("fuzz.img"), "{message}");
            assert!(message.len() < 4096, "a {}-byte error", message.len());
        }
    }
});
