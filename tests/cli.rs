//! End-to-end tests of the `nedrt` binary: the README's main command, every
//! kind of bad input named in the issue (a clear one-line error, non-zero
//! exit, nothing half-written), the PSF cache, eval and the plots.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn nedrt() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_nedrt"));
    // One shared cache for the whole test run, inside the build folder.
    c.env(
        "NEDRT_CACHE_DIR",
        Path::new(env!("CARGO_TARGET_TMPDIR")).join("psf-cache"),
    );
    c.env_remove("NEDRT_LOG");
    c
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn small_calib() -> PathBuf {
    repo().join("tests/data/small-aperture.toml")
}

fn run(args: &[&str]) -> Output {
    nedrt().args(args).output().expect("run nedrt")
}

/// `nedrt --sim --accom D --out OUT` with extra arguments.
fn sim(accom: &str, out: &Path, extra: &[&str]) -> Output {
    run(&[&["--sim", "--accom", accom, "--out", path(out)][..], extra].concat())
}

fn path(p: &Path) -> &str {
    p.to_str().expect("utf8 path")
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A failure: non-zero exit and exactly one `error:` line naming `needle`.
fn assert_clean_error(o: &Output, needle: &str) {
    let err = stderr(o);
    assert!(
        !o.status.success(),
        "expected failure, got success; stderr: {err}"
    );
    assert!(!err.contains("panicked"), "panic: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "one error line expected: {err}");
    assert!(
        lines[0].contains(needle),
        "error should mention {needle:?}: {}",
        lines[0]
    );
}

fn write_png(path: &Path, w: u32, h: u32) {
    let img = image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([
            (x * 7 % 256) as u8,
            (y * 5 % 256) as u8,
            ((x + y) % 256) as u8,
        ])
    });
    img.save(path).expect("write png");
}

#[test]
fn readme_main_command_runs_on_shipped_defaults() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("perceived.png");
    let o = sim("1.0", &out, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = stdout(&o);
    for needle in [
        "vs sharp",
        "vs target",
        "pupil step",
        "window",
        "veil",
        "integrated",
        "time",
    ] {
        assert!(s.contains(needle), "missing {needle:?} in:\n{s}");
    }
    let img = image::open(&out).expect("perceived image");
    assert_eq!(
        (img.width(), img.height()),
        (1024, 1024),
        "retinal grid is 2× the display"
    );
    // Second run: PSFs come from the cache.
    let o = sim("1.0", &out, &[]);
    assert!(stdout(&o).contains("from cache"), "{}", stdout(&o));
}

#[test]
fn bad_images_are_clear_errors() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("p.png");
    let o = sim("1", &out, &["--input", "/no/such.png"]);
    assert_clean_error(&o, "/no/such.png: cannot read image");
    let junk = dir.path().join("junk.png");
    std::fs::write(&junk, b"this is not an image").expect("write");
    let o = sim("1", &out, &["--input", path(&junk)]);
    assert_clean_error(&o, "cannot decode image");
    let nan = dir.path().join("nan.tif");
    let mut im = image::Rgb32FImage::from_pixel(16, 16, image::Rgb([0.5, 0.5, 0.5]));
    im.put_pixel(3, 4, image::Rgb([f32::NAN, 0.5, 0.5]));
    image::DynamicImage::ImageRgb32F(im)
        .save(&nan)
        .expect("tiff");
    let o = sim("1", &out, &["--input", path(&nan)]);
    assert_clean_error(&o, "pixel 3,4 channel 0 is NaN");
    assert!(!out.exists(), "nothing written on failure");
}

