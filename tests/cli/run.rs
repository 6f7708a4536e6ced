//! `nedrt run`: bad sources and sinks, recording, fallbacks, pacing.

use super::*;

#[test]
fn run_refuses_bad_sources_sinks_and_models_with_one_error_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    let panel = small_panel();
    let run_with = |extra: &[&str]| {
        run_on_small_panel()
            .args(extra)
            .output_within(deadline::COMMAND, "nedrt run")
    };
    // An image of the wrong size is named before anything starts.
    let big = dir.path().join("big.png");
    image::RgbImage::new(65, 48).save(&big).expect("save");
    let o = run_with(&["--source", "dir", "--input", path(&big), "--sink", "record"]);
    assert_clean_error(&o, "big.png: 65×48 image is larger than the 64×48 panel");
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
    // A shared-memory folder that is not there is named at start.
    let o = run_with(&[
        "--source",
        "socket",
        "--socket",
        path(&dir.path().join("s.sock")),
        "--shm-dir",
        "/no/such/shm",
        "--sink",
        "record",
    ]);
    assert_clean_error(&o, "/no/such/shm: not a folder");
    assert!(!dir.path().join("s.sock").exists(), "nothing listened");
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
    let o = run_on_small_panel()
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .args(["--frames", "1", "--sink", "window"])
        .output_within(deadline::COMMAND, "nedrt run");
    assert_clean_error(&o, "window sink");
    // A calibration whose panel makes no sense.
    let bad = dir.path().join("bad-panel.toml");
    let text = std::fs::read_to_string(&panel)
        .expect("read")
        .replace("refresh_hz = 240.0", "refresh_hz = 0.0");
    std::fs::write(&bad, text).expect("write");
    let o = nedrt()
        .args(["run", "--calib", path(&bad), "--sink", "record"])
        .output_within(deadline::COMMAND, "nedrt run");
    assert_clean_error(&o, "panel.refresh_hz");
}

#[test]
fn run_records_a_folder_and_writes_a_trace_and_report() {
    let dir = tempfile::tempdir().expect("tempdir");
    let img = dir.path().join("in.png");
    image::RgbImage::from_fn(64, 48, |x, y| {
        image::Rgb([(x * 4) as u8, (y * 5) as u8, 128])
    })
    .save(&img)
    .expect("save");
    let rec = dir.path().join("rec");
    let trace = dir.path().join("trace.json");
    let report = dir.path().join("report.json");
    let o = run_on_small_panel()
        .args(["--source", "dir", "--input", path(&img)])
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
        .output_within(deadline::COMMAND, "nedrt run");
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
    for stage in ["upload", "preprocess", "encode", "present"] {
        assert!(
            names.iter().any(|n| n == stage),
            "no {stage} span in the trace: {names:?}"
        );
    }
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("JSON");
    assert_eq!(r["presented"].as_u64(), Some(3));
}

/// `--preprocess auto` on the host path (a recorder): every frame runs a
/// level of the ladder, and the report says which, with the quality
/// delivered.
#[test]
fn run_with_the_frame_budget_reports_its_levels() {
    let dir = tempfile::tempdir().expect("tempdir");
    let report = dir.path().join("report.json");
    let mut c = nedrt();
    c.current_dir(repo())
        .args(["run", "--calib", path(&small_panel()), "--backend", "cpu"]);
    let o = c
        .args(["--preprocess", "auto:none..wiener", "--frames", "12"])
        .args(["--source-rate", "60", "--sink", "record", "--record-dir"])
        .arg(dir.path().join("rec"))
        .args(["--report-json", path(&report)])
        .output_within(deadline::COMMAND, "nedrt run --preprocess auto");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("frame budget: "), "{}", stdout(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("JSON");
    let budget = &r["frame_budget"];
    let names: Vec<&str> = budget["levels"]
        .as_array()
        .expect("levels")
        .iter()
        .filter_map(|l| l["name"].as_str())
        .collect();
    assert_eq!(names, ["none", "wiener"], "{budget}");
    let frames: u64 = budget["levels"]
        .as_array()
        .expect("levels")
        .iter()
        .filter_map(|l| l["frames"].as_u64())
        .sum();
    assert_eq!(frames, 12, "every frame ran a level: {budget}");
    assert!(
        budget["budget_ms"]
            .as_f64()
            .is_some_and(|b| b > 0.0 && b < 4.2)
    );
    assert!(
        budget["quality_delivered_db"].as_f64().is_some(),
        "{budget}"
    );
}

#[test]
fn run_falls_back_to_the_cpu_when_the_chosen_backend_cannot_start() {
    let dir = tempfile::tempdir().expect("tempdir");
    let panel = small_panel();
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
                "--preprocess",
                "proposed",
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
            .output_within(deadline::COMMAND, "nedrt run")
    };
    let o = run_without_ort(&[], "rec");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("running the D-CNN on the fallback"),
        "{}",
        stderr(&o)
    );
    // The shipped network runs behind its Wiener stage.
    assert!(
        stdout(&o).contains("preprocess: Wiener prefilter of proposed")
            && stdout(&o).contains("then D-CNN models/dcnn.onnx"),
        "{}",
        stdout(&o)
    );
    assert!(stdout(&o).contains("on cpu (tract"), "{}", stdout(&o));
    // Asked not to fall back to a network at all, it shows the frames
    // without one: the shipped network's Wiener stage alone.
    let o = run_without_ort(&["--fallback", "passthrough"], "rec2");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("preprocess: Wiener prefilter of proposed")
            && stdout(&o).contains("then none (the frame as it comes"),
        "{}",
        stdout(&o)
    );
}

