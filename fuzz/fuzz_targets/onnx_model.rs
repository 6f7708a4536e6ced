//! The D-CNN's ONNX file through the part nedrt owns: protobuf decoding,
//! signature and operator validation, and lowering to the layer list the
//! wgpu backend generates kernels from.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use nedrt_infer::ModelFile;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.onnx");
    let checked = ModelFile::from_bytes(path, data.to_vec()).and_then(|m| m.lower());
    if let Err(e) = checked {
        let message = e.to_string();
        assert!(message.contains("fuzz.onnx"), "{message}");
        assert!(message.len() < 4096, "a {}-byte error", message.len());
    }
});
