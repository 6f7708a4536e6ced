//! Integration tests of `nedrt run` on the small test panel
//! (tests/data/small-panel.toml, 64×48 at 240 Hz): frames streamed over the
//! socket protocol are recorded bit for bit as the backend computes them,
//! every kind of bad frame is rejected while good ones get through, a soak
//! of thousands of frames keeps its memory flat, and a real window under
//! Xvfb shows the expected frame. The last two need a GPU adapter (and an
//! X display): `#[ignore]`d, in modules named after what they need, and run
//! by `scripts/test.sh` where the machine has it.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use nedrt_core::Image;
use nedrt_core::calib::Calibration;
use nedrt_infer::{BackendKind, BackendOptions, Dcnn};
use nedrt_service::pipeline::frame::{PixelFormat, RejectReason, planar_payload};
use nedrt_service::pipeline::protocol::{Client, FrameHeader, HEADER_LEN, STATUS_OK};
use nedrt_service::present::recorder::frame_path;
use nedrt_service::present::transfer::Transfer;

const W: usize = 64;
const H: usize = 48;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn small_panel() -> PathBuf {
    repo().join("tests/data/small-panel.toml")
}

/// A running service with its scratch folder.
struct Service {
    child: Child,
    dir: tempfile::TempDir,
}

impl Service {
    fn start(args: &[&str], dir: tempfile::TempDir) -> Self {
        let child = Command::new(env!("CARGO_BIN_EXE_nedrt"))
            .current_dir(repo())
            .env("NEDRT_LOG", "nedrt=info")
            .arg("run")
            .arg("--calib")
            .arg(small_panel())
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start nedrt run");
        Self { child, dir }
    }

    fn socket(dir: &Path) -> PathBuf {
        dir.join("nedrt.sock")
    }

    /// Starts a socket service recording into `<dir>/rec`.
    fn socket_recorder() -> Self {
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::create_dir_all(dir.path().join("shm")).expect("shm dir");
        let socket = Self::socket(dir.path());
        let args = [
            "--backend".to_string(),
            "cpu".into(),
            "--source".into(),
            "socket".into(),
            "--socket".into(),
            socket.display().to_string(),
            "--shm-dir".into(),
            dir.path().join("shm").display().to_string(),
            "--sink".into(),
            "record".into(),
            "--record-dir".into(),
            dir.path().join("rec").display().to_string(),
            "--report-json".into(),
            dir.path().join("report.json").display().to_string(),
        ];
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let s = Self::start(&args, dir);
        wait_until("the socket to appear", || socket.exists());
        s
    }

    fn client(&self, shm_bytes: usize) -> Client {
        Client::connect(
            &Self::socket(self.dir.path()),
            &self.dir.path().join("shm"),
            shm_bytes as u64,
        )
        .expect("connect")
    }

    /// SIGTERM, then the exit status and output.
    fn stop(self) -> (Output, tempfile::TempDir) {
        let status = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status()
            .expect("kill");
        assert!(status.success());
        let out = self.child.wait_with_output().expect("wait");
        (out, self.dir)
    }
}

