//! The D-CNN methods: companion DOE, backends agree, one padding rule, bad models.

use super::*;

/// `nedrt --sim --method proposed` with the small calibration and the
/// shipped model on `backend` (none: the default, the CPU), with its output.
fn proposed_on(backend: Option<&str>, dir: &Path) -> Output {
    let (calib, model) = (small_calib(), dcnn_model());
    let mut args = vec![
        "--calib",
        path(&calib),
        "--method",
        "proposed",
        "--dcnn",
        path(&model),
    ];
    args.extend(backend.map(|b| ["--backend", b]).into_iter().flatten());
    let out = dir.join(format!("{}.png", backend.unwrap_or("default")));
    sim("1.0", &out, &args)
}

#[test]
fn proposed_method_runs_the_dcnn_with_its_companion_doe() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cpu = proposed_on(None, dir.path());
    assert!(cpu.status.success(), "{}", stderr(&cpu));
    assert!(stdout(&cpu).contains("D-CNN"), "{}", stdout(&cpu));
    assert!(
        // models/dcnn.doe.safetensors is the multifocal design's DOE.
        stdout(&cpu).contains("nedrt_train.design multifocal"),
        "the companion DOE is used: {}",
        stdout(&cpu)
    );
}

/// The display frame of `method` for a 61×45 frame, as `nedrt sim
/// --display-out` renders it and as `nedrt run --preprocess` records it on
/// the panel (codes after the transfer curve), with the panel's encoder.
pub(super) struct SimAndService {
    pub(super) sim_codes: Vec<u8>,
    pub(super) recorded: Vec<u8>,
    /// The simulator's display frame (planar RGB, linear intensity).
    pub(super) sim_display: Vec<f32>,
    input: PathBuf,
    pub(super) transfer: nedrt_service::present::transfer::Transfer,
    _dir: tempfile::TempDir,
}

impl SimAndService {
    /// The panel's RGB codes for a display frame.
    fn codes(&self, frame: &nedrt_core::Image) -> Vec<u8> {
        panel_codes(&self.transfer, frame)
    }
}

fn panel_codes(
    transfer: &nedrt_service::present::transfer::Transfer,
    frame: &nedrt_core::Image,
) -> Vec<u8> {
    let mut rgba = Vec::new();
    transfer.encode_rgba8(frame, &mut rgba);
    nedrt_service::present::rgb8_of_rgba8(&rgba)
}

const ODD: (usize, usize) = (61, 45);

impl SimAndService {
    /// The panel's codes of the input frame itself.
    pub(super) fn input_codes(&self) -> Vec<u8> {
        let source = nedrt_core::image_io::load(&self.input)
            .expect("input")
            .image;
        self.codes(&source)
    }

    /// The service showed the simulator's display frame, and it is not the
    /// input's: the prefilter ran in both.
    pub(super) fn assert_same_changed_frame(&self) {
        assert_eq!(self.sim_codes, self.recorded, "sim and service differ");
        let source = nedrt_core::image_io::load(&self.input)
            .expect("input")
            .image;
        assert_ne!(
            self.codes(&source),
            self.recorded,
            "the prefilter changed the frame"
        );
    }
}

fn sim_and_service(method: &str) -> SimAndService {
    sim_and_service_with(method, &[])
}

/// [`sim_and_service`] with more arguments for both commands.
pub(super) fn sim_and_service_with(method: &str, extra: &[&str]) -> SimAndService {
    use nedrt_core::Image;
    let dir = tempfile::tempdir().expect("tempdir");
    let (w, h) = ODD;
    let toml = std::fs::read_to_string(small_calib())
        .expect("calib")
        .replace("width_px = 1920", &format!("width_px = {w}"))
        .replace("height_px = 1080", &format!("height_px = {h}"));
    assert!(toml.contains("width_px = 61") && toml.contains("height_px = 45"));
    let calib = dir.path().join("odd-panel.toml");
    std::fs::write(&calib, toml).expect("write calib");
    let input = dir.path().join("odd.png");
    write_png(&input, w as u32, h as u32);

    let display = dir.path().join("display.tif");
    let o = nedrt()
        .current_dir(repo())
        .args(["--calib", path(&calib), "sim", "--accom", "1.0"])
        .args(["--method", method, "--backend", "cpu", "--input"])
        .args([path(&input), "--out", path(&dir.path().join("p.png"))])
        .args(["--display-out", path(&display)])
        .args(extra)
        .output_within(deadline::COMMAND, "nedrt sim");
    assert!(o.status.success(), "{method}: {}", stderr(&o));

    let record = dir.path().join("rec");
    let o = nedrt()
        .current_dir(repo())
        .args(["run", "--calib", path(&calib), "--backend", "cpu"])
        .args(["--preprocess", method, "--source", "dir", "--input"])
        .args([path(&input), "--frames", "1", "--source-rate", "0"])
        .args(["--sink", "record", "--record-dir", path(&record)])
        .args(extra)
        .output_within(deadline::COMMAND, "nedrt run");
    assert!(o.status.success(), "{method}: {}", stderr(&o));
    let recorded = std::fs::read_dir(&record)
        .expect("recording")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.extension().is_some_and(|e| e == "png"))
        .expect("a recorded frame");
    let recorded = image::open(&recorded).expect("png").to_rgb8().into_raw();

    let panel = nedrt_core::calib::Calibration::load(&calib)
        .expect("calib")
        .panel;
    let transfer = nedrt_service::present::transfer::Transfer::from_panel(&panel);
    let rgb = image::open(&display).expect("tif").to_rgb32f().into_raw();
    let planar: Vec<f32> = (0..3)
        .flat_map(|c| rgb.iter().skip(c).step_by(3).copied().collect::<Vec<_>>())
        .collect();
    SimAndService {
        sim_codes: panel_codes(&transfer, &Image::rgb(w, h, planar.clone())),
        recorded,
        sim_display: planar,
        input,
        transfer,
        _dir: dir,
    }
}

