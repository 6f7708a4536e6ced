//! The studies: stability and tradeoff (with the picker).

use super::*;

#[test]
fn stability_refuses_a_missing_output_folder_before_the_work() {
    let dir = tempfile::tempdir().expect("tmp");
    let missing = dir.path().join("missing");
    let out = missing.join("stability.md");
    let (images, model) = (repo().join("data/images/test"), dcnn_model());
    let o = run(&[
        "--dcnn",
        path(&model),
        "stability",
        "--images",
        path(&images),
        "--no-cache",
        "--out",
        path(&out),
    ]);
    assert_clean_error(&o, "does not exist");
    assert!(stderr(&o).contains("missing"), "{}", stderr(&o));
    assert!(!missing.exists());
}

#[test]
fn tradeoff_writes_the_chart_and_the_picker_reads_it() {
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = dir.path().join("imgs");
    std::fs::create_dir(&imgs).expect("dir");
    write_png(&imgs.join("a.png"), 24, 16);
    write_png(&imgs.join("b.png"), 16, 16);
    let out = dir.path().join("tradeoff");
    let calib = small_calib();
    let model = dcnn_model();
    let designs = format!(
        "{},{}",
        repo().join("designs/multifocal.toml").display(),
        repo().join("designs/allsharp.toml").display()
    );
    let base = ["--calib", path(&calib)];
    // The study on two designs, into `out`, starting nothing after `budget` s.
    let tradeoff = |out: &std::path::Path, budget: &str| {
        run(&[
            &base[..],
            &[
                "tradeoff",
                "--designs",
                &designs,
                "--images",
                path(&imgs),
                "--out-dir",
                path(out),
                "--size",
                "32x24",
                "--backends",
                "cpu",
                "--repeat",
                "1",
                "--no-fidelity",
                "--models",
                path(&model),
                "--time-budget",
                budget,
            ],
        ]
        .concat())
    };
    // A budget never reached drops nothing (the names below).
    let o = tradeoff(&out, "1e6");
    assert!(o.status.success(), "{}", stderr(&o));
    for f in [
        "tradeoff.md",
        "tradeoff.json",
        "tradeoff.png",
        "tradeoff.svg",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let table = out.join("tradeoff.json");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&table).expect("json")).expect("parse");
    let records = json["records"].as_array().expect("records");
    let names: Vec<&str> = records
        .iter()
        .map(|r| r["name"].as_str().expect("name"))
        .collect();
    for want in [
        "conventional",
        "ai",
        "doe-only",
        "doe+wiener",
        "proposed dcnn cpu f32",
        // The least-squares prefilters on each design, with its own objective.
        "doe+wiener multifocal lsq@target",
        "doe+wiener multifocal refine:3@target",
        "doe+wiener multifocal admm:3@target",
        "doe+wiener multifocal optimal@target",
        "doe+wiener allsharp refine:10@sharp",
        "doe+wiener allsharp optimal@sharp",
    ] {
        assert!(names.contains(&want), "{want} missing: {names:?}");
    }
    // The rows a lent GPU is asked for run first (what a --time-budget
    // keeps): the designs' prefilters, then the networks, the rest last.
    let at = |n: &str| names.iter().position(|x| *x == n).expect(n);
    assert!(
        names[0].starts_with("doe+wiener multifocal ") && names[0].contains('@'),
        "{names:?}"
    );
    assert!(at("doe+wiener allsharp optimal@sharp") < at("proposed dcnn cpu f32"));
    assert!(at("proposed dcnn cpu f32") < at("conventional"));
    assert!(records.iter().any(|r| r["on_front"] == true));
    let md = std::fs::read_to_string(out.join("tradeoff.md")).expect("md");
    assert!(
        md.contains("32×24") && md.contains("models/dcnn.onnx ("),
        "{md}"
    );
    // --add measures a design's prefilters only and adds their rows,
    // replacing a row of the same name and keeping every other.
    let add = |out: &std::path::Path, size: &str, prefilter: &str| {
        run(&[
            &base[..],
            &[
                "tradeoff",
                "--add",
                "--designs",
                path(&repo().join("designs/multifocal.toml")),
                "--prefilter",
                prefilter,
                "--images",
                path(&imgs),
                "--out-dir",
                path(out),
                "--size",
                size,
                "--backends",
                "cpu",
                "--repeat",
                "1",
                "--no-fidelity",
                "--models",
                path(&model),
            ],
        ]
        .concat())
    };
    let before = std::fs::read_to_string(&table).expect("json");
    let o = add(&out, "32x24", "admm:2,refine:3");
    assert!(o.status.success(), "{}", stderr(&o));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&table).expect("json")).expect("parse");
    let added: Vec<&str> = json["records"]
        .as_array()
        .expect("records")
        .iter()
        .map(|r| r["name"].as_str().expect("name"))
        .collect();
    assert_eq!(added.len(), names.len() + 1, "{added:?}");
    for n in names
        .iter()
        .chain(["doe+wiener multifocal admm:2@target"].iter())
    {
        assert!(added.contains(n), "{n} missing after --add: {added:?}");
    }
    // Another frame size cannot share the chart: refused, the table as it was.
    let added_table = std::fs::read_to_string(&table).expect("json");
    assert_ne!(added_table, before);
    assert_clean_error(&add(&out, "40x24", "admm:1"), "frame size");
    assert_eq!(std::fs::read_to_string(&table).expect("json"), added_table);
    let o = add(&dir.path().join("none"), "32x24", "admm:1");
    assert_clean_error(&o, "there is none");
    // The fastest configuration meets an easy floor; among equally fast
    // ones (several preprocess nothing) the picker takes the best PSNR.
    let fastest = records
        .iter()
        .min_by(|a, b| {
            let ms = |r: &serde_json::Value| r["latency_ms"].as_f64().unwrap_or(f64::MAX);
            let db = |r: &serde_json::Value| r["mean_psnr_db"].as_f64().unwrap_or(f64::MIN);
            ms(a).total_cmp(&ms(b)).then(db(b).total_cmp(&db(a)))
        })
        .expect("one");
    let pick = |floor: &str, budget: &str| {
        run(&[
            "pick",
            "--table",
            path(&table),
            "--min-psnr",
            floor,
            "--budget-ms",
            budget,
        ])
    };
    let o = pick("0", "1e9");
    assert!(o.status.success(), "{}", stderr(&o));
    let fastest_name = fastest["name"].as_str().expect("name");
    assert!(
        stdout(&o).starts_with(&format!("{fastest_name}:")),
        "{}",
        stdout(&o)
    );
    assert_clean_error(
        &pick("99", "1e9"),
        "no configuration reaches the quality floor",
    );
    assert_clean_error(&pick("0", "0"), "no configuration meets both");
    assert_clean_error(&pick("nan", "1"), "--min-psnr NaN: not a number");
    std::fs::write(dir.path().join("bad.json"), "{\"records\": 3}").expect("write");
    let o = run(&[
        "pick",
        "--table",
        path(&dir.path().join("bad.json")),
        "--min-psnr",
        "1",
        "--budget-ms",
        "1",
    ]);
    assert_clean_error(&o, "not a table written by `nedrt tradeoff`");
    // A D-CNN without its DOE is refused before any work.
    let lonely = dir.path().join("lonely.onnx");
    std::fs::copy(dcnn_model(), &lonely).expect("copy");
    let o = run(&[
        &base[..],
        &[
            "tradeoff",
            "--images",
            path(&imgs),
            "--models",
            path(&lonely),
        ],
    ]
    .concat());
    assert_clean_error(&o, "no DOE beside this D-CNN");
    // A budget spent before the first configuration: a clean error, no table.
    let spent = dir.path().join("spent");
    let o = tradeoff(&spent, "0");
    assert_clean_error(&o, "--time-budget");
    assert!(
        stderr(&o).contains("before the first configuration ran"),
        "{}",
        stderr(&o)
    );
    assert!(!spent.join("tradeoff.json").exists());
    assert_clean_error(
        &tradeoff(&spent, "nan"),
        "--time-budget NaN: not a number of seconds",
    );
}