#[test]
fn odd_gray_and_16_bit_images_are_converted_and_said_so() {
    let dir = tempfile::tempdir().expect("tmp");
    let odd = dir.path().join("odd.png");
    write_png(&odd, 37, 29);
    let out = dir.path().join("p.png");
    let o = sim("0.5", &out, &["--input", path(&odd)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("not a multiple of 8; padded to 40×32"),
        "{}",
        stderr(&o)
    );
    let img = image::open(&out).expect("out");
    assert_eq!(
        (img.width(), img.height()),
        (74, 58),
        "cropped back to 2× the input"
    );

    let g16 = dir.path().join("g16.png");
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(24, 16, |x, _| {
        image::Luma([x as u16 * 2000])
    })
    .save(&g16)
    .expect("png16");
    let o = sim("0.5", &out, &["--input", path(&g16)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("grayscale image converted to RGB") && e.contains("16-bit image converted"),
        "{e}"
    );
}

#[test]
fn accommodation_is_checked() {
    let dir = tempfile::tempdir().expect("tmp");
    let input = dir.path().join("in.png");
    write_png(&input, 16, 16);
    let out = dir.path().join("p.png");
    let base = ["--sim", "--input", path(&input), "--out", path(&out)];
    let o = run(&[&base[..], &["--accom", "-0.5"]].concat());
    assert_clean_error(&o, "accommodation must be ≥ 0 D");
    for huge in ["1e308", "20.5"] {
        let o = run(&[&base[..], &["--accom", huge]].concat());
        assert_clean_error(&o, "beyond what an eye accommodates (at most 20 D");
    }
    let o = run(&[&base[..], &["--accom", "4"]].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("outside the calibrated range"),
        "{}",
        stderr(&o)
    );
    let o = run(&base);
    assert_clean_error(&o, "--sim needs --accom");
    let o = run(&[&base[..], &["--accom", "1", "--method", "proposed"]].concat());
    assert!(
        !o.status.success() && stderr(&o).contains("D-CNN"),
        "{}",
        stderr(&o)
    );
}

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
fn malformed_calibration_and_doe_files_are_clear_errors() {
    let dir = tempfile::tempdir().expect("tmp");
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[panel\npixel_pitch_um = 8.7").expect("write");
    let o = run(&["--calib", path(&bad), "--sim", "--accom", "1"]);
    assert_clean_error(&o, "bad.toml: malformed TOML");
    let phys = dir.path().join("phys.toml");
    let text = std::fs::read_to_string(repo().join("calib/default.toml")).expect("calib");
    std::fs::write(
        &phys,
        text.replace("lens_distance_mm = 28.57", "lens_distance_mm = 31"),
    )
    .expect("write");
    let o = run(&["--calib", path(&phys), "--sim", "--accom", "1"]);
    assert_clean_error(&o, "no virtual image");

    let doe = dir.path().join("doe.safetensors");
    std::fs::write(&doe, b"\x08\x00\x00\x00\x00\x00\x00\x00{}      ").expect("write");
    let o = run(&[
        "--doe",
        path(&doe),
        "--sim",
        "--accom",
        "1",
        "--method",
        "doe-only",
    ]);
    assert_clean_error(&o, "invalid DOE file");
    // A valid file whose grid is too coarse for the aperture it is used with.
    let init = dir.path().join("init.safetensors");
    let o = run(&[
        "--calib",
        small_calib().to_str().expect("utf8"),
        "doe",
        "--write-init",
        path(&init),
        "--out-dir",
        path(dir.path()),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = run(&[
        "--doe",
        path(&init),
        "--sim",
        "--accom",
        "1",
        "--method",
        "doe-only",
    ]);
    assert_clean_error(&o, "does not cover");
}

#[test]
fn display_image_must_match_and_outputs_must_be_writable() {
    let dir = tempfile::tempdir().expect("tmp");
    let input = dir.path().join("in.png");
    let disp = dir.path().join("d.png");
    write_png(&input, 16, 16);
    write_png(&disp, 24, 16);
    let o = run(&[
        "--sim",
        "--accom",
        "1",
        "--input",
        path(&input),
        "--display-image",
        path(&disp),
    ]);
    assert_clean_error(&o, "must match");
    let o = run(&[
        "--sim",
        "--accom",
        "1",
        "--input",
        path(&input),
        "--out",
        "/no/such/dir/p.png",
    ]);
    assert_clean_error(&o, "cannot write image");
    let o = run(&[
        "--sim",
        "--accom",
        "1",
        "--input",
        path(&input),
        "--out",
        dir.path().join("p.jpg").to_str().expect("utf8"),
    ]);
    assert_clean_error(&o, "unsupported extension");
}

#[test]
fn display_image_is_simulated_through_the_chosen_optics() {
    let dir = tempfile::tempdir().expect("tmp");
    let input = dir.path().join("in.png");
    write_png(&input, 16, 16);
    let out = dir.path().join("p.png");
    let calib = small_calib();
    let o = run(&[
        "--calib",
        path(&calib),
        "--sim",
        "--accom",
        "1.5",
        "--input",
        path(&input),
        "--display-image",
        path(&input),
        "--out",
        path(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("through lens + DOE"), "{}", stdout(&o));
}

#[test]
fn eval_writes_fig6_tables() {
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = dir.path().join("imgs");
    std::fs::create_dir(&imgs).expect("dir");
    write_png(&imgs.join("a.png"), 24, 16);
    write_png(&imgs.join("b.png"), 19, 21);
    let out = dir.path().join("eval");
    let o = run(&[
        "--calib",
        small_calib().to_str().expect("utf8"),
        "eval",
        "--images",
        path(&imgs),
        "--out-dir",
        path(&out),
        "--methods",
        "conventional,doe-only",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("cropped from 19×21 to 16×16"),
        "{}",
        stderr(&o)
    );
    let md = std::fs::read_to_string(out.join("eval.md")).expect("md");
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
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).expect("json"))
            .expect("parse");
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
fn eval_measures_focus_cues_and_charts_them() {
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = dir.path().join("imgs");
    std::fs::create_dir(&imgs).expect("dir");
    write_png(&imgs.join("a.png"), 64, 64);
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
        "conventional,ai,doe-only",
        "--focus-cues",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ["focus_cues.png", "focus_cues.svg"] {
        let p = out.join(f);
        assert!(
            p.metadata().map(|m| m.len() > 1000).unwrap_or(false),
            "{f} missing or empty"
        );
        assert!(stdout(&o).contains(f), "{f} not reported: {}", stdout(&o));
    }
    let md = std::fs::read_to_string(out.join("eval.md")).expect("md");
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
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).expect("json"))
            .expect("parse");
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
    let imgs = dir.path().join("imgs");
    std::fs::create_dir(&imgs).expect("dir");
    write_png(&imgs.join("a.png"), 24, 16);
    let out = dir.path().join("eval");
    let c = small_calib();
    let args = [
        "--calib",
        path(&c),
        "eval",
        "--images",
        path(&imgs),
        "--out-dir",
        path(&out),
        "--methods",
        "doe-only",
        "--display-dir",
        path(&imgs),
        "--display-name",
        "same-as-input",
    ];
    let o = run(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).expect("json"))
            .expect("parse");
    let methods = json["methods"].as_array().expect("methods");
    assert_eq!(methods[1]["method"], "same-as-input");
    assert_eq!(methods[0]["rows"], methods[1]["rows"]);
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).expect("dir");
    let mut missing = args.to_vec();
    missing[10] = path(&empty);
    let o = run(&missing);
    assert_clean_error(&o, "a.png: cannot read image");
}

fn dcnn_model() -> PathBuf {
    repo().join("models/dcnn.onnx")
}

/// The "vs sharp" line of a sim report.
fn vs_sharp(o: &Output) -> String {
    stdout(o)
        .lines()
        .find(|l| l.starts_with("vs sharp"))
        .unwrap_or_default()
        .to_string()
}

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
        stdout(&cpu).contains("nedrt_train run cpu"),
        "the companion DOE is used"
    );
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
    let o = sim(
        "1.0",
        &out,
        &[
            "--calib",
            path(&calib),
            "--method",
            "proposed",
            "--dcnn",
            path(&corrupt),
        ],
    );
    assert_clean_error(&o, "corrupt.onnx");
    let missing = dir.path().join("none.onnx");
    let o = sim(
        "1.0",
        &out,
        &[
            "--calib",
            path(&calib),
            "--method",
            "lens+dcnn",
            "--dcnn-lens",
            path(&missing),
        ],
    );
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
            .output()
            .expect("run")
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

#[test]
fn run_refuses_bad_sources_sinks_and_models_with_one_error_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    let panel = repo().join("tests/data/small-panel.toml");
    let run_with = |extra: &[&str]| {
        let mut c = nedrt();
        c.current_dir(repo())
            .args(["run", "--calib", path(&panel), "--backend", "cpu"])
            .args(extra);
        c.output().expect("run")
    };
    // An image of the wrong size is named before anything starts.
    let big = dir.path().join("big.png");
    image::RgbImage::new(65, 48).save(&big).expect("save");
    let o = run_with(&["--source", "dir", "--input", path(&big), "--sink", "record"]);
    assert_clean_error(&o, "big.png: 65×48 image for a 64×48 panel");
    let o = run_with(&["--source", "dir", "--sink", "record"]);
    assert_clean_error(&o, "--source dir needs --input");
    // A socket path held by a regular file is not clobbered.
    let file = dir.path().join("not-a-socket");
    std::fs::write(&file, b"keep me").expect("write");
    let o = run_with(&[
        "--source",
        "socket",
        "--socket",
        path(&file),
        "--sink",
        "record",
    ]);
    assert_clean_error(&o, "exists and is not a socket");
    assert_eq!(std::fs::read(&file).expect("still there"), b"keep me");
    // A missing or corrupt model.
    let o = run_with(&[
        "--frames",
        "1",
        "--sink",
        "record",
        "--dcnn",
        path(&dir.path().join("none.onnx")),
    ]);
    assert_clean_error(&o, "none.onnx");
    // No display for a window.
    let o = nedrt()
        .current_dir(repo())
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .args([
            "run",
            "--calib",
            path(&panel),
            "--backend",
            "cpu",
            "--frames",
            "1",
            "--sink",
            "window",
        ])
        .output()
        .expect("run");
    assert_clean_error(&o, "window sink");
    // A calibration whose panel makes no sense.
    let bad = dir.path().join("bad-panel.toml");
    let text = std::fs::read_to_string(&panel)
        .expect("read")
        .replace("refresh_hz = 240.0", "refresh_hz = 0.0");
    std::fs::write(&bad, text).expect("write");
    let o = nedrt()
        .args(["run", "--calib", path(&bad), "--sink", "record"])
        .output()
        .expect("run");
    assert_clean_error(&o, "panel.refresh_hz");
}

#[test]
fn run_records_a_folder_and_writes_a_trace_and_report() {
    let dir = tempfile::tempdir().expect("tempdir");
    let panel = repo().join("tests/data/small-panel.toml");
    let img = dir.path().join("in.png");
    image::RgbImage::from_fn(64, 48, |x, y| {
        image::Rgb([(x * 4) as u8, (y * 5) as u8, 128])
    })
    .save(&img)
    .expect("save");
    let rec = dir.path().join("rec");
    let trace = dir.path().join("trace.json");
    let report = dir.path().join("report.json");
    let o = nedrt()
        .current_dir(repo())
        .args([
            "run",
            "--calib",
            path(&panel),
            "--backend",
            "cpu",
            "--source",
            "dir",
            "--input",
            path(&img),
        ])
        .args([
            "--frames",
            "3",
            // Slow enough that a loaded machine (a D-CNN frame took 128 ms
            // here while other jobs ran) drops none as stale.
            "--source-rate",
            "4",
            "--sink",
            "record",
            "--record-dir",
            path(&rec),
        ])
        .args(["--trace", path(&trace), "--report-json", path(&report)])
        .output()
        .expect("run");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("3 submitted, 3 presented"),
        "{}",
        stdout(&o)
    );
    for id in 0..3 {
        assert!(
            rec.join(format!("frame-{id:08}.png")).exists(),
            "frame {id}"
        );
    }
    let trace: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&trace).expect("trace")).expect("trace JSON");
    let names: Vec<String> = trace
        .as_array()
        .expect("events")
        .iter()
        .filter_map(|e| e["args"]["stage"].as_str().map(str::to_string))
        .collect();
    for stage in ["upload", "dcnn", "encode", "present"] {
        assert!(
            names.iter().any(|n| n == stage),
            "no {stage} span in the trace: {names:?}"
        );
    }
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("JSON");
    assert_eq!(r["presented"].as_u64(), Some(3));
}