/// One image type, one padding rule: for a frame whose sides are not
/// multiples of 8, the display frame `nedrt sim --method proposed` renders
/// is the one `nedrt run` puts on the panel, code for code (both pad by
/// reflection, the trainer's rule). The simulator's former symmetric
/// extension gives different edge pixels, so the comparison can fail.
#[test]
fn sim_and_service_show_the_same_display_frame_for_an_odd_sized_frame() {
    let s = sim_and_service("proposed");
    assert_eq!(s.sim_codes, s.recorded, "sim and service differ");
    // The old rule (symmetric extension) feeds the network other edge
    // pixels: a different display frame.
    let (w, h) = ODD;
    let source = nedrt_core::image_io::load(&s.input).expect("input").image;
    let mut dcnn = nedrt_infer::Dcnn::load(
        &dcnn_model(),
        nedrt_infer::BackendKind::Cpu,
        &nedrt_infer::BackendOptions::default(),
    )
    .expect("model");
    let symmetric = dcnn
        .run_frame(&source.extend_symmetric(0, 0, 64, 48))
        .expect("runs")
        .crop(0, 0, w, h);
    assert_ne!(
        s.codes(&symmetric),
        s.recorded,
        "the padding rule matters here"
    );
}

/// `nedrt run --preprocess ai` puts the AI display's Wiener prefilter on the
/// panel: the same display frame as `nedrt sim --method ai`, and not the
/// unprocessed frame.
#[test]
fn the_service_runs_the_wiener_prefilter_the_simulator_renders() {
    sim_and_service("ai").assert_same_changed_frame();
}

/// `nedrt run --prefilter` puts on the panel the display image `nedrt sim
/// --prefilter` renders, code for code.
#[test]
fn the_service_runs_the_least_squares_prefilter_the_simulator_renders() {
    sim_and_service_with("doe-only", &["--prefilter", "refine:2"]).assert_same_changed_frame();
}

/// `--method proposed` on `backend` gives the same scores as on the CPU.
fn proposed_method_gives_the_same_image_on(backend: &str, needs: &str) {
    let dir = tempfile::tempdir().expect("tempdir");
    let cpu = proposed_on(None, dir.path());
    assert!(cpu.status.success(), "{}", stderr(&cpu));
    let o = proposed_on(Some(backend), dir.path());
    assert!(
        o.status.success(),
        "--backend {backend} (this test needs {needs}): {}",
        stderr(&o)
    );
    assert_eq!(vs_sharp(&o), vs_sharp(&cpu), "{backend}");
}

mod needs_ort {
    use super::*;

    #[test]
    #[ignore = "needs ONNX Runtime (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn proposed_method_gives_the_same_image_on_ort() {
        proposed_method_gives_the_same_image_on("ort", "ONNX Runtime");
    }
}

mod needs_gpu {
    use super::*;

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn proposed_method_gives_the_same_image_on_the_gpu() {
        proposed_method_gives_the_same_image_on("wgpu", "a GPU adapter");
    }
}

