//! Loading, validation and CPU-backend tests. GPU parity lives in
//! gpu_tests.rs; ort parity here, in `needs_ort`: `#[ignore]`d, so a plain
//! `cargo test` lists them as not run, and run by `scripts/test.sh` (which
//! points ORT_DYLIB_PATH at the library in .venv). When run, a missing
//! library is a failure.

use std::path::Path;

use super::synth::{self, SplitMix};
use super::*;

pub(crate) fn model_from(proto: &tract_onnx::pb::ModelProto, name: &str) -> ModelFile {
    ModelFile::from_bytes(Path::new(name), synth::encode(proto)).expect("decodes")
}

pub(crate) fn random_frame(width: usize, height: usize, seed: u64) -> Image {
    let mut rng = SplitMix::new(seed);
    Image::rgb(
        width,
        height,
        (0..3 * width * height).map(|_| rng.unit()).collect(),
    )
}

/// The largest |a − b|; a NaN on either side counts as infinite (f32::max
/// would pass over it, and a NaN output is a bug, not agreement).
pub(crate) fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| {
            let d = (x - y).abs();
            if d.is_nan() { f32::INFINITY } else { d }
        })
        .fold(0.0, f32::max)
}

fn lowering_error(proto: &tract_onnx::pb::ModelProto) -> String {
    model_from(proto, "bad.onnx")
        .lower()
        .expect_err("must be refused")
        .to_string()
}

#[test]
fn full_unet_lowers_to_fused_layers_with_the_trainers_cost() {
    let net = model_from(&synth::unet(32, 4, 1), "full.onnx")
        .lower()
        .expect("lowers");
    // 4 encoder + 3 decoder levels of two convs, 3 pools, 3 upsamplings,
    // 3 concats, the output conv; ReLU and the residual Add fused away.
    assert_eq!(net.layers.len(), 14 + 3 + 3 + 3 + 1);
    assert_eq!(net.multiple, 8);
    // models/nedrt_train/unet.py macs_per_pixel() for width 32, 4 levels.
    assert_eq!(net.macs_per_pixel, 140_736.0);
    let Some(Layer::Conv(last)) = net.layers.last() else {
        panic!("last layer is not a conv");
    };
    assert_eq!((last.kernel, last.relu, last.residual), (1, false, Some(0)));
    let relus = net
        .layers
        .iter()
        .filter(|l| matches!(l, Layer::Conv(c) if c.relu))
        .count();
    assert_eq!(relus, 14);
}

use network::Layer;

#[test]
fn reference_twin_matches_tract_on_a_random_unet() {
    let model = model_from(&synth::unet(4, 3, 7), "small.onnx");
    let net = model.lower().expect("lowers");
    let mut tract =
        tract_backend::TractBackend::new(&model, &BackendOptions::default()).expect("tract loads");
    for (w, h) in [(8, 8), (24, 16), (16, 40)] {
        let frame = random_frame(w, h, (w * h) as u64);
        let reference = reference::run(&net, frame.data(), h, w);
        let mut got = tract.run(&frame).expect("runs").into_data();
        got.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
        let d = max_abs_diff(&reference, &got);
        assert!(d <= 1e-5, "{w}×{h}: max abs difference {d}");
    }
}

/// A frame of `channels` planes, uniform in ±1 (a step correction's
/// inputs are signed: the dual and the gradient).
pub(crate) fn signed_planes(width: usize, height: usize, channels: usize, seed: u64) -> Image {
    let mut rng = SplitMix::new(seed);
    let planes = (0..channels)
        .map(|_| (0..width * height).map(|_| rng.symmetric(1.0)).collect())
        .collect();
    Image::from_planes(width, height, planes)
}

#[test]
fn a_correction_network_of_nine_planes_runs_signed_at_odd_sizes() {
    let model = model_from(&synth::step_correction(9, 8, 3, 5), "step.onnx");
    let net = model.lower().expect("lowers");
    assert_eq!((net.values[0].channels, net.clamped), (9, false));
    let mut dcnn =
        Dcnn::from_model(model, BackendKind::Cpu, &BackendOptions::default()).expect("loads");
    assert_eq!(dcnn.input_channels(), 9);
    assert_eq!(dcnn.flat_field_shift().expect("no image to shift"), 0.0);
    for (w, h) in [(21, 13), (8, 8), (1, 3)] {
        let frame = signed_planes(w, h, 9, (w * h) as u64);
        let out = dcnn.run_unclamped(&frame).expect("runs");
        assert_eq!((out.channels(), out.width, out.height), (3, w, h));
        let want = reference::run(&net, frame.data(), h, w);
        let d = max_abs_diff(out.data(), &want);
        assert!(d <= 1e-5, "{w}×{h}: {d}");
        // Signed: neither the backend nor the twin clamped it.
        assert!(out.data().iter().any(|v| *v < 0.0) || w * h < 8, "{w}×{h}");
    }
    let e = dcnn
        .run_unclamped(&random_frame(8, 8, 1))
        .expect_err("3 planes for a network of 9");
    assert!(e.to_string().contains('9'), "{e}");
}

