//! `nedrt eval` and the plots: tables, focus cues, external displays, designs.

use super::*;

/// A folder `imgs` in `dir` with test images of the given names and sizes.
fn image_folder(dir: &Path, images: &[(&str, u32, u32)]) -> PathBuf {
    let imgs = dir.join("imgs");
    std::fs::create_dir(&imgs).expect("dir");
    for (name, w, h) in images {
        write_png(&imgs.join(name), *w, *h);
    }
    imgs
}

/// A finished `nedrt eval`: the process, its Markdown and its JSON.
struct Eval {
    o: Output,
    md: String,
    json: serde_json::Value,
}

impl Eval {
    fn methods(&self) -> Vec<serde_json::Value> {
        self.json["methods"].as_array().expect("methods").clone()
    }
}

/// `nedrt --calib <small> [global…] eval --images IMGS --out-dir OUT [args…]`,
/// which must succeed.
fn eval_run(imgs: &Path, out: &Path, global: &[&str], args: &[&str]) -> Eval {
    let calib = small_calib();
    let o = run(&[
        &["--calib", path(&calib)][..],
        global,
        &["eval", "--images", path(imgs), "--out-dir", path(out)],
        args,
    ]
    .concat());
    assert!(o.status.success(), "{}", stderr(&o));
    let md = std::fs::read_to_string(out.join("eval.md")).expect("md");
    let json = serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).expect("json"))
        .expect("parse");
    Eval { o, md, json }
}

#[test]
fn eval_writes_fig6_tables() {
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = image_folder(dir.path(), &[("a.png", 24, 16), ("b.png", 19, 21)]);
    let out = dir.path().join("eval");
    let Eval { o, md, json } = eval_run(&imgs, &out, &[], &["--methods", "conventional,doe-only"]);
    assert!(
        stderr(&o).contains("cropped from 19×21 to 16×16"),
        "{}",
        stderr(&o)
    );
    for needle in [
        "vs sharp",
        "vs target",
        "| 3.0 |",
        "| 0.0 |",
        "mean 0–2.5",
        "worst 0–2.5",
        "conventional",
        "doe-only",
    ] {
        assert!(md.contains(needle), "{needle:?} missing from\n{md}");
    }
    assert_eq!(
        json["methods"][0]["rows"].as_array().expect("rows").len(),
        7
    );
    assert!(
        json["methods"][1]["doe"].is_string(),
        "DOE rows name their DOE"
    );
    // Focus cues are opt-in: none measured, no chart.
    assert!(json["methods"][0].get("focus_cues").is_none());
    assert!(json.get("focus_cue_definition").is_none());
    assert!(!out.join("focus_cues.png").exists());
    assert!(!md.contains("Focus cues"));
    let o = run(&[
        "eval",
        "--images",
        dir.path().join("nothing").to_str().expect("utf8"),
    ]);
    assert_clean_error(&o, "cannot read folder");
}

#[test]
fn eval_runs_the_built_in_methods_and_the_shipped_dcnn_by_default() {
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = image_folder(dir.path(), &[("a.png", 32, 32)]);
    let out = dir.path().join("eval");
    // From the repository root, where the shipped model is.
    let o = nedrt()
        .current_dir(repo())
        .args([
            "--calib",
            path(&small_calib()),
            "eval",
            "--images",
            path(&imgs),
        ])
        .args(["--out-dir", path(&out)])
        .output_within(deadline::COMMAND, "nedrt eval");
    assert!(o.status.success(), "{}", stderr(&o));
    let md = std::fs::read_to_string(out.join("eval.md")).expect("md");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).expect("json"))
            .expect("parse");
    let names: Vec<String> = json["methods"]
        .as_array()
        .expect("methods")
        .iter()
        .map(|m| m["method"].as_str().expect("name").to_string())
        .collect();
    assert_eq!(
        names,
        ["conventional", "ai", "doe-only", "doe+wiener", "proposed"]
    );
    assert!(md.contains("D-CNN proposed: models/dcnn.onnx"), "{md}");
    // Elsewhere (no models/dcnn.onnx under the working folder) the
    // built-in methods still run, and the log says why proposed is not.
    let elsewhere = eval_run(&imgs, &dir.path().join("elsewhere"), &[], &[]);
    assert_eq!(elsewhere.methods().len(), 4);
    assert!(
        stderr(&elsewhere.o).contains("proposed is left out"),
        "{}",
        stderr(&elsewhere.o)
    );
}

