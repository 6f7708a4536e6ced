//! The service on a GPU and in a real window (ignored where the machine lacks them).

use super::*;

/// For a test that needs a GPU adapter (it is `#[ignore]`d, so it runs only
/// when asked for): none is a failure, with the reason.
fn require_gpu() {
    if let Err(e) = nedrt_infer::gpu::open_device(&Default::default(), nedrt_infer::Precision::F32)
    {
        panic!("this test needs a GPU adapter and found none: {e}");
    }
}

mod needs_gpu {
    use super::*;

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn a_soak_of_thousands_of_frames_keeps_memory_flat_and_counts_every_frame() {
        require_gpu();
        // The host path (the network on the CPU), and the device path
        // (no network: unpack, encode and the texture copy on the GPU).
        soak(&["--backend", "cpu", "--preprocess", "proposed"], "host");
        soak(&["--preprocess", "conventional"], "device");
    }

    fn soak(args: &[&str], path: &str) {
        let dir = tempfile::tempdir().expect("tempdir");
        let report_path = dir.path().join("report.json");
        let frames = 3000u64;
        let out = nedrt()
            .current_dir(repo())
            .args(["run", "--calib"])
            .arg(small_panel())
            .args(args)
            .args([
                "--source",
                "pattern",
                "--frames",
                &frames.to_string(),
                "--sink",
                "headless",
                "--report-json",
            ])
            .arg(&report_path)
            .output_within(deadline::COMMAND, "nedrt run (a soak of 3000 frames)");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let r = report(dir.path());
        assert!(
            r["frame_path"]
                .as_str()
                .is_some_and(|p| p.starts_with(path)),
            "{}",
            r["frame_path"]
        );
        let n = |k: &str| r[k].as_u64().unwrap_or_else(|| panic!("{k}"));
        let rejected: u64 = r["rejected"]
            .as_array()
            .expect("rejected")
            .iter()
            .filter_map(|p| p[1].as_u64())
            .sum();
        assert_eq!(n("submitted"), frames);
        assert_eq!(rejected, 0);
        assert_eq!(
            n("presented") + n("dropped_queued") + n("dropped_at_present") + n("skipped"),
            frames,
            "every frame presented or counted: {r}"
        );
        // How many reach the panel depends on the machine's speed (the
        // host path drops what it cannot preprocess in time), which a test
        // does not assert: the benchmarks measure it.
        assert!(n("presented") > 0, "frames reach the panel: {r}");
        let rss: Vec<u64> = r["rss_kib"]
            .as_array()
            .expect("rss")
            .iter()
            .filter_map(|v| v.as_u64())
            .collect();
        assert!(rss.len() >= 10, "{rss:?}");
        // After warm-up (the first fifth of the samples), resident memory stays within 8 MiB.
        let warm = &rss[rss.len() / 5..];
        let (lo, hi) = (
            warm.iter().min().copied().unwrap_or(0),
            warm.iter().max().copied().unwrap_or(0),
        );
        assert!(
            hi - lo < 8 * 1024,
            "resident memory grew from {lo} to {hi} KiB: {rss:?}"
        );
    }