#[test]
fn run_falls_back_to_the_cpu_when_the_chosen_backend_cannot_start() {
    let dir = tempfile::tempdir().expect("tempdir");
    let panel = repo().join("tests/data/small-panel.toml");
    // `--backend ort` with no ONNX Runtime to load, recording into `rec`.
    let run_without_ort = |extra: &[&str], rec: &str| {
        nedrt()
            .current_dir(repo())
            .env(
                "ORT_DYLIB_PATH",
                dir.path().join("no-such-libonnxruntime.so"),
            )
            .args([
                "run",
                "--calib",
                path(&panel),
                "--backend",
                "ort",
                "--frames",
                "2",
            ])
            .args([
                "--sink",
                "record",
                "--record-dir",
                path(&dir.path().join(rec)),
            ])
            .args(extra)
            .output()
            .expect("run")
    };
    let o = run_without_ort(&[], "rec");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("running the D-CNN on the fallback"),
        "{}",
        stderr(&o)
    );
    assert!(stdout(&o).contains("D-CNN: cpu (tract"), "{}", stdout(&o));
    // Asked not to fall back to a network at all, it shows the frames unprocessed.
    let o = run_without_ort(&["--fallback", "passthrough"], "rec2");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("pass-through"), "{}", stdout(&o));
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
    let base = ["--calib", path(&calib)];
    let o = run(&[
        &base[..],
        &[
            "tradeoff",
            "--images",
            path(&imgs),
            "--out-dir",
            path(&out),
            "--size",
            "32x24",
            "--backends",
            "cpu",
            "--repeat",
            "1",
            "--no-fidelity",
            "--models",
            path(&model),
        ],
    ]
    .concat());
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
    ] {
        assert!(names.contains(&want), "{want} missing: {names:?}");
    }
    assert!(records.iter().any(|r| r["on_front"] == true));
    let md = std::fs::read_to_string(out.join("tradeoff.md")).expect("md");
    assert!(
        md.contains("32×24") && md.contains("0bbffee9f270c792"),
        "{md}"
    );
    // The fastest configuration meets an easy floor.
    let fastest = records
        .iter()
        .min_by(|a, b| {
            let ms = |r: &serde_json::Value| r["latency_ms"].as_f64().unwrap_or(f64::MAX);
            ms(a).total_cmp(&ms(b))
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
}

#[test]
fn designs_are_selected_by_name_and_bad_selections_are_refused() {
    let in_repo = |args: &[&str]| {
        nedrt()
            .current_dir(repo())
            .args(args)
            .output()
            .expect("run nedrt")
    };
    for name in ["allsharp", "multifocal"] {
        let o = in_repo(&["--design", name, "calib"]);
        assert!(o.status.success(), "{name}: {}", stderr(&o));
    }
    let o = in_repo(&["--design", "no-such-design", "calib"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("designs/no-such-design.toml") && stderr(&o).contains("allsharp"),
        "{}",
        stderr(&o)
    );
    let o = in_repo(&["--design", "allsharp", "--doe", "x.safetensors", "calib"]);
    assert!(!o.status.success(), "--design and --doe together");
}

#[test]
fn eval_adds_a_row_per_design_equal_to_running_that_design() {
    let dir = tempfile::tempdir().expect("tmp");
    let imgs = dir.path().join("imgs");
    std::fs::create_dir(&imgs).expect("dir");
    write_png(&imgs.join("a.png"), 48, 40);
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
    let eval = |extra: &[&str], out: &str| {
        let out = dir.path().join(out);
        let o = run(&[
            &["--calib", path(&small)][..],
            extra,
            &[
                "eval",
                "--images",
                path(&imgs),
                "--out-dir",
                path(&out),
                "--methods",
                "doe+wiener",
            ],
        ]
        .concat());
        assert!(o.status.success(), "{}", stderr(&o));
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).expect("json"))
                .expect("parse");
        json["methods"].as_array().expect("methods").clone()
    };
    let rows = eval(&[], "rows");
    assert_eq!(rows.len(), 1);
    let with_design = {
        let out = dir.path().join("with");
        let o = run(&[
            "--calib",
            path(&small),
            "eval",
            "--images",
            path(&imgs),
            "--out-dir",
            path(&out),
            "--methods",
            "doe+wiener",
            "--designs",
            path(&design),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let md = std::fs::read_to_string(out.join("eval.md")).expect("md");
        assert!(md.contains("| doe+wiener | doe+wiener d |"), "{md}");
        assert!(
            md.contains("Design d:") && md.contains("Wiener K 0.05"),
            "{md}"
        );
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).expect("json"))
                .expect("parse");
        json["methods"].as_array().expect("methods").clone()
    };
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
    let alone = eval(&["--design", path(&design)], "alone");
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
fn sim_refuses_images_smaller_than_8_pixels_a_side_like_eval() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (w, h) in [(1, 1), (300, 1), (7, 64)] {
        let img = dir.path().join(format!("{w}x{h}.png"));
        write_png(&img, w, h);
        let out = dir.path().join(format!("{w}x{h}-out.png"));
        let o = sim("1.0", &out, &["--input", path(&img)]);
        assert_clean_error(&o, "smaller than 8×8");
        assert!(
            stderr(&o).contains(&format!("{w}x{h}.png")),
            "{}",
            stderr(&o)
        );
        assert!(!out.exists(), "nothing written for {w}×{h}");
    }
    let img = dir.path().join("8x8.png");
    write_png(&img, 8, 8);
    let o = sim(
        "1.0",
        &dir.path().join("8x8-out.png"),
        &["--input", path(&img)],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stdout(&o).contains("NaN"), "{}", stdout(&o));
}