#[test]
fn eval_measures_focus_cues_and_charts_them() {
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = image_folder(dir.path(), &[("a.png", 64, 64)]);
    let out = dir.path().join("eval");
    let Eval { o, md, json } = eval_run(
        &imgs,
        &out,
        &[],
        &["--methods", "conventional,ai,doe-only", "--focus-cues"],
    );
    for f in ["focus_cues.png", "focus_cues.svg"] {
        let p = out.join(f);
        assert!(
            p.metadata().map(|m| m.len() > 1000).unwrap_or(false),
            "{f} missing or empty"
        );
        assert!(stdout(&o).contains(f), "{f} not reported: {}", stdout(&o));
    }
    for needle in [
        "vs sharp",
        "## Focus cues",
        "| conventional | 1.5 |",
        "| ai | 0.5 |",
        "| doe-only | 2.5 |",
        "S_5 maxima, ai:",
        "focus_cues.png",
    ] {
        assert!(md.contains(needle), "{needle:?} missing from\n{md}");
    }
    let def = &json["focus_cue_definition"];
    assert_eq!(def["frequencies_cpd"], serde_json::json!([5.0, 10.0]));
    assert_eq!(def["sweep_step_d"], 0.1);
    assert_eq!(json["charts"].as_array().expect("charts").len(), 2);
    let methods = json["methods"].as_array().expect("methods");
    assert_eq!(methods.len(), 3);
    for m in methods {
        // The tables are unchanged by the sweep: seven depths.
        assert_eq!(m["rows"].as_array().expect("rows").len(), 7);
        let cues = &m["focus_cues"];
        let depths = cues["accommodation_d"].as_array().expect("depths");
        assert_eq!(depths.len(), 31, "0–3 D in 0.1 D steps");
        let curves = cues["curves"].as_array().expect("curves");
        assert_eq!(curves.len(), 2);
        for c in curves {
            let s = c["sharpness"].as_array().expect("sharpness");
            assert_eq!(s.len(), 31);
            assert!(
                s.iter()
                    .all(|v| v.as_f64().is_some_and(|v| v > 0.0 && v < 1.5)),
                "{}: {s:?}",
                m["method"]
            );
        }
        let main = cues["main_depths"].as_array().expect("main depths");
        assert_eq!(main.len(), 3);
        for (d, want) in main.iter().zip([0.5, 1.5, 2.5]) {
            assert_eq!(d["depth_d"], want);
            assert_eq!(d["scores"].as_array().expect("scores").len(), 2);
            assert!(d["scores"][0]["score"].is_f64(), "{d}");
            assert!(d["nearest_peak"]["offset_d"].is_f64(), "{d}");
        }
    }
    // Physics: the lens alone is sharpest near its own focus (G at 1.49 D,
    // R 1.70, B 1.12: the channel mean peaks between), and that is a cue.
    let conventional = &methods[0]["focus_cues"];
    let best = conventional["peaks"]
        .as_array()
        .expect("peaks")
        .iter()
        .max_by(|a, b| {
            let v = |p: &serde_json::Value| p["value"].as_f64().unwrap_or(f64::NAN);
            v(a).total_cmp(&v(b))
        })
        .expect("a peak");
    let at = best["accommodation_d"].as_f64().expect("d");
    assert!((at - 1.49).abs() < 0.25, "conventional S_5 peaks at {at} D");
    let fc_mid = conventional["main_depths"][1]["scores"][0]["score"]
        .as_f64()
        .expect("fc");
    assert!(fc_mid > 0.0, "FC_5(1.5 D) of the lens alone: {fc_mid}");
}

