//! The unrolled preprocessor where a D-CNN goes (`--dcnn NAME.unrolled.toml`):
//! a model made as the trainer makes one (its optics' facts from `nedrt
//! prefilter --operator`, a signed step correction, a classical step), run
//! by `sim`, `eval` and `run` (a fixed level and a level of the frame
//! budget, on the host and as one device stage) from its own lsq start;
//! refused with the reason where its optics are not the display's.

use super::*;

/// The DOE every model here is made through (the shipped one).
fn doe() -> PathBuf {
    repo().join("models/dcnn.doe.safetensors")
}

/// What `nedrt prefilter --operator` says of the optics: (DOE hash,
/// calibration, K), from a kernel file made with the small calibration.
fn optics_facts(dir: &Path) -> (String, String, String) {
    let imgs = dir.join("imgs");
    std::fs::create_dir_all(&imgs).expect("dir");
    write_png(&imgs.join("a.png"), 8, 8);
    let out = dir.join("op");
    let o = run(&[
        "prefilter",
        "--calib",
        path(&small_calib()),
        "--doe",
        path(&doe()),
        "--method",
        "doe+wiener",
        "--prefilter",
        "lsq@sharp",
        "--operator",
        "8x8",
        "--images",
        path(&imgs),
        "--out-dir",
        path(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let bytes = std::fs::read(out.join("operator-8x8.safetensors")).expect("kernels");
    let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes).expect("safetensors");
    let meta = meta.metadata().clone().expect("metadata");
    (
        meta["doe"].clone(),
        meta["calibration"].clone(),
        meta["k_reg"].clone(),
    )
}

fn sha256(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Writes `dir/NAME.unrolled.toml`: steps of (ρ share, α, with a random
/// correction), on the optics of `facts`.
fn write_model(
    dir: &Path,
    name: &str,
    facts: &(String, String, String),
    steps: &[(f64, f64, bool)],
) -> PathBuf {
    let mut text = format!(
        "format = \"nedrt unrolled 1\"\nmethod = \"doe+wiener\"\nobjective = \"sharp\"\n\
         doe = \"{}\"\ncalibration = \"{}\"\nk_reg = {}\nkernels_sha256 = \"made by hand\"\n\
         trained_size = [8, 8]\n",
        facts.0, facts.1, facts.2
    );
    for (k, &(rho, relaxation, network)) in steps.iter().enumerate() {
        text += &format!("\n[[step]]\nrho = {rho}\nrelaxation = {relaxation}\n");
        if network {
            let bytes =
                nedrt_infer::synth::encode(&nedrt_infer::synth::step_correction(9, 4, 2, k as u64));
            let file = format!("{name}.step{}.onnx", k + 1);
            std::fs::write(dir.join(&file), &bytes).expect("onnx");
            text += &format!(
                "network = \"{file}\"\nnetwork_sha256 = \"{}\"\n",
                sha256(&bytes)
            );
        }
    }
    let manifest = dir.join(format!("{name}.unrolled.toml"));
    std::fs::write(&manifest, text).expect("manifest");
    manifest
}

/// `nedrt sim` of `args` on a 24×16 frame with the small calibration.
fn sim_small(dir: &Path, name: &str, args: &[&str]) -> Output {
    let input = dir.join("frame.png");
    if !input.exists() {
        write_png(&input, 24, 16);
    }
    let calib = small_calib();
    let out = dir.join(format!("{name}.png"));
    let mut all = vec!["--calib", path(&calib), "--input", path(&input)];
    all.extend_from_slice(args);
    sim("1.0", &out, &all)
}

#[test]
fn an_unrolled_model_without_corrections_is_the_split_solver_and_with_them_moves() {
    let dir = tempfile::tempdir().expect("tempdir");
    let facts = optics_facts(dir.path());
    let d = dir.path();
    let classical = write_model(d, "classical", &facts, &[(0.05, 1.8, false); 2]);
    let learned = write_model(
        d,
        "learned",
        &facts,
        &[(0.05, 1.8, true), (0.05, 1.8, false)],
    );
    let doe = doe();
    let proposed = |model: &Path, name: &str| {
        let o = sim_small(
            d,
            name,
            &[
                "--method",
                "proposed",
                "--dcnn",
                path(model),
                "--doe",
                path(&doe),
            ],
        );
        assert!(o.status.success(), "{name}: {}", stderr(&o));
        assert!(stdout(&o).contains("unrolled"), "{}", stdout(&o));
        vs_sharp(&o)
    };
    let admm = sim_small(
        d,
        "admm",
        &[
            "--method",
            "doe+wiener",
            "--prefilter",
            "admm:2@sharp",
            "--doe",
            path(&doe),
        ],
    );
    assert!(admm.status.success(), "{}", stderr(&admm));
    // Two uncorrected steps at the shipped schedule are admm:2, score for score.
    assert_eq!(proposed(&classical, "classical"), vs_sharp(&admm));
    // The lsq start's K is the model's own (as a D-CNN's card names its
    // Wiener's), whatever the display's.
    let other_k = write_model(
        d,
        "k",
        &(facts.0.clone(), facts.1.clone(), "0.5".into()),
        &[(0.05, 1.8, false); 2],
    );
    assert_ne!(proposed(&other_k, "k"), vs_sharp(&admm));
    assert_ne!(proposed(&learned, "learned"), vs_sharp(&admm));
    // eval takes it as it takes a D-CNN.
    let imgs = d.join("imgs");
    let o = run(&[
        "eval",
        "--calib",
        path(&small_calib()),
        "--images",
        path(&imgs),
        "--methods",
        "proposed",
        "--dcnn",
        path(&learned),
        "--doe",
        path(&doe),
        "--out-dir",
        path(&d.join("eval")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("learned.unrolled.toml"),
        "{}",
        stdout(&o)
    );
}

#[test]
fn an_unrolled_model_on_other_optics_is_refused_with_the_reason_by_sim_and_run() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let facts = optics_facts(d);
    let model = write_model(d, "m", &facts, &[(0.05, 1.8, true)]);
    // Without --doe the display has the calibration's DOE, not the model's.
    let o = sim_small(
        d,
        "other",
        &["--method", "proposed", "--dcnn", path(&model)],
    );
    assert_clean_error(&o, "trained through DOE");
    assert!(stderr(&o).contains("m.unrolled.toml"), "{}", stderr(&o));
    // The lens alone is not the optics it solves through.
    let o = sim_small(
        d,
        "lens",
        &["--method", "lens+dcnn", "--dcnn-lens", path(&model)],
    );
    assert_clean_error(&o, "not lens+dcnn's");
    // `run` checks it before its sink opens: nothing is recorded.
    let rec = d.join("rec");
    let o = run(&[
        "run",
        "--calib",
        path(&small_calib()),
        "--preprocess",
        "proposed",
        "--dcnn",
        path(&model),
        "--frames",
        "1",
        "--sink",
        "record",
        "--record-dir",
        path(&rec),
    ]);
    assert_clean_error(&o, "trained through DOE");
    assert!(!rec.exists(), "a refused run made its record folder");
}

/// `nedrt run` puts on the panel the display frame `nedrt sim` renders for
/// an unrolled model, code for code, on an odd-sized panel (61×45, whose
/// sides the device FFT lacks: the host runs it); its correction moved
/// the frame from the classical steps'.
#[test]
fn run_shows_the_display_frame_sim_renders_for_an_unrolled_model() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let facts = optics_facts(d);
    let learned = write_model(
        d,
        "learned",
        &facts,
        &[(0.05, 1.8, true), (0.05, 1.8, false)],
    );
    let classical = write_model(d, "classical", &facts, &[(0.05, 1.8, false); 2]);
    let doe = doe();
    let shown = |model: &Path| {
        super::dcnn::sim_and_service_with("proposed", &["--dcnn", path(model), "--doe", path(&doe)])
    };
    let learned = shown(&learned);
    assert_codes_of(&learned);
    assert_ne!(
        learned.sim_codes,
        panel_codes_of_input(&learned),
        "the model changed nothing"
    );
    let classical = shown(&classical);
    assert_codes_of(&classical);
    assert_ne!(
        learned.recorded, classical.recorded,
        "the learned correction changed nothing"
    );
}

/// Every recorded code is the one of the simulator's display value, up to
/// 1e-5 in linear intensity either side of the code's interval: the
/// correction's convolutions (tract, several threads) sum in an order that
/// differs from run to run by about 1e-6, which moves a value lying on a
/// threshold to its neighbour code.
fn assert_codes_of(s: &super::dcnn::SimAndService) {
    let n = s.recorded.len() / 3;
    let mut off = 0;
    for (i, &code) in s.recorded.iter().enumerate() {
        let (c, p) = (i % 3, i / 3);
        let x = s.sim_display[c * n + p].clamp(0.0, 1.0);
        let t = s.transfer.thresholds(c);
        let lo = if code == 0 {
            f32::MIN
        } else {
            t[code as usize - 1]
        };
        let hi = t.get(code as usize).copied().unwrap_or(f32::MAX);
        if !(x >= lo - 1e-5 && x < hi + 1e-5) {
            off += 1;
        }
    }
    assert_eq!(off, 0, "{off} recorded codes are not the simulator's");
}

fn panel_codes_of_input(s: &super::dcnn::SimAndService) -> Vec<u8> {
    s.input_codes()
}

/// The frame budget's ladder takes unrolled models as network levels, one
/// per K (`--ladder-network`, then `--dcnn`), each named by its manifest's
/// stem, in the order given; refused with the reason without a ladder or
/// where two levels would share a name.
#[test]
fn unrolled_models_are_levels_of_the_frame_budget() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let facts = optics_facts(d);
    let k1 = write_model(d, "k1", &facts, &[(0.05, 1.8, true)]);
    let k2 = write_model(d, "k2", &facts, &[(0.05, 1.8, true), (0.05, 1.8, false)]);
    let report = d.join("report.json");
    let run_with = |args: &[&str]| {
        nedrt()
            .current_dir(repo())
            .args(["run", "--calib", path(&small_panel()), "--backend", "cpu"])
            .args([
                "--doe",
                path(&doe()),
                "--frames",
                "4",
                "--source-rate",
                "60",
            ])
            .args(["--sink", "record", "--record-dir", path(&d.join("rec"))])
            .args(args)
            .output_within(deadline::COMMAND, "nedrt run --preprocess auto")
    };
    let o = run_with(&[
        "--preprocess",
        "auto:admm:10..",
        "--ladder-network",
        path(&k1),
        "--dcnn",
        path(&k2),
        "--report-json",
        path(&report),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("JSON");
    let budget = &r["frame_budget"];
    // Each kept or, where no better than a faster level, dropped: in the
    // ladder's order either way.
    let mut named: Vec<String> = budget["levels"]
        .as_array()
        .expect("levels")
        .iter()
        .filter_map(|l| l["name"].as_str().map(str::to_string))
        .collect();
    named.extend(
        budget["dropped"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(|n| n.as_str().map(str::to_string)),
    );
    for level in ["admm:10", "k1", "k2"] {
        assert!(named.iter().any(|n| n == level), "{level}: {budget}");
    }
    let frames: u64 = budget["levels"]
        .as_array()
        .expect("levels")
        .iter()
        .filter_map(|l| l["frames"].as_u64())
        .sum();
    assert_eq!(frames, 4, "every frame ran a level: {budget}");
    std::fs::remove_dir_all(d.join("rec")).expect("remove the recording");

    let o = run_with(&[
        "--preprocess",
        "proposed",
        "--dcnn",
        path(&k2),
        "--ladder-network",
        path(&k1),
    ]);
    assert_clean_error(&o, "--ladder-network adds a level");
    let o = run_with(&[
        "--preprocess",
        "auto",
        "--dcnn",
        path(&k2),
        "--ladder-network",
        path(&k2),
    ]);
    assert_clean_error(&o, "would be named \"k2\"");
    assert!(
        !d.join("rec").exists(),
        "a refused run made its record folder"
    );
}

mod needs_gpu {
    use super::*;

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn an_unrolled_model_on_the_device_scores_what_the_host_scores() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        let facts = optics_facts(d);
        let model = write_model(d, "m", &facts, &[(0.04, 1.7, true), (0.06, 1.8, false)]);
        let doe = doe();
        let on = |backend: &str| {
            let o = sim_small(
                d,
                backend,
                &[
                    "--method",
                    "proposed",
                    "--dcnn",
                    path(&model),
                    "--doe",
                    path(&doe),
                    "--backend",
                    backend,
                ],
            );
            assert!(o.status.success(), "{backend}: {}", stderr(&o));
            o
        };
        let (cpu, gpu) = (on("cpu"), on("wgpu"));
        assert!(stdout(&gpu).contains(") on wgpu"), "{}", stdout(&gpu));
        assert_eq!(vs_sharp(&cpu), vs_sharp(&gpu));
    }

    /// On the sink's GPU the model is one device stage of the frame: the
    /// frame uploaded once, nothing read back.
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn run_keeps_an_unrolled_models_frames_on_the_device() {
        let dir = tempfile::tempdir().expect("tempdir");
        let d = dir.path();
        let facts = optics_facts(d);
        let model = write_model(d, "m", &facts, &[(0.05, 1.8, true), (0.05, 1.8, false)]);
        let o = nedrt()
            .current_dir(repo())
            .args(["run", "--calib", path(&small_panel()), "--backend", "wgpu"])
            .args(["--preprocess", "proposed", "--dcnn", path(&model)])
            .args(["--doe", path(&doe()), "--frames", "3", "--source-rate", "4"])
            .args(["--sink", "headless"])
            .output_within(deadline::COMMAND, "nedrt run --sink headless");
        assert!(o.status.success(), "{}", stderr(&o));
        let out = stdout(&o);
        // A loaded machine may drop a frame as stale; none may fail.
        assert!(out.contains("3 submitted, "), "{out}");
        assert!(out.contains(" 0 failed;"), "{out}");
        assert!(
            out.contains("on the device (2 split-solver steps, 1 with a learned correction)"),
            "{out}"
        );
        assert!(out.contains("0.00 read-backs"), "{out}");
    }
}