fn wait_until(what: &str, mut ok: impl FnMut() -> bool) {
    let start = Instant::now();
    while !ok() {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "timed out waiting for {what}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn report(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("report.json")).expect("report.json");
    serde_json::from_str(&text).expect("report JSON")
}

/// A distinct, smooth test frame per id, values in [0, 1].
fn test_frame(id: u64) -> Image {
    let mut data = Vec::with_capacity(3 * W * H);
    for c in 0..3 {
        for y in 0..H {
            for x in 0..W {
                let v = 0.5
                    + 0.45
                        * ((x as f32 * 0.21 + id as f32 * 0.7 + c as f32).sin()
                            * (y as f32 * 0.13 - id as f32 * 0.3).cos());
                data.push(v);
            }
        }
    }
    Image::rgb(W, H, data)
}

/// What the panel must show for `frame`: the shipped D-CNN on tract, then
/// the small panel's transfer curve, as RGB.
fn expected_rgb(dcnn: &mut Dcnn, transfer: &Transfer, frame: &Image) -> Vec<u8> {
    let out = dcnn.run_frame(frame).expect("D-CNN");
    let mut rgba = Vec::new();
    transfer.encode_rgba8(&out, &mut rgba);
    rgba.chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect()
}

fn reference() -> (Dcnn, Transfer) {
    let calib = Calibration::load(&small_panel()).expect("calib");
    let dcnn = Dcnn::load(
        &repo().join("models/dcnn.onnx"),
        BackendKind::Cpu,
        &BackendOptions::default(),
    )
    .expect("model");
    (dcnn, Transfer::from_panel(&calib.panel))
}

#[test]
fn socket_frames_are_recorded_exactly_as_the_backend_computes_them() {
    let service = Service::socket_recorder();
    let mut client = service.client(W * H * 12);
    assert_eq!(client.panel, (W, H));
    let n = 12u64;
    for id in 0..n {
        let frame = test_frame(id);
        let header = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, id, 0);
        let reply = client.send(&header, &planar_payload(&frame)).expect("send");
        assert_eq!(
            (reply.status, reply.frame_id),
            (STATUS_OK, id),
            "{}",
            reply.message
        );
    }
    let rec = service.dir.path().join("rec");
    wait_until("the last frame to be recorded", || {
        frame_path(&rec, n - 1).exists()
    });
    let (out, dir) = service.stop();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r = report(dir.path());
    let presented = r["presented"].as_u64().expect("presented");
    let dropped = r["dropped_queued"].as_u64().expect("dropped")
        + r["dropped_at_present"].as_u64().expect("dropped");
    assert_eq!(r["submitted"].as_u64(), Some(n));
    assert_eq!(
        presented + dropped,
        n,
        "every frame presented or counted as dropped"
    );
    let (mut dcnn, transfer) = reference();
    let mut checked = 0;
    for id in 0..n {
        let path = frame_path(&dir.path().join("rec"), id);
        if !path.exists() {
            continue;
        }
        let got = image::open(&path).expect("png").to_rgb8().into_raw();
        assert_eq!(
            got,
            expected_rgb(&mut dcnn, &transfer, &test_frame(id)),
            "frame {id}"
        );
        checked += 1;
    }
    assert_eq!(checked as u64, presented);
    assert!(checked >= 1);
}

