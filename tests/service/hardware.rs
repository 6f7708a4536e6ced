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
        let dir = tempfile::tempdir().expect("tempdir");
        let report_path = dir.path().join("report.json");
        let frames = 3000u64;
        let out = Command::new(env!("CARGO_BIN_EXE_nedrt"))
            .current_dir(repo())
            .args(["run", "--calib"])
            .arg(small_panel())
            .args([
                "--backend",
                "cpu",
                "--source",
                "pattern",
                "--frames",
                &frames.to_string(),
                "--sink",
                "headless",
                "--report-json",
            ])
            .arg(&report_path)
            .output()
            .expect("run");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let r = report(dir.path());
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
        assert!(
            n("presented") >= frames / 2,
            "most frames reach the panel: {r}"
        );
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
        let want = expected_rgb(&mut dcnn, &transfer, &as_read);
        let service = Service::start(
            &[
                "--backend",
                "cpu",
                "--source",
                "dir",
                "--input",
                input.to_str().expect("utf-8"),
                "--sink",
                "window",
                "--keep-open",
            ],
            dir,
        );
        let start = Instant::now();
        let mut last;
        loop {
            match super::xwd::screenshot("nedrt") {
                Ok((w, h, rgb)) => {
                    if (w, h) == (W, H) && rgb == want {
                        break;
                    }
                    let differ = rgb.iter().zip(&want).filter(|(a, b)| a != b).count();
                    last = format!("{w}×{h}, {differ} values differ");
                }
                Err(e) => last = e,
            }
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "the window never showed the expected frame: {last}"
            );
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
