//! Image files through the project's validated loader (every format the
//! `image` crate is built with here: PNG, JPEG, TIFF, BMP, PNM).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    match nedrt_core::image_io::decode(data, "fuzz.img") {
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