    /// `nedrt run --backend wgpu --sink headless` over the test pattern,
    /// on the device path and the host path side by side: the device path
    /// uploads each frame once, as the pattern sends it (RGBA8), and reads
    /// nothing back; the host path reads the network's output back and
    /// uploads the codes again. (That the codes it presents are the CPU
    /// transfer's, bit for bit, is `pipeline::resident`'s test.)
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn frames_stay_on_the_gpu_from_the_upload_to_the_panel() {
        require_gpu();
        let dir = tempfile::tempdir().expect("tempdir");
        // The shipped network without its card: no host Wiener stage.
        let network = dir.path().join("network.onnx");
        std::fs::copy(repo().join("models/dcnn.onnx"), &network).expect("copy the model");
        for path in ["device", "host"] {
            let report_path = dir.path().join(format!("{path}.json"));
            let out = nedrt()
                .current_dir(repo())
                .args(["run", "--calib"])
                .arg(small_panel())
                .arg("--dcnn")
                .arg(&network)
                .args(["--backend", "wgpu", "--source", "pattern", "--frames", "4"])
                .args(["--preprocess", "proposed"])
                .args(["--sink", "headless", "--frame-path", path, "--report-json"])
                .arg(&report_path)
                .output_within(deadline::COMMAND, "nedrt run (4 frames on the GPU)");
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
            let r: serde_json::Value =
                serde_json::from_slice(&std::fs::read(&report_path).expect("report"))
                    .expect("json");
            assert!(
                r["frame_path"]
                    .as_str()
                    .expect("frame_path")
                    .starts_with(path),
                "{}",
                r["frame_path"]
            );
            assert!(
                r["backend"].as_str().expect("backend").contains("wgpu"),
                "{r}"
            );
            assert_eq!(r["dcnn_failures"], 0, "{r}");
            let stage = |name: &str| {
                r["traffic"]
                    .as_array()
                    .expect("traffic")
                    .iter()
                    .find(|t| t["stage"] == name)
                    .unwrap_or_else(|| panic!("no {name} traffic: {r}"))
                    .clone()
            };
            let (dcnn, present) = (stage("preprocess"), stage("present"));
            let n = |t: &serde_json::Value, k: &str| t["total"][k].as_u64().expect(k);
            let frames = dcnn["frames"].as_u64().expect("frames");
            let shown = present["frames"].as_u64().expect("frames");
            assert!(frames >= 1 && shown >= 1, "{r}");
            let rgba8 = (W * H * 4) as u64;
            if path == "device" {
                // One upload per frame, of the frame as it came; none back.
                assert_eq!(n(&dcnn, "uploads"), frames, "{r}");
                assert_eq!(n(&dcnn, "to_device_bytes"), frames * rgba8, "{r}");
                // Only the 4-byte non-finite count and, where the adapter
                // has timestamps (lavapipe has), 16 bytes of them for the
                // network and 16 for the whole frame come back, with the
                // fence the stage waits on anyway: no read-back.
                let timed = |name: &str| {
                    r["stages"]
                        .as_array()
                        .expect("stages")
                        .iter()
                        .any(|s| s["stage"] == name && s["count"].as_u64() > Some(0))
                };
                let stamps = if timed("preprocess-frame-gpu") { 32 } else { 0 };
                assert_eq!(timed("preprocess-gpu"), stamps > 0, "{r}");
                assert_eq!(
                    (n(&dcnn, "read_backs"), n(&dcnn, "to_host_bytes")),
                    (0, (4 + stamps) * frames),
                    "{r}"
                );
                assert_eq!(
                    (n(&present, "read_backs"), n(&present, "to_host_bytes")),
                    (0, 0)
                );
                assert_eq!(n(&present, "uploads"), 0, "{r}");
            } else {
                // The host path: f32 planes up, the output back, codes up.
                assert_eq!(n(&dcnn, "read_backs"), frames, "{r}");
                assert_eq!(n(&dcnn, "to_device_bytes"), frames * 3 * rgba8, "{r}");
                assert_eq!(n(&present, "to_device_bytes"), shown * rgba8, "{r}");
            }
        }
    }
}

mod needs_gpu_prefilters {
    use super::*;