#[test]
fn every_kind_of_bad_frame_is_rejected_and_good_frames_still_arrive() {
    let service = Service::socket_recorder();
    let shm = W * H * 12;
    let mut client = service.client(shm);
    let good = |id| {
        (
            FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, id, 0),
            planar_payload(&test_frame(id)),
        )
    };
    let mut nan = test_frame(0);
    nan.data_mut()[100] = f32::NAN;
    let mut bright = test_frame(0);
    bright.data_mut()[7] = 1.5;
    let mut bad_magic = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 901, 0).to_bytes();
    bad_magic[0] = b'X';
    let mut bad_version = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 902, 0).to_bytes();
    bad_version[4] = 9;
    let mut unknown_format = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 903, 0);
    unknown_format.format = 77;
    let wrong_size = FrameHeader::new(PixelFormat::Rgb32fPlanar, W / 2, H, 904, 0);
    let mut short = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 905, 0);
    short.length -= 4;
    let mut outside = FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 906, 0);
    outside.offset = 8;
    let cases: Vec<(Vec<u8>, Option<Vec<u8>>, RejectReason)> = vec![
        (bad_magic.to_vec(), None, RejectReason::Malformed),
        (bad_version.to_vec(), None, RejectReason::Malformed),
        (
            unknown_format.to_bytes().to_vec(),
            None,
            RejectReason::UnsupportedFormat,
        ),
        (
            wrong_size.to_bytes().to_vec(),
            None,
            RejectReason::WrongSize,
        ),
        (short.to_bytes().to_vec(), None, RejectReason::Truncated),
        (outside.to_bytes().to_vec(), None, RejectReason::Truncated),
        (
            FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 907, 0)
                .to_bytes()
                .to_vec(),
            Some(planar_payload(&nan)),
            RejectReason::NonFinite,
        ),
        (
            FrameHeader::new(PixelFormat::Rgb32fPlanar, W, H, 908, 0)
                .to_bytes()
                .to_vec(),
            Some(planar_payload(&bright)),
            RejectReason::OutOfRange,
        ),
    ];
    let mut id = 0u64;
    let send_good = |client: &mut Client, id: &mut u64| {
        let (h, p) = good(*id);
        let r = client.send(&h, &p).expect("good frame");
        assert_eq!(r.status, STATUS_OK, "good frame {id}: {}", r.message);
        *id += 1;
        // Far slower than the pipeline, so no good frame is dropped.
        std::thread::sleep(Duration::from_millis(150));
    };
    for (header, body, reason) in &cases {
        send_good(&mut client, &mut id);
        let r = match body {
            Some(b) => {
                let mut h = [0u8; HEADER_LEN];
                h.copy_from_slice(header);
                client
                    .send(&FrameHeader::parse(&h).expect("header"), b)
                    .expect("reply")
            }
            None => client.send_header_bytes(header).expect("reply"),
        };
        assert_eq!(
            RejectReason::from_code(r.status),
            Some(*reason),
            "{}",
            r.message
        );
        assert!(!r.message.is_empty());
    }
    // A client that vanishes mid-header, and one with a bad hello.
    {
        let mut half = service.client(16);
        use std::io::Write;
        half.stream()
            .write_all(&good(0).0.to_bytes()[..10])
            .expect("half a header");
    }
    {
        use std::io::{Read, Write};
        let mut raw = std::os::unix::net::UnixStream::connect(Service::socket(service.dir.path()))
            .expect("connect");
        raw.write_all(b"HELLO, this is not the protocol")
            .expect("write");
        let mut buf = Vec::new();
        let _ = raw.read_to_end(&mut buf);
        assert!(
            String::from_utf8_lossy(&buf).contains("bad hello"),
            "{:?}",
            String::from_utf8_lossy(&buf)
        );
    }
    send_good(&mut client, &mut id);
    let last = id - 1;
    let rec = service.dir.path().join("rec");
    wait_until("the last good frame", || frame_path(&rec, last).exists());
    let (out, dir) = service.stop();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for good_id in 0..id {
        assert!(
            frame_path(&dir.path().join("rec"), good_id).exists(),
            "good frame {good_id} was not delivered"
        );
    }
    let r = report(dir.path());
    let rejected: std::collections::HashMap<String, u64> = r["rejected"]
        .as_array()
        .expect("rejected")
        .iter()
        .map(|p| {
            (
                p[0].as_str().expect("name").to_string(),
                p[1].as_u64().expect("n"),
            )
        })
        .collect();
    assert_eq!(rejected["malformed"], 2);
    assert_eq!(rejected["unsupported-format"], 1);
    assert_eq!(rejected["wrong-size"], 1);
    assert_eq!(rejected["truncated"], 2);
    assert_eq!(rejected["non-finite"], 1);
    assert_eq!(rejected["out-of-range"], 1);
    assert_eq!(r["disconnects_mid_frame"].as_u64(), Some(1));
    assert_eq!(r["submitted"].as_u64(), Some(id + cases.len() as u64));
    assert_eq!(
        r["presented"].as_u64(),
        Some(id),
        "{}",
        serde_json::to_string(&r).unwrap_or_default()
    );
}

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

/// Reads an XWD (X Window Dump) of a 24/32-bit TrueColor window as RGB.
fn parse_xwd(b: &[u8]) -> (usize, usize, Vec<u8>) {
    let be = |i: usize| u32::from_be_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]);
    let (header, w, h) = (be(0) as usize, be(4) as usize, be(5) as usize);
    let (byte_order, bpp, stride) = (be(7), be(11) as usize, be(12) as usize);
    let (rm, gm, bm, ncolors) = (be(14), be(15), be(16), be(19) as usize);
    assert_eq!(bpp, 32, "expected a 32-bit visual");
    let data = &b[header + 12 * ncolors..];
    let chan = |p: u32, m: u32| ((p & m) >> m.trailing_zeros()) as u8;
    let mut rgb = Vec::with_capacity(3 * w * h);
    for y in 0..h {
        for x in 0..w {
            let q = &data[y * stride + 4 * x..y * stride + 4 * x + 4];
            let p = if byte_order == 0 {
                u32::from_le_bytes([q[0], q[1], q[2], q[3]])
            } else {
                u32::from_be_bytes([q[0], q[1], q[2], q[3]])
            };
            rgb.extend([chan(p, rm), chan(p, gm), chan(p, bm)]);
        }
    }
    (w, h, rgb)
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
            let shot = Command::new("xwd")
                .args(["-name", "nedrt", "-silent"])
                .output()
                .expect("xwd (x11-apps)");
            if shot.status.success() && shot.stdout.len() > 100 {
                let (w, h, rgb) = parse_xwd(&shot.stdout);
                if (w, h) == (W, H) && rgb == want {
                    break;
                }
                let differ = rgb.iter().zip(&want).filter(|(a, b)| a != b).count();
                last = format!("{w}×{h}, {differ} values differ");
            } else {
                last = String::from_utf8_lossy(&shot.stderr).into_owned();
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