#[test]
fn frames_of_any_size_are_padded_by_reflection_and_cropped_back() {
    let model = model_from(&synth::unet(4, 3, 3), "small.onnx");
    let net = model.lower().expect("lowers");
    let mut dcnn =
        Dcnn::from_model(model, BackendKind::Cpu, &BackendOptions::default()).expect("loads");
    for (w, h) in [(21, 13), (9, 17), (3, 5), (1, 1)] {
        let frame = random_frame(w, h, 11);
        let out = dcnn.run_frame(&frame).expect("runs");
        assert_eq!((out.width, out.height, out.data().len()), (w, h, 3 * w * h));
        let m = net.multiple;
        let (pw, ph) = (w.div_ceil(m) * m, h.div_ceil(m) * m);
        let padded = frame.pad_reflect(pw, ph);
        let want = Image::rgb(pw, ph, reference::run(&net, padded.data(), ph, pw)).crop(0, 0, w, h);
        let d = max_abs_diff(out.data(), want.data());
        assert!(d <= 1e-5, "{w}×{h}: {d}");
        assert!(out.data().iter().all(|v| (0.0..=1.0).contains(v)));
    }
}

#[test]
fn corrupt_truncated_and_empty_files_are_refused_with_the_file_named() {
    let bytes = synth::encode(&synth::unet(4, 3, 1));
    let dir = tempfile::tempdir().expect("tempdir");
    let cases: [(&str, Vec<u8>); 3] = [
        ("empty.onnx", vec![]),
        ("truncated.onnx", bytes[..bytes.len() / 2].to_vec()),
        (
            "garbage.onnx",
            b"\xff\xfe this is not a protobuf \x00\x01".to_vec(),
        ),
    ];
    for (name, content) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, content).expect("write");
        let e = ModelFile::read(&path).expect_err(name).to_string();
        assert!(e.contains(name), "{e}");
        assert!(
            e.contains("empty") || e.contains("corrupt or truncated"),
            "{e}"
        );
    }
    let missing = ModelFile::read(&dir.path().join("missing.onnx")).expect_err("missing");
    assert!(missing.to_string().contains("missing.onnx"));
}

#[test]
fn unsupported_operators_and_wrong_signatures_are_refused() {
    let mut m = synth::unet(4, 3, 1);
    let g = m.graph.as_mut().expect("graph");
    let relu = g
        .node
        .iter_mut()
        .find(|n| n.op_type == "Relu")
        .expect("relu");
    relu.op_type = "Sigmoid".into();
    assert!(lowering_error(&m).contains("operator 'Sigmoid' is not supported"));

    // An input of other planes than its first conv takes.
    let mut m = synth::unet(4, 3, 1);
    m.graph.as_mut().expect("graph").input[0] = synth::image_value("image", 4);
    let e = lowering_error(&m);
    assert!(e.contains("4") && e.contains("bad.onnx"), "{e}");

    let mut m = synth::step_correction(9, 4, 2, 1);
    m.graph.as_mut().expect("graph").input[0] = synth::image_value("image", 65);
    let e = lowering_error(&m);
    assert!(e.contains("1×C×H×W (C from 1 to 64)"), "{e}");

    let mut m = synth::step_correction(9, 4, 2, 1);
    m.graph.as_mut().expect("graph").output[0] = synth::image_value("display", 9);
    let e = lowering_error(&m);
    assert!(e.contains("output") && e.contains("1×3×H×W"), "{e}");

    let mut m = synth::step_correction(9, 4, 2, 1);
    m.metadata_props[0].value = "residual".into();
    let e = lowering_error(&m);
    assert!(
        e.contains("nedrt.output") && e.contains("\"residual\""),
        "{e}"
    );

    let mut m = synth::unet(4, 3, 1);
    if let Some(tract_onnx::pb::type_proto::Value::TensorType(t)) =
        m.graph.as_mut().expect("graph").input[0]
            .r#type
            .as_mut()
            .and_then(|t| t.value.as_mut())
    {
        for d in &mut t.shape.as_mut().expect("shape").dim[2..] {
            d.value = Some(tract_onnx::pb::tensor_shape_proto::dimension::Value::DimValue(64));
        }
    }
    assert!(lowering_error(&m).contains("fixed size 64×64"));

    let mut m = synth::unet(4, 3, 1);
    m.graph.as_mut().expect("graph").initializer[0]
        .raw_data
        .truncate(8);
    assert!(lowering_error(&m).contains("bytes"));

    // Dims whose product overflows: an error, not a panic or a wrapped size.
    let mut m = synth::unet(4, 3, 1);
    m.graph.as_mut().expect("graph").initializer[0].dims = vec![1 << 32, 1 << 32, 3, 3];
    let e = lowering_error(&m);
    assert!(e.contains("more values than can be addressed"), "{e}");

    let mut m = synth::unet(4, 3, 1);
    let g = m.graph.as_mut().expect("graph");
    let conv = g
        .node
        .iter_mut()
        .find(|n| n.op_type == "Conv")
        .expect("conv");
    conv.attribute
        .iter_mut()
        .find(|a| a.name == "strides")
        .expect("strides")
        .ints = vec![2, 2];
    assert!(lowering_error(&m).contains("strides"));
}

