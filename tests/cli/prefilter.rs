//! `--prefilter` (lsq, refine:K, optimal) in `sim` and `eval`, and `nedrt
//! prefilter` (the trainer's teacher and kernels).

use super::*;

/// One image, `nedrt --calib <small> eval` of doe-only with every prefilter.
#[test]
fn eval_adds_a_row_per_prefilter_and_the_optimum_has_the_least_error() {
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = dir.path().join("imgs");
    std::fs::create_dir(&imgs).expect("dir");
    write_png(&imgs.join("a.png"), 24, 16);
    let out = dir.path().join("eval");
    let o = run(&[
        "--calib",
        path(&small_calib()),
        "eval",
        "--images",
        path(&imgs),
        "--out-dir",
        path(&out),
        "--methods",
        "doe-only",
        "--prefilter",
        "native,lsq,refine:3,optimal,optimal",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).expect("json"))
            .expect("parse");
    let methods = json["methods"].as_array().expect("methods");
    let names: Vec<&str> = methods
        .iter()
        .map(|m| m["method"].as_str().expect("name"))
        .collect();
    // Repeats are dropped; each row names its prefilter and objective.
    assert_eq!(
        names,
        [
            "doe-only",
            "doe-only lsq@target",
            "doe-only refine:3@target",
            "doe-only optimal@target"
        ]
    );
    // With one image, Σ_D 10^(−PSNR_D/10) over 0–2.5 D is the objective the
    // prefilters minimise (up to a constant factor).
    let objective = |m: &serde_json::Value| -> f64 {
        m["rows"]
            .as_array()
            .expect("rows")
            .iter()
            .filter(|r| r["accommodation_d"].as_f64().expect("d") <= 2.5 + 1e-9)
            .map(|r| 10f64.powf(-r["vs_target"]["psnr_db"].as_f64().expect("db") / 10.0))
            .sum()
    };
    let e: Vec<f64> = methods.iter().map(objective).collect();
    assert!(e[2] < e[1], "refine:3 {} not below lsq {}", e[2], e[1]);
    assert!(e[3] <= e[2], "optimal {} above refine:3 {}", e[3], e[2]);
    assert!(
        e[3] < e[0],
        "optimal {} not below no prefilter {}",
        e[3],
        e[0]
    );
}