    /// The shipped system (its network behind its Wiener), the AI display's
    /// Wiener and `refine:3` keep the frame on the device: no host stage,
    /// one upload of the frame as it came, nothing read back
    /// (docs/gpu-fft.md; the codes are the host's within one, app's tests).
    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_prefilters_keep_frames_on_the_gpu() {
        require_gpu();
        let dir = tempfile::tempdir().expect("tempdir");
        for (i, extra) in [
            &["--preprocess", "proposed"][..],
            &["--preprocess", "ai"][..],
            &[
                "--design",
                "multifocal",
                "--preprocess",
                "doe+wiener",
                "--prefilter",
                "refine:3",
            ][..],
        ]
        .into_iter()
        .enumerate()
        {
            let report_path = dir.path().join(format!("{i}.json"));
            let out = nedrt()
                .current_dir(repo())
                .args(["--calib"])
                .arg(small_panel())
                .args([
                    "run",
                    "--backend",
                    "wgpu",
                    "--source",
                    "pattern",
                    "--frames",
                    "3",
                ])
                .args(extra)
                .args(["--sink", "headless", "--report-json"])
                .arg(&report_path)
                .output_within(deadline::COMMAND, "nedrt run (a prefilter on the GPU)");
            assert!(
                out.status.success(),
                "{extra:?}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            let r: serde_json::Value =
                serde_json::from_slice(&std::fs::read(&report_path).expect("report"))
                    .expect("json");
            let path = r["frame_path"].as_str().expect("frame_path");
            assert!(
                path.starts_with("device (the frame is uploaded as it came"),
                "{extra:?}: {path}"
            );
            let dcnn = r["traffic"]
                .as_array()
                .expect("traffic")
                .iter()
                .find(|t| t["stage"] == "preprocess")
                .cloned()
                .unwrap_or_else(|| panic!("no dcnn traffic: {r}"));
            let n = |k: &str| dcnn["total"][k].as_u64().expect(k);
            let frames = dcnn["frames"].as_u64().expect("frames");
            assert!(frames >= 1, "{r}");
            assert_eq!(
                (n("uploads"), n("to_device_bytes")),
                (frames, frames * (W * H * 4) as u64),
                "{extra:?}"
            );
            assert_eq!(n("read_backs"), 0, "{extra:?}");
        }
    }
}

/// A device lost mid-run on the device path: the dcnn stage switches to the
/// host path with the CPU fallback, re-runs the frame, and every frame is
/// accounted for.
mod needs_gpu_fault {
    use super::*;

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn a_device_lost_on_the_device_path_falls_back_to_the_host_path() {
        require_gpu();
        let dir = tempfile::tempdir().expect("tempdir");
        let network = dir.path().join("network.onnx");
        std::fs::copy(repo().join("models/dcnn.onnx"), &network).expect("copy the model");
        let report_path = dir.path().join("report.json");
        let frames = 5u64;
        let out = nedrt()
            .current_dir(repo())
            .env("NEDRT_LOG", "nedrt=info")
            .args(["run", "--calib"])
            .arg(small_panel())
            .arg("--dcnn")
            .arg(&network)
            .args([
                "--backend",
                "wgpu",
                "--preprocess",
                "proposed",
                "--source",
                "pattern",
                "--source-rate",
                "5",
            ])
            .args(["--frames", &frames.to_string(), "--sink", "headless"])
            .args(["--inject-device-loss-after", "1", "--report-json"])
            .arg(&report_path)
            .output_within(deadline::COMMAND, "nedrt run (a device lost mid-run)");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{err}");
        assert!(err.contains("device lost (injected fault)"), "{err}");
        let r = report(dir.path());
        assert_eq!(r["dcnn_failures"].as_u64(), Some(1), "{r}");
        assert_eq!(r["failed"].as_u64(), Some(0), "the frame was re-run: {r}");
        assert_eq!(r["submitted"].as_u64(), Some(frames), "{r}");
        assert!(
            r["frame_path"]
                .as_str()
                .is_some_and(|p| p.starts_with("host (after the device path failed)")),
            "{r}"
        );
        assert!(
            r["backend"]
                .as_str()
                .is_some_and(|b| b.contains("tract") && b.contains("after a failure")),
            "{r}"
        );
        let accounted: u64 = [
            "presented",
            "dropped_queued",
            "dropped_at_present",
            "skipped",
        ]
        .iter()
        .map(|k| r[k].as_u64().unwrap_or(0))
        .sum();
        assert_eq!(accounted, frames, "{r}");
    }
}

/// Two views (issue 54), the frame budget's ladder and a fixed method
/// alike, from the one builder: both eyes on the device, one decision for
/// both; an injected device loss and the fallback act on both views (each
/// its host preprocessing; the ladder's at the same level).
mod needs_gpu_ladder {
    use super::*;

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn both_views_run_on_the_device_and_fall_back_together() {
        require_gpu();
        for (preprocess, built, fallback) in [
            (
                "auto:none..wiener",
                "2 view(s), the frame budget over none < wiener on the GPU",
                "frame budget over",
            ),
            (
                "doe+wiener",
                "2 views, on the GPU: ",
                "Wiener prefilter of doe+wiener",
            ),
        ] {
            let dir = tempfile::tempdir().expect("tempdir");
            let report_path = dir.path().join("report.json");
            let out = nedrt()
                .current_dir(repo())
                .env("NEDRT_LOG", "nedrt=info")
                .args(["run", "--calib"])
                .arg(small_panel())
                .args(["--stereo", "--preprocess", preprocess])
                .args([
                    "--source",
                    "pattern",
                    "--source-rate",
                    "30",
                    "--frames",
                    "8",
                ])
                .args(["--sink", "headless", "--fallback", "passthrough"])
                .args(["--inject-device-loss-after", "2", "--report-json"])
                .arg(&report_path)
                .output_within(deadline::COMMAND, "nedrt run --stereo (a device lost)");
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(out.status.success(), "{preprocess}: {err}");
            let r: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&report_path).expect("report"))
                    .expect("report JSON");
            // Both views on the device, in one submission, first.
            assert!(err.contains(built), "{preprocess}: {err}");
            assert_eq!(
                r["frame_budget"]["levels"].is_array(),
                preprocess.starts_with("auto"),
                "{r}"
            );
            // Both views failed as one device: one switch, to the host.
            assert_eq!(r["dcnn_failures"].as_u64(), Some(1), "{preprocess}: {r}");
            assert!(
                r["frame_path"]
                    .as_str()
                    .is_some_and(|p| p.starts_with("host (after the device path failed)")),
                "{preprocess}: {r}"
            );
            // Each view's fallback is its preprocessing on the host.
            let backend = r["backend"].as_str().unwrap_or("");
            for v in 0..2 {
                assert!(
                    backend.contains(&format!("view {v}: {fallback}")),
                    "{preprocess}: {backend}"
                );
                let name = format!("preprocess view {v}");
                let ran = r["view_stages"]
                    .as_array()
                    .and_then(|s| s.iter().find(|s| s["stage"] == name.as_str()))
                    .and_then(|s| s["count"].as_u64());
                assert!(ran.is_some_and(|n| n > 0), "{preprocess}: {name}: {r}");
            }
            assert_eq!(r["failed"].as_u64(), Some(0), "the frame was re-run: {r}");
        }
    }
}