#[test]
fn plots_are_written() {
    let dir = tempfile::tempdir().expect("tmp");
    let calib = small_calib();
    let c = path(&calib);
    let d = path(dir.path());
    for cmd in [
        vec!["mtf", "--step", "0.5"],
        vec!["psf", "--step", "0.5"],
        vec!["doe"],
    ] {
        let o = run(&[&["--calib", c][..], &cmd, &["--out-dir", d]].concat());
        assert!(o.status.success(), "{cmd:?}: {}", stderr(&o));
    }
    for f in [
        "mtf.png",
        "mtf.svg",
        "mtf.csv",
        "psf_cross_sections.png",
        "psf_cross_sections.csv",
        "doe_height_map.png",
        "doe_cross_sections.csv",
    ] {
        let p = dir.path().join(f);
        assert!(
            p.metadata().map(|m| m.len() > 100).unwrap_or(false),
            "{f} missing or empty"
        );
    }
    let csv = std::fs::read_to_string(dir.path().join("mtf.csv")).expect("csv");
    // At 0 CPD every MTF is 1 less its veil.
    let zero: Vec<f64> = csv
        .lines()
        .filter(|l| l.starts_with("a,") && l.split(',').nth(4) == Some("0"))
        .map(|l| l.rsplit(',').next().expect("v").parse().expect("f"))
        .collect();
    assert_eq!(zero.len(), 4);
    assert!(zero.iter().all(|v| *v <= 1.0 && *v > 0.9), "{zero:?}");
}

#[test]
fn eval_scores_external_display_images() {
    // The inputs themselves as "display images" through lens + DOE must score
    // exactly as doe-only (which shows the input unprocessed).
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = image_folder(dir.path(), &[("a.png", 24, 16)]);
    let out = dir.path().join("eval");
    let external = |displays: &Path| {
        [
            "--methods",
            "doe-only",
            "--display-dir",
            path(displays),
            "--display-name",
            "same-as-input",
        ]
        .map(str::to_string)
    };
    let args = external(&imgs);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let methods = eval_run(&imgs, &out, &[], &args).methods();
    assert_eq!(methods[1]["method"], "same-as-input");
    assert_eq!(methods[0]["rows"], methods[1]["rows"]);
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).expect("dir");
    let calib = small_calib();
    let args = external(&empty);
    let o = run(&[
        &["--calib", path(&calib), "eval", "--images", path(&imgs)][..],
        &["--out-dir", path(&out)],
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
    ]
    .concat());
    assert_clean_error(&o, "a.png: cannot read image");
}

