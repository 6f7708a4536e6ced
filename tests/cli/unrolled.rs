//! The unrolled preprocessor where a D-CNN goes (`--dcnn NAME.unrolled.toml`):
//! a model made as the trainer makes one (its optics' facts from `nedrt
//! prefilter --operator`, a signed step correction, a classical step), run
//! by `sim` and `eval` from its own lsq start; refused with the reason
//! where its optics are not the display's, and by `run`, which does not
//! compose it yet.

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
fn an_unrolled_model_on_other_optics_or_in_run_is_refused_with_the_reason() {
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
    ]);
    assert_clean_error(&o, "does not take it yet");
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
}