#[test]
fn run_refuses_a_source_rate_it_cannot_pace() {
    let dir = tempfile::tempdir().expect("tempdir");
    let panel = repo().join("tests/data/small-panel.toml");
    let rec = dir.path().join("rec");
    for rate in ["nan", "inf", "1e-300", "0.001", "1e6"] {
        let o = run(&[
            "run",
            "--calib",
            path(&panel),
            "--backend",
            "cpu",
            "--sink",
            "record",
            "--record-dir",
            path(&rec),
            "--frames",
            "1",
            "--source-rate",
            rate,
        ]);
        assert_clean_error(&o, "--source-rate");
        assert!(stderr(&o).contains("0 (unpaced)"), "{rate}: {}", stderr(&o));
        assert!(!rec.exists(), "{rate}: the record folder was created");
    }
}

#[test]
fn oversized_calibrations_and_endless_doe_files_are_refused_with_a_short_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let shipped = std::fs::read_to_string(repo().join("calib/default.toml")).expect("read");
    // An unknown key with a 200 kB value: the error quotes it, bounded.
    let big = dir.path().join("big-key.toml");
    std::fs::write(
        &big,
        format!("{shipped}\n[extra]\nnote = \"{}\"\n", "x".repeat(200_000)),
    )
    .expect("write");
    let o = run(&["--calib", path(&big), "calib"]);
    assert_clean_error(&o, "big-key.toml");
    assert!(
        stderr(&o).len() < 2000,
        "{} bytes of error",
        stderr(&o).len()
    );
    // Past the 1 MiB cap the file is not parsed at all.
    let huge = dir.path().join("huge.toml");
    std::fs::write(&huge, format!("{shipped}\n# {}\n", "y".repeat(2 << 20))).expect("write");
    let o = run(&["--calib", path(&huge), "calib"]);
    assert_clean_error(&o, "larger than 1 MiB");
    // /dev/zero as the DOE: refused at the cap, not read forever.
    let out = dir.path().join("p.png");
    let o = sim("1.0", &out, &["--doe", "/dev/zero", "--method", "doe-only"]);
    assert_clean_error(&o, "larger than 512 MiB");
    assert!(!out.exists());
}