/// The library an ONNX Runtime test loads: `ORT_DYLIB_PATH`, which
/// scripts/test.sh points at the onnxruntime wheel in .venv (test code
/// only; the library crates never read the environment).
pub(crate) fn test_ort_library() -> OrtLibrary {
    match std::env::var_os("ORT_DYLIB_PATH") {
        Some(p) => OrtLibrary::Found(p.into()),
        None => OrtLibrary::Missing("ORT_DYLIB_PATH is not set".into()),
    }
}

/// The ort backend for a test that needs ONNX Runtime: a library that
/// cannot be found or loaded is a failure (the test is `#[ignore]`d, so it
/// runs only when asked for).
pub(crate) fn open_ort(model: &ModelFile) -> ort_backend::OrtBackend {
    ort_backend::OrtBackend::new(
        model,
        &BackendOptions {
            threads: 1,
            ort_library: test_ort_library(),
            ..Default::default()
        },
    )
    .unwrap_or_else(|e| {
        panic!(
            "this test needs ONNX Runtime and could not load it: {e} \
             (scripts/test.sh sets ORT_DYLIB_PATH to the onnxruntime wheel in .venv)"
        )
    })
}

#[test]
fn the_committed_model_loads_and_validates() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/dcnn.onnx");
    let model = ModelFile::read(&path).expect("the committed model loads");
    let net = model.lower().expect("and validates");
    assert_eq!(net.multiple, 8);
}

mod needs_ort {
    use super::*;

    #[test]
    #[ignore = "needs ONNX Runtime (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn an_unavailable_ort_provider_is_an_error_not_a_silent_cpu_fallback() {
        let model = model_from(&synth::unet(4, 3, 1), "small.onnx");
        // The library loads: the error below is the provider's, not a missing library's.
        open_ort(&model);
        let options = BackendOptions {
            ort_provider: OrtProvider::Cuda,
            ..Default::default()
        };
        let e = ort_backend::OrtBackend::new(&model, &options).expect_err("CPU-only wheel");
        assert!(
            e.to_string()
                .contains("execution provider is not available"),
            "{e}"
        );
    }

    #[test]
    #[ignore = "needs ONNX Runtime (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn tract_matches_onnxruntime_on_random_unets() {
        for (width, levels, seed) in [(4, 3, 5), (8, 4, 6)] {
            let model = model_from(&synth::unet(width, levels, seed), "random.onnx");
            let mut ort = open_ort(&model);
            let mut tract = tract_backend::TractBackend::new(&model, &BackendOptions::default())
                .expect("tract");
            for (w, h) in [(16, 16), (40, 24)] {
                let frame = random_frame(w, h, seed);
                let a = ort.run(&frame).expect("ort runs").into_data();
                let b = tract.run(&frame).expect("tract runs").into_data();
                let d = max_abs_diff(&a, &b);
                assert!(d <= 1e-4, "width {width}, {w}×{h}: {d}");
            }
        }
    }

    #[test]
    #[ignore = "needs ONNX Runtime (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn tract_matches_onnxruntime_on_a_correction_network() {
        let model = model_from(&synth::step_correction(9, 16, 3, 8), "step.onnx");
        let mut ort = open_ort(&model);
        let mut tract =
            tract_backend::TractBackend::new(&model, &BackendOptions::default()).expect("tract");
        for (w, h) in [(16, 16), (21, 13)] {
            let frame = signed_planes(w, h, 9, 3);
            let a = ort.run(&frame).expect("ort runs").into_data();
            let b = tract.run(&frame).expect("tract runs").into_data();
            assert!(a.iter().any(|v| *v < 0.0), "ort clamped");
            let d = max_abs_diff(&a, &b);
            assert!(d <= 1e-4, "{w}×{h}: {d}");
        }
    }

    /// The committed trained model, through every CPU backend.
    #[test]
    #[ignore = "needs ONNX Runtime (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn trained_model_agrees_across_cpu_backends() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/dcnn.onnx");
        let model = ModelFile::read(&path).expect("the committed model loads");
        let mut ort = open_ort(&model);
        let mut tract =
            tract_backend::TractBackend::new(&model, &BackendOptions::default()).expect("tract");
        let frame = random_frame(48, 32, 99);
        let a = ort.run(&frame).expect("ort").into_data();
        let b = tract.run(&frame).expect("tract").into_data();
        assert!(max_abs_diff(&a, &b) <= 1e-4);
    }
}