#[test]
fn bad_dcnn_inputs_are_clear_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let calib = small_calib();
    let out = dir.path().join("p.png");
    let corrupt = dir.path().join("corrupt.onnx");
    std::fs::write(&corrupt, b"\x08\x07garbage").expect("write");
    let sim_with = |method: &str, model_flag: &str, model: &Path| {
        sim(
            "1.0",
            &out,
            &[
                "--calib",
                path(&calib),
                "--method",
                method,
                model_flag,
                path(model),
            ],
        )
    };
    let o = sim_with("proposed", "--dcnn", &corrupt);
    assert_clean_error(&o, "corrupt.onnx");
    let o = sim_with("lens+dcnn", "--dcnn-lens", &dir.path().join("none.onnx"));
    assert_clean_error(&o, "none.onnx");
    // A backend that cannot start: its environment variable says why.
    let model = dcnn_model();
    let with_backend = |backend: &str, var: &str, value: &str| {
        nedrt()
            .args([
                "--sim",
                "--accom",
                "1",
                "--out",
                path(&out),
                "--calib",
                path(&calib),
            ])
            .args([
                "--method",
                "proposed",
                "--dcnn",
                path(&model),
                "--backend",
                backend,
            ])
            .env(var, value)
            .output_within(deadline::COMMAND, "nedrt --sim")
    };
    let o = with_backend("ort", "ORT_DYLIB_PATH", "/nonexistent/libonnxruntime.so");
    assert_clean_error(
        &o,
        "ORT_DYLIB_PATH=/nonexistent/libonnxruntime.so is not a file",
    );
    // No adapter: ask wgpu for a backend this OS does not have.
    let o = with_backend("wgpu", "WGPU_BACKEND", "metal");
    assert_clean_error(&o, "no GPU adapter");
    assert!(!out.exists(), "nothing written on error");
}

/// A copy of the shipped model (with its DOE) whose card says it takes
/// the Wiener's output before the clamp, with `card` as the card's text.
fn model_with_card(dir: &Path, card: &str) -> PathBuf {
    let model = dir.join("w.onnx");
    std::fs::copy(dcnn_model(), &model).expect("copy model");
    std::fs::copy(
        dcnn_model().with_extension("doe.safetensors"),
        dir.join("w.doe.safetensors"),
    )
    .expect("copy DOE");
    std::fs::write(dir.join("w.card.json"), card).expect("write card");
    model
}

/// A network trained on the Wiener's output (`"input": "wiener-raw"` in
/// its card) runs behind its optics' Wiener prefilter: said in the report,
/// another display image than the network alone, and the same frame from
/// `nedrt sim` and `nedrt run`, code for code.
#[test]
fn a_network_on_the_wiener_output_runs_behind_the_wiener_in_sim_and_service() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = model_with_card(dir.path(), r#"{"input": "wiener-raw", "wiener_k": 0.03}"#);
    let both = sim_and_service_with("proposed", &["--dcnn", path(&model)]);
    both.assert_same_changed_frame();
    let alone = sim_and_service("proposed");
    assert_ne!(
        both.sim_codes, alone.sim_codes,
        "the Wiener stage changed nothing"
    );
    let calib = small_calib();
    let sim_with = |model: &Path, out: &Path| {
        sim(
            "1.0",
            out,
            &[
                "--calib",
                path(&calib),
                "--method",
                "proposed",
                "--dcnn",
                path(model),
            ],
        )
    };
    let o = sim_with(&model, &dir.path().join("p.png"));
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("behind its optics' Wiener prefilter (K = 3e-2) before the clamp"),
        "{}",
        stdout(&o)
    );
    for (card, says) in [
        (r#"{"input": "wiener-raw"}"#, "needs \"wiener_k\""),
        (
            r#"{"input": "wiener-raw", "wiener_k": -1}"#,
            "needs \"wiener_k\"",
        ),
        (
            r#"{"input": "edges"}"#,
            "\"input\": \"edges\" is not an input",
        ),
        ("{", "not a model card (JSON)"),
    ] {
        let model = model_with_card(dir.path(), card);
        let o = sim_with(&model, &dir.path().join("bad.png"));
        assert_clean_error(&o, "w.card.json");
        assert!(stderr(&o).contains(says), "{card}: {}", stderr(&o));
        assert!(!dir.path().join("bad.png").exists());
        let record = dir.path().join("rec");
        let o = nedrt()
            .args(["run", "--calib", path(&small_calib()), "--backend", "cpu"])
            .args(["--preprocess", "proposed", "--dcnn", path(&model)])
            .args(["--source", "pattern", "--frames", "1", "--source-rate", "0"])
            .args(["--sink", "record", "--record-dir", path(&record)])
            .output_within(deadline::COMMAND, "nedrt run");
        assert_clean_error(&o, "w.card.json");
        assert!(!record.exists(), "{card}: the recorder's folder was made");
    }
}
