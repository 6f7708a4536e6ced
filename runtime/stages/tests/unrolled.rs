//! The unrolled preprocessor on the host against PyTorch: the golden of
//! tools/golden/make_unrolled_golden.py (three steps, two of them with
//! seeded random corrections, on the display problem of
//! tests/golden/optimal.json) is what nedrt-stages' `Unrolled` computes,
//! after each step, on every D-CNN backend; bad manifests are refused with
//! the file and the reason.

use std::path::{Path, PathBuf};

use nedrt_core::{Image, Preprocess};
use nedrt_infer::{BackendKind, BackendOptions};
use nedrt_optics::Psf;
use nedrt_optics::sim::{DisplayProblem, Objective};
use nedrt_stages::unrolled::{Manifest, Unrolled};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).expect("golden file")).expect("JSON")
}

fn floats(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

fn psf(v: &serde_json::Value) -> Psf {
    Psf {
        window: v["window"].as_u64().expect("window") as usize,
        cells: floats(&v["cells"]),
        veil: v["veil"].as_f64().expect("veil"),
    }
}

/// The golden display problem (its PSFs, as nedrt-optics' own golden test reads them).
fn golden_problem() -> (DisplayProblem, Image) {
    let g = json(&repo().join("tests/golden/optimal.json"));
    let (w, h) = (
        g["width"].as_u64().expect("w") as usize,
        g["height"].as_u64().expect("h") as usize,
    );
    let psfs = g["psfs"]
        .as_array()
        .expect("psfs")
        .iter()
        .map(|ch| ch.as_array().expect("depths").iter().map(psf).collect())
        .collect();
    let blurred = g["blurred"]
        .as_array()
        .expect("blurred")
        .iter()
        .map(|b| b.as_bool().expect("bool"))
        .collect();
    let blur = g["blur"]
        .as_array()
        .expect("blur")
        .iter()
        .map(psf)
        .collect();
    let problem = DisplayProblem::new(
        Objective::Target,
        floats(&g["depths_d"]),
        psfs,
        blurred,
        Some(blur),
        g["k_reg"].as_f64().expect("k"),
    )
    .expect("valid");
    let input = floats(&g["input"]).into_iter().map(|v| v as f32).collect();
    (problem, Image::from_data(w, h, 3, input))
}

fn manifest_path() -> PathBuf {
    repo().join("tests/golden/unrolled/golden.unrolled.toml")
}

/// The backend options of a test: ONNX Runtime from `ORT_DYLIB_PATH`,
/// which scripts/test.sh points at the wheel in .venv (test code only).
fn options() -> BackendOptions {
    BackendOptions {
        ort_library: match std::env::var_os("ORT_DYLIB_PATH") {
            Some(p) => nedrt_infer::OrtLibrary::Found(p.into()),
            None => nedrt_infer::OrtLibrary::Missing("ORT_DYLIB_PATH is not set".into()),
        },
        ..Default::default()
    }
}

/// The largest difference from PyTorch after each step, on `kind`.
fn step_differences(kind: BackendKind) -> Vec<f32> {
    let io = json(&repo().join("tests/golden/unrolled/io.json"));
    let manifest = Manifest::read(&manifest_path()).expect("the golden manifest reads");
    assert_eq!(manifest.steps.len(), 3);
    assert!(manifest.steps[1].network.is_none() && manifest.steps[2].network.is_some());
    let (_, input) = golden_problem();
    let mut out = Vec::new();
    for (k, want) in io["steps"].as_array().expect("steps").iter().enumerate() {
        let mut first = manifest.clone();
        first.steps.truncate(k + 1);
        let (problem, _) = golden_problem();
        let mut unrolled = Unrolled::with_problem(first, problem, kind, &options()).expect("loads");
        let got = unrolled.run(&input).expect("runs");
        let d = floats(want)
            .iter()
            .zip(got.data())
            .map(|(a, b)| (*a as f32 - b).abs())
            .fold(0.0f32, f32::max);
        out.push(d);
    }
    out
}

#[test]
fn the_unrolled_golden_is_what_the_cpu_backend_computes() {
    let d = step_differences(BackendKind::Cpu);
    eprintln!("largest difference after each step: {d:?}");
    assert!(d.iter().all(|d| *d <= 1e-4), "after each step: {d:?}");
}

#[test]
fn the_corrections_move_the_display_image() {
    // Without its networks the golden is the classical solver, which must
    // differ from it: a golden whose corrections did nothing would test
    // nothing.
    let io = json(&repo().join("tests/golden/unrolled/io.json"));
    let mut manifest = Manifest::read(&manifest_path()).expect("reads");
    manifest.steps.iter_mut().for_each(|s| s.network = None);
    let (problem, input) = golden_problem();
    let mut classical = Unrolled::with_problem(
        manifest,
        problem,
        BackendKind::Cpu,
        &BackendOptions::default(),
    )
    .expect("loads");
    let got = classical.run(&input).expect("runs");
    let want = floats(&io["steps"][2]);
    let d = want
        .iter()
        .zip(got.data())
        .map(|(a, b)| (*a as f32 - b).abs())
        .fold(0.0f32, f32::max);
    assert!(
        d > 1e-2,
        "the corrections moved the display image by only {d}"
    );
}

/// The golden folder copied into a temporary one, with its manifest edited.
fn edited(edit: impl Fn(&str) -> String) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("tempdir");
    for entry in std::fs::read_dir(repo().join("tests/golden/unrolled")).expect("golden dir") {
        let entry = entry.expect("entry");
        std::fs::copy(entry.path(), dir.path().join(entry.file_name())).expect("copy");
    }
    let path = dir.path().join("golden.unrolled.toml");
    let text = std::fs::read_to_string(&path).expect("manifest");
    std::fs::write(&path, edit(&text)).expect("write");
    (dir, path)
}