#[test]
fn sim_describes_the_prefilter_and_writes_its_display_image() {
    let dir = tempfile::tempdir().expect("tmp");
    let img = dir.path().join("a.png");
    write_png(&img, 16, 16);
    let display = dir.path().join("display.tif");
    let o = run(&[
        "--calib",
        path(&small_calib()),
        "sim",
        "--accom",
        "0.5",
        "--input",
        path(&img),
        "--method",
        "ai",
        "--prefilter",
        "optimal@sharp",
        "--out",
        path(&dir.path().join("p.png")),
        "--display-out",
        path(&display),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = stdout(&o);
    assert!(s.contains("method ai optimal@sharp"), "{s}");
    assert!(
        s.contains("bounded least-squares optimum of ai (sharp objective over 6 depths"),
        "{s}"
    );
    let d = image::open(&display).expect("display").into_rgb32f();
    assert!(
        d.pixels()
            .flat_map(|p| p.0)
            .all(|v| (0.0..=1.0).contains(&v))
    );
    // A display image cannot be both given and made.
    let o = run(&[
        "--calib",
        path(&small_calib()),
        "sim",
        "--accom",
        "0.5",
        "--input",
        path(&img),
        "--display-image",
        path(&display),
        "--prefilter",
        "lsq",
        "--out",
        path(&dir.path().join("q.png")),
    ]);
    assert_clean_error(&o, "--prefilter lsq@target makes a display image");
    let o = run(&["sim", "--accom", "1", "--prefilter", "refine:0"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("from 1 to 1000"), "{}", stderr(&o));
}

/// `nedrt prefilter` with the small calibration on the images in `imgs`,
/// writing to `out`, with `extra` arguments.
fn prefilter_in(imgs: &Path, out: &Path, extra: &[&str]) -> Output {
    let calib = small_calib();
    let mut args = vec![
        "--calib",
        path(&calib),
        "prefilter",
        "--images",
        path(imgs),
        "--out-dir",
        path(out),
    ];
    args.extend_from_slice(extra);
    run(&args)
}

#[test]
fn the_prefilter_command_writes_displays_kernels_and_a_manifest() {
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = dir.path().join("imgs");
    std::fs::create_dir(&imgs).expect("dir");
    write_png(&imgs.join("a.png"), 24, 16);
    write_png(&imgs.join("b.png"), 16, 16);
    let out = dir.path().join("teacher");
    let o = prefilter_in(&imgs, &out, &["--method", "doe-only", "--operator", "8x8"]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in [
        "a.tif",
        "b.tif",
        "displays.safetensors",
        "operator-8x8.safetensors",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("prefilter.json")).expect("json"))
            .expect("parse");
    assert_eq!(manifest["prefilter"], "optimal@target");
    let bytes = std::fs::read(out.join("displays.safetensors")).expect("read");
    let t = safetensors::SafeTensors::deserialize(&bytes).expect("safetensors");
    assert_eq!(t.tensor("a").expect("a").shape(), &[3, 16, 24]);
    let bytes = std::fs::read(out.join("operator-8x8.safetensors")).expect("read");
    let t = safetensors::SafeTensors::deserialize(&bytes).expect("safetensors");
    assert_eq!(t.tensor("normal").expect("normal").shape(), &[3, 16, 16]);
    // The lsq filter, the unrolled model's start (its values are checked
    // against the runtime by tests/golden/unrolled, stages' tests/unrolled.rs).
    assert_eq!(t.tensor("linear").expect("linear").shape(), &[3, 16, 16]);
    // A D-CNN method has no network-free display image of its own.
    let o = prefilter_in(
        &imgs,
        &dir.path().join("x"),
        &["--method", "proposed", "--prefilter", "native"],
    );
    assert_clean_error(&o, "needs --prefilter lsq, refine:K, admm:K or optimal");
}

/// `--unclamped` writes the Wiener's output before the panel's clamp:
/// clamped, it is the native prefilter's display image, and the clamp has
/// something to cut.
#[test]
fn the_prefilter_command_writes_the_wiener_before_its_clamp() {
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = dir.path().join("imgs");
    std::fs::create_dir(&imgs).expect("dir");
    // A checkerboard: the prefilter's overshoot at every edge leaves [0, 1].
    image::RgbImage::from_fn(24, 16, |x, y| {
        image::Rgb([((x / 2 + y / 2) % 2 * 255) as u8; 3])
    })
    .save(imgs.join("a.png"))
    .expect("write png");
    let displays = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec!["--method", "ai", "--prefilter", "native"];
        args.extend_from_slice(extra);
        let o = prefilter_in(&imgs, &out, &args);
        assert!(o.status.success(), "{}", stderr(&o));
        let bytes = std::fs::read(out.join("displays.safetensors")).expect("read");
        let t = safetensors::SafeTensors::deserialize(&bytes).expect("safetensors");
        let v = t.tensor("a").expect("a");
        v.data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect::<Vec<f32>>()
    };
    let clamped = displays("clamped", &[]);
    let raw = displays("raw", &["--unclamped"]);
    assert_eq!(raw.len(), clamped.len());
    assert!(
        raw.iter().any(|v| !(0.0..=1.0).contains(v)),
        "nothing to clamp"
    );
    for (r, c) in raw.iter().zip(&clamped) {
        assert_eq!(r.clamp(0.0, 1.0), *c);
    }
}

mod needs_gpu {
    use super::*;

    /// (vs sharp, vs target) PSNR of `nedrt sim`'s report.
    fn scores(o: &Output) -> (f64, f64) {
        let db = |label: &str| {
            stdout(o)
                .lines()
                .find(|l| l.starts_with(label))
                .and_then(|l| l.split_whitespace().nth(3))
                .and_then(|v| v.parse::<f64>().ok())
                .unwrap_or_else(|| panic!("no {label} PSNR in {}", stdout(o)))
        };
        (db("vs sharp"), db("vs target"))
    }

    /// `--backend wgpu` runs the prefilter on the device (the report says
    /// so) and scores what the CPU scores, to 0.01 dB.
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_prefilters_on_the_device_score_what_the_cpu_scores() {
        let dir = tempfile::tempdir().expect("tmp");
        let input = dir.path().join("a.png");
        write_png(&input, 40, 24);
        let out = dir.path().join("p.png");
        for (method, prefilter) in [
            ("ai", "native"),
            ("doe+wiener", "native"),
            ("doe-only", "lsq"),
            ("doe-only", "refine:5"),
            ("doe+wiener", "refine:3@sharp"),
        ] {
            let on = |backend: &str| {
                let o = sim(
                    "1.0",
                    &out,
                    &[
                        "--calib",
                        path(&small_calib()),
                        "--input",
                        path(&input),
                        "--method",
                        method,
                        "--prefilter",
                        prefilter,
                        "--backend",
                        backend,
                    ],
                );
                assert!(
                    o.status.success(),
                    "{method} {prefilter} {backend}: {}",
                    stderr(&o)
                );
                o
            };
            let (cpu, gpu) = (on("cpu"), on("wgpu"));
            assert!(stdout(&gpu).contains("on the device"), "{}", stdout(&gpu));
            assert!(!stdout(&cpu).contains("on the device"), "{}", stdout(&cpu));
            let (a, b) = (scores(&cpu), scores(&gpu));
            assert!(
                (a.0 - b.0).abs() <= 0.01 && (a.1 - b.1).abs() <= 0.01,
                "{method} {prefilter}: CPU {a:?}, device {b:?}"
            );
        }
        // A side of 34 = 2·17: the device FFT has no radix 17, so the
        // prefilter runs on the host, says so, and scores as the CPU.
        let odd = dir.path().join("odd.png");
        write_png(&odd, 34, 24);
        let on = |backend: &str| {
            sim(
                "1.0",
                &out,
                &[
                    "--calib",
                    path(&small_calib()),
                    "--input",
                    path(&odd),
                    "--method",
                    "doe+wiener",
                    "--prefilter",
                    "refine:3",
                    "--backend",
                    backend,
                ],
            )
        };
        let (cpu, gpu) = (on("cpu"), on("wgpu"));
        assert!(gpu.status.success(), "{}", stderr(&gpu));
        assert!(stderr(&gpu).contains("prime factor 17"), "{}", stderr(&gpu));
        assert!(
            stdout(&gpu).contains("lacked the frame's size"),
            "{}",
            stdout(&gpu)
        );
        assert_eq!(scores(&cpu), scores(&gpu));
    }
}