#[test]
fn eval_adds_a_row_per_design_equal_to_running_that_design() {
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = image_folder(dir.path(), &[("a.png", 48, 40)]);
    let doe = dir.path().join("d.safetensors");
    let small = small_calib();
    let o = run(&[
        "--calib",
        path(&small),
        "doe",
        "--out-dir",
        path(dir.path()),
        "--write-init",
        path(&doe),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let design = dir.path().join("d.toml");
    std::fs::write(
        &design,
        "name = \"d\"\ntarget = \"multifocal\"\ndoe = \"d.safetensors\"\nwiener_k = 0.05\n",
    )
    .expect("write");
    let eval = |global: &[&str], out: &str, args: &[&str]| {
        eval_run(&imgs, &dir.path().join(out), global, args)
    };
    let rows = eval(&[], "rows", &["--methods", "doe+wiener"]).methods();
    assert_eq!(rows.len(), 1);
    let with = eval(
        &[],
        "with",
        &["--methods", "doe+wiener", "--designs", path(&design)],
    );
    assert!(
        with.md.contains("| doe+wiener | doe+wiener d |"),
        "{}",
        with.md
    );
    assert!(
        with.md.contains("Design d:") && with.md.contains("Wiener K 0.05"),
        "{}",
        with.md
    );
    let with_design = with.methods();
    assert_eq!(with_design.len(), 2);
    assert_eq!(with_design[1]["method"], "doe+wiener d");
    // Every PSNR and SSIM of a row (the PSF cache stores f32, so a run that
    // loads them differs from one that computed them in the 9th digit).
    let scores = |row: &serde_json::Value| -> Vec<f64> {
        row["rows"]
            .as_array()
            .expect("rows")
            .iter()
            .flat_map(|r| {
                ["vs_sharp", "vs_target"]
                    .into_iter()
                    .flat_map(|k| [r[k]["psnr_db"].as_f64(), r[k]["ssim"].as_f64()])
            })
            .map(|v| v.expect("number"))
            .collect()
    };
    let close = |a: &serde_json::Value, b: &serde_json::Value| {
        let (a, b) = (scores(a), scores(b));
        a.len() == b.len() && a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-6)
    };
    // The calibration's own row is unchanged by the extra row.
    assert!(close(&with_design[0], &rows[0]));
    // The design's row is what `--design d.toml` gives for doe+wiener.
    let alone = eval(
        &["--design", path(&design)],
        "alone",
        &["--methods", "doe+wiener"],
    )
    .methods();
    assert!(close(&with_design[1], &alone[0]));
    assert_eq!(with_design[1]["doe"], alone[0]["doe"]);
    // K differs from the calibration's (0.01), so the rows differ.
    assert!(!close(&with_design[1], &with_design[0]));
    // A design that does not exist is refused, naming it.
    let o = run(&[
        "--calib",
        path(&small),
        "eval",
        "--images",
        path(&imgs),
        "--out-dir",
        path(&dir.path().join("bad")),
        "--designs",
        "no-such-design",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("no-such-design"), "{}", stderr(&o));
}

#[test]
fn eval_over_eyes_tabulates_each_eye_charts_the_pupil_and_resumes() {
    // The small calibration's aperture is 3 mm: a 2 mm pupil limits it, a
    // 4 mm one does not (the paper's eye exactly), 2mm@3 moves across it.
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = image_folder(dir.path(), &[("a.png", 24, 16)]);
    let out = dir.path().join("eyes");
    let calib = small_calib();
    let eyes = |extra: &[&str]| {
        run(&[
            &["--calib", path(&calib), "eval", "--images", path(&imgs)][..],
            &["--out-dir", path(&out), "--methods", "conventional,ai"],
            extra,
        ]
        .concat())
    };
    let o = eyes(&["--eyes", "paper,2mm,4mm,2mm@3,2mm+lca"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let md = std::fs::read_to_string(out.join("eyes.md")).expect("eyes.md");
    for needle in [
        "| paper (the 3 mm aperture) |",
        "| 2mm |",
        "| 2mm@3 |",
        "| 2mm+lca |",
        "eye LCA (Thibos 1992)",
        "does not limit",
    ] {
        assert!(md.contains(needle), "{needle:?} in\n{md}");
    }
    let rows: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("eyes.json")).expect("json"))
            .expect("parse");
    let mean = |eye: usize, method: usize| {
        rows[eye]["rows"][method]["mean_vs_sharp_db"]
            .as_f64()
            .expect("psnr")
    };
    // A pupil that does not limit is the paper's eye; one that does is not.
    assert_eq!(mean(0, 0), mean(2, 0));
    assert_ne!(mean(0, 0), mean(1, 0));
    assert!(out.join("eyes.png").exists() && out.join("2mm-at3/eval.json").exists());
    // Run again: every eye is read back, nothing recomputed.
    let again = eyes(&["--eyes", "paper,2mm,4mm,2mm@3,2mm+lca", "-v"]);
    assert!(again.status.success());
    assert_eq!(
        stderr(&again).matches("read back").count(),
        5,
        "{}",
        stderr(&again)
    );
    // Another study (other rows) in the same folder recomputes, not reads back.
    let other = run(&[
        &[
            "--calib",
            path(&calib),
            "-v",
            "eval",
            "--images",
            path(&imgs),
        ][..],
        &[
            "--out-dir",
            path(&out),
            "--methods",
            "conventional",
            "--eyes",
            "paper,2mm",
        ],
    ]
    .concat());
    assert!(other.status.success(), "{}", stderr(&other));
    assert!(!stderr(&other).contains("read back"), "{}", stderr(&other));
    // Bad eyes are refused: unparsable, or seeing no light (2 mm at 10°
    // lands 2.6 mm off axis, past the 1.5 mm aperture).
    let bad = eyes(&["--eyes", "2"]);
    assert_clean_error(&bad, "a pupil is written in mm");
    let dark = eyes(&["--eyes", "2mm@10"]);
    assert_clean_error(&dark, "no light reaches the eye");
}