#[test]
fn bad_manifests_are_refused_with_the_file_and_the_reason() {
    type Edit = Box<dyn Fn(&str) -> String>;
    let cases: Vec<(Edit, &str)> = vec![
        (
            Box::new(|t| t.replace("nedrt unrolled 1", "nedrt unrolled 9")),
            "this nedrt reads",
        ),
        (Box::new(|t| t.replace("6acf2bf6", "00000000")), "SHA-256"),
        (
            Box::new(|t| t.replace("golden.step1.onnx", "missing.onnx")),
            "missing.onnx",
        ),
        (
            Box::new(|t| t.replace("rho = 0.0299", "rho = -0.0299")),
            "positive share",
        ),
        (
            Box::new(|t| t.replace("relaxation = 1.5", "relaxation = 2.5")),
            "between 0 and 2",
        ),
        (
            Box::new(|t| t.replace("objective = \"target\"", "objective = \"blurry\"")),
            "objective",
        ),
        (Box::new(|t| format!("{t}\nextra = 1\n")), "unknown field"),
        (
            Box::new(|t| t.replace("network_sha256 = \"c85c", "# \"c85c")),
            "together",
        ),
        (
            Box::new(|t| t.split("[[step]]").next().unwrap_or_default().to_string()),
            "step",
        ),
    ];
    for (edit, says) in cases {
        let (_dir, path) = edited(edit);
        let e = Manifest::read(&path).expect_err("refused").to_string();
        assert!(
            e.contains("golden.unrolled.toml") && e.contains(says),
            "{says}: {e}"
        );
    }
    // A correction of the wrong shape is refused at load, naming its file.
    let (dir, path) = edited(|t| t.to_string());
    let (problem, _) = golden_problem();
    Unrolled::check_with_problem(&Manifest::read(&path).expect("sound"), &problem)
        .expect("the sound model passes the check");
    let wrong = nedrt_infer::synth::encode(&nedrt_infer::synth::step_correction(6, 4, 2, 1));
    std::fs::write(dir.path().join("golden.step1.onnx"), &wrong).expect("write");
    let text = std::fs::read_to_string(&path).expect("manifest");
    let sha: String = {
        use sha2::Digest;
        sha2::Sha256::digest(&wrong)
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    };
    std::fs::write(
        &path,
        text.replace(
            "6acf2bf68a72cb2121b0f17a96df6cebba93dbf556ad56c9851b609de27fc4f2",
            &sha,
        ),
    )
    .expect("write");
    let manifest = Manifest::read(&path).expect("the manifest itself is sound");
    // The check without a network prepared (nedrt run's, before anything
    // opens) refuses it as the load does.
    let e = Unrolled::check_with_problem(&manifest, &problem)
        .expect_err("6 planes for 9")
        .to_string();
    assert!(
        e.contains("golden.step1.onnx") && e.contains("6 input planes"),
        "{e}"
    );
    let e = Unrolled::with_problem(
        manifest,
        problem,
        BackendKind::Cpu,
        &BackendOptions::default(),
    )
    .expect_err("6 planes for 9")
    .to_string();
    assert!(
        e.contains("golden.step1.onnx") && e.contains("6 input planes"),
        "{e}"
    );
}