#[test]
fn frames_with_nan_or_the_wrong_size_are_refused() {
    let model = model_from(&synth::unet(4, 3, 1), "small.onnx");
    let mut dcnn =
        Dcnn::from_model(model, BackendKind::Cpu, &BackendOptions::default()).expect("loads");
    let mut frame = random_frame(8, 8, 1);
    frame.data_mut()[5] = f32::NAN;
    assert!(
        dcnn.run_frame(&frame)
            .expect_err("NaN")
            .to_string()
            .contains("NaN")
    );
    let gray = nedrt_core::Image::zeros(8, 8, 1);
    assert!(
        dcnn.run_frame(&gray)
            .expect_err("gray")
            .to_string()
            .contains("3 needed")
    );
    let f16_cpu = BackendOptions {
        precision: Precision::F16,
        ..Default::default()
    };
    let model = model_from(&synth::unet(4, 3, 1), "small.onnx");
    let e = Dcnn::from_model(model, BackendKind::Cpu, &f16_cpu).expect_err("f16 on cpu");
    assert!(e.to_string().contains("wgpu backend only"));
}

#[test]
fn a_model_that_moves_flat_fields_is_warned_about() {
    // An untrained U-Net (random weights) adds its own pattern to any
    // frame, flat ones included.
    let model = model_from(&synth::unet(4, 3, 7), "random.onnx");
    let mut dcnn =
        Dcnn::from_model(model, BackendKind::Cpu, &BackendOptions::default()).expect("loads");
    let shift = dcnn.flat_field_shift().expect("runs");
    assert!(shift > FLAT_FIELD_TOLERANCE && shift.is_finite(), "{shift}");
    let w = flat_field_warning("m.onnx", shift).expect("warns");
    assert!(w.contains("m.onnx") && w.contains("flat"), "{w}");
    assert!(flat_field_warning("m.onnx", 0.5 / 255.0).is_none());
}

/// A backend whose network overflows: every value +inf, one NaN.
#[derive(Debug)]
struct Overflowing;

impl Backend for Overflowing {
    fn describe(&self) -> String {
        "overflowing test backend".into()
    }
    fn run(&mut self, frame: &Image) -> Result<Image, InferenceError> {
        let mut out = Image::rgb(
            frame.width,
            frame.height,
            vec![f32::INFINITY; 3 * frame.width * frame.height],
        );
        out.data_mut()[0] = f32::NAN;
        Ok(out)
    }
}

#[test]
fn a_network_output_that_overflows_is_an_engine_failure_not_white_pixels() {
    let model = model_from(&synth::unet(4, 3, 1), "small.onnx");
    let network = model.lower().expect("lowers");
    let mut dcnn = Dcnn {
        model,
        network,
        backend: Box::new(Overflowing),
    };
    let e = dcnn
        .run_frame(&random_frame(8, 8, 3))
        .expect_err("overflow");
    assert!(
        e.to_string()
            .contains("output holds 192 non-finite values (NaN or ±inf) for a 8×8 frame"),
        "{e}"
    );
    // Through the one interface the service uses: an engine failure (the
    // service counts it and switches to its fallback), not a bad frame.
    let e = Preprocess::run(&mut dcnn, &random_frame(8, 8, 3)).expect_err("overflow");
    assert!(matches!(e, PreprocessError::Engine { .. }), "{e}");
}