mod needs_gpu {
    use super::*;

    /// `bench inference` of the wgpu backend once at 16×16.
    const INFER_16: [&str; 8] = [
        "bench",
        "inference",
        "--backends",
        "wgpu",
        "--sizes",
        "16x16",
        "--repeat",
        "1",
    ];

    /// `bench tune` writes this adapter's table (the heuristics' tile and
    /// one other per conv shape: each tile is a kernel lavapipe compiles
    /// for seconds; the DCT filter's shape at the size), the wgpu backend
    /// and the device prefilters then read it, and a broken table stops
    /// the backend with an error naming the file.
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn bench_tune_writes_the_table_the_backend_then_reads() {
        let dir = tempfile::tempdir().expect("tempdir");
        let tuning = dir.path().join("tuning");
        let tune = |tiles: &str| {
            run(&[
                "--tuning",
                path(&tuning),
                "bench",
                "tune",
                "--networks",
                "half",
                "--sizes",
                "16x16",
                "--tiles",
                tiles,
                "--fused-tiles",
                "8x8",
                "--repeat",
                "1",
            ])
        };
        let o = tune("8x4");
        assert!(o.status.success(), "{}", stderr(&o));
        let out = stdout(&o);
        assert!(
            out.contains("| conv | layer input | heuristic tile | µs | tuned tile | µs |"),
            "{out}"
        );
        assert!(out.contains("| 3×3 16→16 | 16×16 | 16×16 |"), "{out}");
        let tables: Vec<PathBuf> = std::fs::read_dir(&tuning)
            .expect("the folder is made")
            .map(|e| e.expect("entry").path())
            .collect();
        assert_eq!(tables.len(), 1, "{tables:?}");
        let text = std::fs::read_to_string(&tables[0]).expect("reads");
        let table: toml::Value = toml::from_str(&text).expect("toml");
        let convs = table["conv"].as_array().expect("conv entries");
        // The half network's 3×3 shapes at 16, 8, 4 and 2 pixels, and its 1×1.
        assert_eq!(convs.len(), 12, "{text}");
        for c in convs {
            let tile = (c["px"].as_integer(), c["threads_y"].as_integer());
            let (w, h) = (
                c["width"].as_integer().expect("w"),
                c["height"].as_integer().expect("h"),
            );
            let heuristic = nedrt_infer::gpu::codegen::ConvTile::for_layer(
                w as u32,
                h as u32,
                c["kernel"].as_integer().expect("k") as usize,
                nedrt_infer::gpu::codegen::Dtype::F32,
            );
            assert!(
                tile == (Some(1), Some(4))
                    || tile
                        == (
                            Some(i64::from(heuristic.px)),
                            Some(i64::from(heuristic.threads_y))
                        ),
                "{c}"
            );
            assert!(
                c["tuned_ns"].as_integer() <= c["heuristic_ns"].as_integer(),
                "{c}"
            );
        }
        assert_eq!(
            table["adapter"]["driver"].as_str(),
            Some("llvmpipe"),
            "{text}"
        );
        // The fused levels: the half network's 7 (4 encoder, 3 decoder),
        // one entry a shape whose intermediate fits lavapipe's workgroup
        // memory at some tile, each timed fused and unfused.
        assert!(
            out.contains("| fused level | layer input | unfused µs | fused tile | µs |"),
            "{out}"
        );
        assert!(out.contains("| 3×3 3→16, 3×3 →16 | 16×16 |"), "{out}");
        let fused = table["fused"].as_array().expect("fused entries");
        assert!((1..=7).contains(&fused.len()), "{text}");
        for f in fused {
            assert!(
                f["fused_ns"].as_integer() > Some(0) && f["unfused_ns"].as_integer() > Some(0),
                "{f}"
            );
        }
        // The DCT filter at the size: one entry.
        assert!(out.contains("### The DCT filter (three planes)"), "{out}");
        let ffts = table["fft"].as_array().expect("fft entries");
        assert_eq!(ffts.len(), 1, "{text}");
        assert_eq!(
            (
                ffts[0]["width"].as_integer(),
                ffts[0]["height"].as_integer()
            ),
            (Some(16), Some(16))
        );
        // A device prefilter's kernels ask for the table: `bench fft` says
        // so and times the tuned shape beside the heuristics'.
        let o = {
            let mut c = nedrt();
            c.env("NEDRT_LOG", "info").args([
                "--tuning",
                path(&tuning),
                "bench",
                "fft",
                "--sizes",
                "16x16",
                "--repeat",
                "1",
                "--fft-paths",
                "auto",
            ]);
            c.output_within(deadline::COMMAND, "nedrt")
        };
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(
            stderr(&o).contains(&format!(
                "DCT filter shapes of {} tuned for ",
                tables[0].display()
            )) && stderr(&o).contains(" at 16×16"),
            "{}",
            stderr(&o)
        );
        assert!(
            stdout(&o).contains("| 16×16 | the adapter's tuned shape: "),
            "{}",
            stdout(&o)
        );
        // The backend finds it for this adapter.
        let infer = || {
            let mut c = nedrt();
            c.env("NEDRT_LOG", "info")
                .args(["--tuning", path(&tuning)])
                .args(INFER_16);
            c.output_within(deadline::COMMAND, "nedrt")
        };
        let o = infer();
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(
            stderr(&o).contains(&format!("conv tiles of {}", tables[0].display())),
            "{}",
            stderr(&o)
        );
        // --coop-only tunes the layers on cooperative matrices alone
        // (lavapipe has none): the table's tiled entries stay as they were.
        let o = run(&[
            "--tuning",
            path(&tuning),
            "bench",
            "tune",
            "--coop-only",
            "--networks",
            "half",
            "--sizes",
            "16x16",
            "--repeat",
            "1",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(stdout(&o).contains("0 tiles timed"), "{}", stdout(&o));
        let again = std::fs::read_to_string(&tables[0]).expect("reads");
        let again: toml::Value = toml::from_str(&again).expect("toml");
        assert_eq!(again["conv"], table["conv"], "the tiled entries changed");
        assert_eq!(
            again["fft"], table["fft"],
            "the DCT filter's entries changed"
        );
        assert!(again.get("coop").is_none(), "{again}");
        assert_eq!(again["fused"], table["fused"], "the fused entries changed");
        // A tile the template does not build is refused by name.
        assert_clean_error(&tune("12x4"), "a conv tile is 8, 16 or 32 pixels wide");
        let bad_fused = run(&[
            "--tuning",
            path(&tuning),
            "bench",
            "tune",
            "--fused-tiles",
            "12x8",
            "--networks",
            "half",
        ]);
        assert_clean_error(&bad_fused, "a fused level's tile is 8x8, 16x8");
        // A broken table stops the backend, naming it (the bench reports
        // each case it could not run).
        std::fs::write(&tables[0], text.replace("threads_y = ", "threads_y = 3 + "))
            .expect("writes");
        let o = infer();
        let said = format!("{}{}", stdout(&o), stderr(&o));
        assert!(
            said.contains(&format!("skipped: tuning table {}", tables[0].display())),
            "{said}"
        );
    }

    /// `bench inference` names the adapter with its cooperative-matrix
    /// shapes (a record and the header) and gives each case's GPU time
    /// beside its wall time; `--per-layer` the whole frame's two times and
    /// each layer against its floors.
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn bench_inference_tells_gpu_time_from_wall_time() {
        let o = run(&INFER_16);
        assert!(o.status.success(), "{}", stderr(&o));
        let out = stdout(&o);
        let records: Vec<serde_json::Value> = out
            .lines()
            .filter(|l| l.starts_with('{'))
            .map(|l| serde_json::from_str(l).expect("json"))
            .collect();
        let adapter = records
            .iter()
            .find(|r| r["kind"] == "adapter")
            .expect("an adapter record");
        assert!(adapter["cooperative_matrices"].is_array(), "{adapter}");
        assert!(
            out.contains("cooperative matrices (M×N×K A·B→C): "),
            "{out}"
        );
        assert!(out.contains("--conv-path auto"), "{out}");
        assert!(
            out.contains("| wall median ms | wall min ms | GPU median ms | GPU min ms |"),
            "{out}"
        );
        let cases: Vec<_> = records
            .iter()
            .filter(|r| r["kind"] == "dcnn_latency")
            .collect();
        assert!(!cases.is_empty(), "{out}");
        for r in cases {
            assert_eq!(r["conv_path"], "auto", "{r}");
            assert!(
                r["gpu_median_s"].is_f64() || r["gpu_median_s"].is_null(),
                "{r}"
            );
        }
        let o = run(&[
            "--conv-path",
            "tiled",
            "bench",
            "inference",
            "--per-layer",
            "--sizes",
            "16x16",
            "--repeat",
            "1",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let out = stdout(&o);
        for says in [
            "--conv-path tiled",
            "ms wall",
            "ms GPU",
            "CUDA-core floor = max(MACs",
            "| × it | tensor-core floor ms | × it |",
        ] {
            assert!(out.contains(says), "{says}: {out}");
        }
        // f16 storage summed in f32 (and f16 FMAs forced, on any adapter):
        // each layer says how it sums, the records name the choice.
        for (math, says) in [
            ("f32", "f32 arithmetic on f16 storage"),
            ("f16", "f16 arithmetic"),
        ] {
            let o = run(&[&["--precision", "f16", "--f16-math", math][..], &INFER_16].concat());
            if stderr(&o).contains("shader-f16") {
                continue; // an adapter without f16 shaders: nothing to sum in f16
            }
            assert!(o.status.success(), "{}", stderr(&o));
            let out = stdout(&o);
            let case = out
                .lines()
                .filter(|l| l.starts_with('{'))
                .map(|l| serde_json::from_str::<serde_json::Value>(l).expect("json"))
                .find(|r| r["kind"] == "dcnn_latency")
                .expect("a case");
            assert_eq!(case["conv_path"], format!("auto, {math} math"), "{case}");
            assert!(
                case["device"].as_str().unwrap_or_default().contains(says)
                    || out.contains(says)
                    || stderr(&o).contains(says),
                "{says}: {out}"
            );
        }
    }

    /// `--backends …,wgpu` adds each prefilter the device runs as a row
    /// of its own, scored as the CPU's row (the same display images) and
    /// timed on the device.
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn tradeoff_puts_the_device_prefilters_beside_the_cpu_ones() {
        let dir = tempfile::tempdir().expect("tmp");
        let imgs = dir.path().join("imgs");
        std::fs::create_dir(&imgs).expect("dir");
        write_png(&imgs.join("a.png"), 24, 16);
        let out = dir.path().join("tradeoff");
        let calib = small_calib();
        let designs = repo().join("designs/multifocal.toml").display().to_string();
        let model = dcnn_model();
        let o = run(&[
            "--calib",
            path(&calib),
            "tradeoff",
            "--designs",
            &designs,
            "--images",
            path(&imgs),
            "--out-dir",
            path(&out),
            "--size",
            "32x24",
            "--backends",
            "cpu,wgpu",
            "--repeat",
            "1",
            "--no-fidelity",
            "--models",
            path(&model),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join("tradeoff.json")).expect("json"),
        )
        .expect("parse");
        let records = json["records"].as_array().expect("records");
        let by_name = |n: &str| records.iter().find(|r| r["name"] == n);
        for cpu in [
            "ai",
            "doe+wiener",
            "doe+wiener multifocal",
            "doe+wiener multifocal lsq@target",
            "doe+wiener multifocal refine:3@target",
        ] {
            let a = by_name(cpu).unwrap_or_else(|| panic!("{cpu} missing"));
            let d = by_name(&format!("{cpu} wgpu")).unwrap_or_else(|| panic!("{cpu} wgpu missing"));
            assert_eq!(d["backend"], "wgpu", "{d}");
            let db = |r: &serde_json::Value| r["mean_psnr_db"].as_f64().expect("db");
            assert!(
                (db(a) - db(d)).abs() <= 0.01,
                "{cpu}: {} against {}",
                db(a),
                db(d)
            );
        }
        // No device row where the device runs nothing (conventional) or
        // the host solver (optimal).
        assert!(by_name("conventional wgpu").is_none());
        assert!(by_name("doe+wiener multifocal optimal@target wgpu").is_none());
    }
}

#[test]
fn stability_refuses_a_bad_eye_before_the_work() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("stability.md");
    let (images, model) = (repo().join("data/images/test"), dcnn_model());
    let run_with = |eyes: &str| {
        run(&[
            "--dcnn",
            path(&model),
            "stability",
            "--images",
            path(&images),
            "--no-cache",
            "--eyes",
            eyes,
            "--out",
            path(&out),
        ])
    };
    assert_clean_error(&run_with("4mm,huge"), "\"huge\"");
    // A pupil that the eyepiece's rim hides entirely at that field angle.
    assert_clean_error(&run_with("2mm@40"), "eye.field_deg");
    assert!(!out.exists());
}