/// A random frame in [0, 1].
fn frame(width: usize, height: usize, seed: u64) -> Image {
    let mut rng = nedrt_infer::synth::SplitMix::new(seed);
    let data = (0..3 * width * height).map(|_| rng.unit()).collect();
    Image::from_data(width, height, 3, data)
}

// Named for scripts/test.sh's hardware stage (`--ignored needs_`).
mod needs_gpu {
    use super::*;

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_unrolled_golden_is_what_the_wgpu_backend_computes() {
        let d = step_differences(BackendKind::Wgpu);
        eprintln!("largest difference after each step: {d:?}");
        assert!(d.iter().all(|d| *d <= 1e-4), "after each step: {d:?}");
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_unrolled_model_as_one_device_stage_is_its_host_twin() {
        use nedrt_gpu::DeviceStage;
        let (adapter, device, queue) =
            nedrt_gpu::open_device(&nedrt_gpu::GpuSettings::default(), false)
                .expect("a GPU adapter");
        let name = adapter.get_info().name;
        let manifest = Manifest::read(&manifest_path()).expect("reads");
        let (problem, _) = golden_problem();
        let mut host =
            Unrolled::with_problem(manifest, problem, BackendKind::Cpu, &options()).expect("loads");
        let mut stage = host
            .device_stage(&device, &queue, &name, &BackendOptions::default())
            .expect("builds");
        assert!(
            stage
                .describe()
                .contains("3 split-solver steps, 2 with a learned correction")
        );
        // Odd sides, neither a power of two; twice, the second on the first's plan.
        for (w, h, seed) in [(21, 13, 1), (21, 13, 2), (24, 16, 3)] {
            let input = frame(w, h, seed);
            let want = host.run(&input).expect("host");
            let usage = wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST;
            let bytes = (3 * w * h * 4) as u64;
            let make = |label| {
                device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size: bytes,
                    usage,
                    mapped_at_creation: false,
                })
            };
            let (frame_buf, display) = (make("frame"), make("display"));
            queue.write_buffer(&frame_buf, 0, bytemuck::cast_slice(input.data()));
            let readback = device.create_buffer(&wgpu::BufferDescriptor {
                label: None,
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut encoder = device.create_command_encoder(&Default::default());
            // The stage records everything into the frame's encoder: no
            // submission or read-back of its own.
            stage
                .record(&mut encoder, &frame_buf, &display, w, h)
                .expect("records");
            encoder.copy_buffer_to_buffer(&display, 0, &readback, 0, bytes);
            queue.submit([encoder.finish()]);
            nedrt_gpu::map_and_wait(&device, &readback).expect("reads back");
            let got: Vec<f32> =
                bytemuck::cast_slice(&readback.slice(..).get_mapped_range().expect("view"))
                    .to_vec();
            readback.unmap();
            let d = want
                .data()
                .iter()
                .zip(&got)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            eprintln!("{w}×{h}: device against host {d}");
            assert!(d <= 1e-4, "{w}×{h}: {d}");
        }
    }
}

mod needs_ort {
    use super::*;

    #[test]
    #[ignore = "needs ONNX Runtime (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_unrolled_golden_is_what_onnx_runtime_computes() {
        let d = step_differences(BackendKind::Ort);
        eprintln!("largest difference after each step: {d:?}");
        assert!(d.iter().all(|d| *d <= 1e-4), "after each step: {d:?}");
    }
}