/// `nedrt bench pipeline` runs each network on both frame paths in one run
/// and reports their traffic side by side.
mod needs_gpu_bench {
    use super::*;

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_pipeline_bench_puts_both_frame_paths_side_by_side() {
        require_gpu();
        let dir = tempfile::tempdir().expect("tempdir");
        let out = nedrt()
            .current_dir(repo())
            .args(["bench", "pipeline", "--networks", "none,half"])
            .args(["--panel", "32x32", "--frames", "2", "--max-seconds", "100"])
            .arg("--dump")
            .arg(dir.path())
            .arg("--frame-log")
            .arg(dir.path().join("frames"))
            .output_within(deadline::COMMAND, "nedrt bench pipeline");
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let records: Vec<serde_json::Value> = stdout
            .lines()
            .filter(|l| l.starts_with('{'))
            .map(|l| serde_json::from_str(l).expect("json"))
            .collect();
        let cases: Vec<(String, String)> = records
            .iter()
            .map(|r| (r["network"].to_string(), r["frame_path"].to_string()))
            .collect();
        assert_eq!(cases.len(), 4, "{cases:?}");
        for r in &records {
            assert!(r["presented"].as_u64().expect("presented") >= 1, "{r}");
            assert!(r["e2e_p99_ms"].as_f64().expect("p99") > 0.0, "{r}");
            // Where the time goes, for a device run to read back: every
            // stage's percentiles, the late frames, the source's lead.
            assert!(r["late"].as_u64().is_some(), "{r}");
            assert!(r["ahead_ms"].as_f64().expect("ahead_ms") > 0.0, "{r}");
            let stages: Vec<&str> = r["stages"]
                .as_array()
                .expect("stages")
                .iter()
                .map(|s| s["stage"].as_str().expect("stage"))
                .collect();
            assert!(
                stages.contains(&"end-to-end") && stages.contains(&"queued"),
                "{r}"
            );
            let reads = r["read_backs"].as_f64().expect("read_backs");
            // Per presented frame: frames dropped on the way add their
            // traffic to the ones shown, so at least one frame's worth.
            let uploads = r["uploads"].as_f64().expect("uploads");
            if r["frame_path"] == "device" {
                assert!(
                    r["path_detail"]
                        .as_str()
                        .expect("detail")
                        .starts_with("device")
                );
                assert_eq!(reads, 0.0, "{r}");
                assert!(uploads >= 1.0, "{r}");
            } else if r["network"] == "half" {
                // The network's output comes back, the codes go up again.
                assert!(reads >= 1.0 && uploads >= 2.0, "{r}");
            }
        }
        assert!(stdout.contains("| half | device |"), "{stdout}");
        // Each case's timelines: a frame for each shown or replaced at the
        // panel, a refresh for each the present loop worked for; the table
        // of where their time went.
        assert!(stdout.contains("Where the frames' time went"), "{stdout}");
        for r in &records {
            let name = format!(
                "frames-{}-{}-f32.json",
                r["network"].as_str().expect("network"),
                r["frame_path"].as_str().expect("path")
            );
            let path = dir.path().join("frames").join(&name);
            let log: serde_json::Value =
                serde_json::from_slice(&std::fs::read(&path).expect(&name)).expect("json");
            let frames = log["frames"].as_array().expect("frames");
            let shown = frames.iter().filter(|f| f["outcome"] == "shown").count() as u64;
            let replaced = frames.iter().filter(|f| f["outcome"] == "replaced").count() as u64;
            assert_eq!(shown, r["presented"].as_u64().expect("presented"), "{name}");
            assert_eq!(
                replaced,
                r["dropped_at_present"].as_u64().expect("slot"),
                "{name}"
            );
            // The device path notes each frame's host time before its
            // submission; the host path has none to note.
            let device = r["frame_path"] == "device";
            assert!(
                frames.iter().all(|f| f["record_ms"].is_number() == device),
                "{name}: record_ms"
            );
            let refreshes = log["refreshes"].as_array().expect("refreshes");
            let with_frame = refreshes.iter().filter(|x| !x["frame"].is_null()).count() as u64;
            assert_eq!(with_frame, shown, "{name}");
            let rows = r["timeline"].as_array().expect("timeline");
            let counted: u64 = rows.iter().map(|x| x["count"].as_u64().unwrap_or(0)).sum();
            assert_eq!(counted, shown + replaced, "{r}");
        }
    }
}