#[test]
fn run_refuses_a_source_rate_it_cannot_pace() {
    let dir = tempfile::tempdir().expect("tempdir");
    let panel = small_panel();
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

/// `nedrt run` of the test pattern into `<dir>/rec` with its report in
/// `<dir>/report.json`, once its first frame is on disk (killed if the
/// test fails before it ends: not left running to slow every later test).
fn recording_pattern() -> (deadline::Watched, tempfile::TempDir) {
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = dir.path().join("rec");
    // The shipped network without its card: no Wiener stage to prepare
    // before the first frame (its PSFs can take most of the 60 s below on
    // a loaded machine with a cold cache), as these tests are about the stop.
    let network = dir.path().join("network.onnx");
    std::fs::copy(repo().join("models/dcnn.onnx"), &network).expect("copy the model");
    let child = run_on_small_panel()
        .arg("--dcnn")
        .arg(&network)
        .args(["--source", "pattern", "--sink", "record", "--record-dir"])
        .args([path(&rec), "--report-json"])
        .arg(dir.path().join("report.json"))
        .spawn_watched("nedrt run (recording the pattern)");
    // Any frame: under load the present stage may show a later frame in
    // frame 0's place (the newest ready frame wins its refresh).
    deadline::wait_until_within(
        std::time::Duration::from_secs(60),
        "a frame to be recorded",
        || {
            std::fs::read_dir(&rec).is_ok_and(|d| {
                d.flatten()
                    .any(|e| e.path().extension().is_some_and(|x| x == "png"))
            })
        },
    );
    (child, dir)
}

/// `timeout` signals the child and then its process group: two SIGTERMs
/// within microseconds are one request to stop, and the report is written.
#[test]
fn two_stop_signals_at_once_still_write_the_report() {
    let (child, dir) = recording_pattern();
    let report = dir.path().join("report.json");
    let pid = child.id().to_string();
    for _ in 0..2 {
        let killed = Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .expect("kill");
        assert!(killed.success());
    }
    let out = child.wait_within(
        std::time::Duration::from_secs(60),
        "nedrt run to stop after two SIGTERMs",
    );
    assert!(out.status.success(), "{}", stderr(&out));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report written"))
            .expect("json");
    assert!(json["presented"].as_u64().is_some_and(|n| n > 0), "{json}");
    assert!(stdout(&out).contains("presented"), "{}", stdout(&out));
}

/// A recorder that fails mid-run (its folder gone) ends the run with an
/// error naming the file, and the report and its JSON are still written:
/// the counts matter most when the sink failed.
#[test]
fn a_failing_recorder_still_leaves_the_report() {
    let (child, dir) = recording_pattern();
    let (rec, report) = (dir.path().join("rec"), dir.path().join("report.json"));
    // Moved away in one step (removing it would race the writer's next
    // file): every later write into `rec` fails.
    std::fs::rename(&rec, dir.path().join("gone")).expect("move the recording folder away");
    let out = child.wait_within(
        deadline::COMMAND,
        "nedrt run to fail once its recording folder is gone",
    );
    assert!(!out.status.success(), "the run must fail");
    assert!(stderr(&out).contains("cannot write"), "{}", stderr(&out));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report written"))
            .expect("json");
    assert!(json["presented"].as_u64().is_some_and(|n| n > 0), "{json}");
    assert!(
        stderr(&out).contains("presented"),
        "the table: {}",
        stderr(&out)
    );
}

/// `nedrt run` on the small panel with the default (wgpu) backend, where
/// the Vulkan loader finds no driver.
fn on_small_panel_without_vulkan() -> std::process::Command {
    let mut c = nedrt();
    c.current_dir(repo())
        .env("VK_ICD_FILENAMES", "/nonexistent")
        .args(["run", "--calib", path(&small_panel())])
        .args(["--preprocess", "proposed"]);
    c
}

#[test]
fn without_a_vulkan_driver_run_records_with_the_dcnn_on_the_cpu_and_gpu_sinks_say_so() {
    // No Vulkan driver at all (the loader finds no ICD): the recorder needs
    // no GPU, so the D-CNN runs on the CPU engine, with a warning saying why.
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = dir.path().join("rec");
    let o = on_small_panel_without_vulkan()
        .args(["--source", "pattern", "--frames", "3", "--source-rate", "4"])
        .args(["--sink", "record", "--record-dir", path(&rec)])
        .output_within(deadline::COMMAND, "nedrt run");
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("no GPU adapter") && err.contains("running the D-CNN on the fallback"),
        "{err}"
    );
    assert!(stdout(&o).contains("on cpu"), "{}", stdout(&o));
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
    // A sink that needs a GPU says which one does not.
    let o = on_small_panel_without_vulkan()
        .args(["--source", "pattern", "--frames", "1", "--sink", "headless"])
        .output_within(deadline::COMMAND, "nedrt run");
    assert_clean_error(&o, "`nedrt run --sink record` needs no GPU");
}