mod needs_gpu_and_window {
    use super::*;

    #[test]
    #[ignore = "needs an X display and a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn the_window_shows_the_preprocessed_frame() {
        assert!(
            std::env::var_os("DISPLAY").is_some(),
            "this test needs an X display and DISPLAY is not set \
             (run it under Xvfb, e.g. xvfb-run; scripts/test.sh starts one)"
        );
        require_gpu();
        let dir = tempfile::tempdir().expect("tempdir");
        let frame = test_frame(3);
        let input = dir.path().join("in.png");
        let rgb8: Vec<u8> = (0..W * H)
            .flat_map(|i| (0..3).map(move |c| (c, i)))
            .map(|(c, i)| (frame.data()[c * W * H + i] * 255.0).round() as u8)
            .collect();
        image::RgbImage::from_raw(W as u32, H as u32, rgb8.clone())
            .expect("image")
            .save(&input)
            .expect("save");
        // The input as the service reads it: 8-bit values as linear intensity.
        let as_read = Image::rgb(
            W,
            H,
            (0..3)
                .flat_map(|c| (0..W * H).map(move |i| (c, i)))
                .map(|(c, i)| rgb8[3 * i + c] as f32 / 255.0)
                .collect(),
        );
        let (mut dcnn, transfer) = reference();
        // Through the host: the network on the CPU, the codes uploaded.
        let want = expected_rgb(&mut dcnn, &transfer, &as_read);
        window_shows(
            &input,
            &want,
            &["--backend", "cpu"],
            tempfile::tempdir().expect("tempdir"),
        );
        // On the device: no network, the frame unpacked, encoded and
        // copied to the surface's texture on the GPU.
        let mut codes = Vec::new();
        transfer.encode_rgba8(&as_read, &mut codes);
        let want = nedrt_service::present::rgb8_of_rgba8(&codes);
        window_shows(&input, &want, &["--preprocess", "conventional"], dir);
    }

    /// Runs `nedrt run --source dir --input <input> --sink window` with
    /// `args` until the window shows `want` (RGB8), then stops it.
    fn window_shows(input: &Path, want: &[u8], args: &[&str], dir: tempfile::TempDir) {
        let mut all = vec![
            "--source",
            "dir",
            "--input",
            input.to_str().expect("utf-8"),
            "--sink",
            "window",
            "--keep-open",
        ];
        all.extend_from_slice(args);
        let mut service = Service::start(&all, dir);
        let start = Instant::now();
        let mut last;
        loop {
            // A service that stopped will never show it: say why now.
            if let Some(status) = service.child.try_wait() {
                let out = service.child.output();
                panic!(
                    "the service ({args:?}) exited with {status} before showing the frame: {}",
                    String::from_utf8_lossy(&out.stderr)
                );
            }
            match super::xwd::screenshot("nedrt") {
                Ok((w, h, rgb)) => {
                    if (w, h) == (W, H) && rgb == want {
                        break;
                    }
                    let differ = rgb.iter().zip(want).filter(|(a, b)| a != b).count();
                    last = format!("{w}×{h}, {differ} values differ");
                }
                Err(e) => last = e,
            }
            if start.elapsed() > Duration::from_secs(60) {
                let (out, _dir) = service.stop();
                let log = String::from_utf8_lossy(&out.stderr);
                let tail: String = {
                    let chars: Vec<char> = log.chars().collect();
                    chars[chars.len().saturating_sub(3000)..].iter().collect()
                };
                panic!(
                    "the window never showed the expected frame ({args:?}) in 60 s: {last}; \
                     the service's log ends: {tail}"
                );
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        let (out, _dir) = service.stop();
        assert!(
            out.status.success(),
            "SIGTERM ends the service cleanly: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            String::from_utf8_lossy(&out.stdout).contains("1 presented"),
            "{}",
            String::from_utf8_lossy(&out.stdout)
        );
    }
}
