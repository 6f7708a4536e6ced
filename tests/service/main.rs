//! Integration tests of `nedrt run` on the small test panel
//! (tests/data/small-panel.toml, 64×48 at 240 Hz): frames streamed over the
//! socket protocol are recorded bit for bit as the backend computes them,
//! every kind of bad frame is rejected while good ones get through, a soak
//! of thousands of frames keeps its memory flat, and a real window under
//! Xvfb shows the expected frame. The last two need a GPU adapter (and an
//! X display): `#[ignore]`d, in modules named after what they need, and run
//! by `scripts/test.sh` where the machine has it.

#[path = "../common/deadline.rs"]
mod deadline;
mod faults;
mod hardware;
mod layers;
mod openxr;
mod socket;
#[path = "../common/xwd.rs"]
mod xwd;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use deadline::{CommandWithin, Watched};

use nedrt_core::Image;
use nedrt_core::calib::Calibration;
use nedrt_infer::{BackendKind, BackendOptions, Dcnn};
use nedrt_protocol::{Client, FrameHeader, HEADER_LEN, STATUS_OK};
use nedrt_service::pipeline::frame::{PixelFormat, RejectReason, planar_payload};
use nedrt_service::present::recorder::frame_path;
use nedrt_service::present::transfer::Transfer;

const W: usize = 64;
const H: usize = 48;

/// The tests' shared PSF cache's bound, in GB (`NEDRT_CACHE_MAX_GB`, which
/// overrides it): a few of the largest entries.
const TEST_CACHE_MAX_GB: &str = "2";

/// `nedrt`, with the PSF cache of the whole test run inside the build
/// folder: the tests never fill the user's own cache.
fn nedrt() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_nedrt"));
    c.env(
        "NEDRT_CACHE_DIR",
        Path::new(env!("CARGO_TARGET_TMPDIR")).join("psf-cache"),
    );
    // Bounded, as CI's disk is limited: unbounded, the run's PSFs took 5.3 GB.
    if std::env::var_os("NEDRT_CACHE_MAX_GB").is_none() {
        c.env("NEDRT_CACHE_MAX_GB", TEST_CACHE_MAX_GB);
    }
    c
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn small_panel() -> PathBuf {
    repo().join("tests/data/small-panel.toml")
}

/// How long a client waits for the service's welcome or a reply, and a
/// test for a client's thread: past it the test fails (a hang, not
/// slowness: a reply takes milliseconds).
const REPLY_WITHIN: Duration = Duration::from_secs(120);

/// How long the service may take to exit after SIGTERM before the test
/// fails (tests that hold it to a promptness bound assert that apart).
const EXIT_WITHIN: Duration = Duration::from_secs(60);

/// A running service with its scratch folder; killed if the test fails
/// before stopping it.
struct Service {
    child: Watched,
    dir: tempfile::TempDir,
}

impl Service {
    fn start(args: &[&str], dir: tempfile::TempDir) -> Self {
        // The shipped network without its card, so it sees the frame
        // itself: these tests compare the service with the backend
        // ([`reference`]), not with the Wiener stage the card adds.
        let network = dir.path().join("network.onnx");
        std::fs::copy(repo().join("models/dcnn.onnx"), &network).expect("copy the model");
        let mut c = nedrt();
        c.current_dir(repo())
            .env("NEDRT_LOG", "nedrt=info")
            .arg("run")
            .arg("--calib")
            .arg(small_panel())
            .arg("--dcnn")
            .arg(&network)
            .args(args);
        // The network fixed unless a test names its preprocessing: these
        // tests are about the service, not the frame budget's ladder.
        if !args.contains(&"--preprocess") {
            c.args(["--preprocess", "proposed"]);
        }
        let child = c.spawn_watched("the service (nedrt run)");
        Self { child, dir }
    }

    fn socket(dir: &Path) -> PathBuf {
        dir.join("nedrt.sock")
    }

    /// Starts a socket service recording into `<dir>/rec`.
    fn socket_recorder() -> Self {
        Self::socket_recorder_with(&[])
    }

    /// As [`Service::socket_recorder`], with `extra` arguments (`--stereo`).
    fn socket_recorder_with(extra: &[&str]) -> Self {
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
        let args: Vec<&str> = args
            .iter()
            .map(String::as_str)
            .chain(extra.iter().copied())
            .collect();
        let s = Self::start(&args, dir);
        wait_until("the socket to appear", || socket.exists());
        s
    }

    /// A protocol version 1 client with `shm_bytes` of shared memory.
    fn client(&self, shm_bytes: usize) -> Client {
        let (socket, shm) = (Self::socket(self.dir.path()), self.dir.path().join("shm"));
        bounded_client("the service's welcome (version 1)", move || {
            refused_at_first(|| Client::connect(&socket, &shm, shm_bytes as u64))
        })
    }

    /// As [`Service::client`], speaking protocol version 2.
    fn client_v2(&self, shm_bytes: usize) -> Client {
        let (socket, shm) = (Self::socket(self.dir.path()), self.dir.path().join("shm"));
        bounded_client("the service's welcome (version 2)", move || {
            refused_at_first(|| Client::connect_v2(&socket, &shm, shm_bytes as u64))
        })
    }

    /// SIGTERM, then the exit status and output.
    fn stop(self) -> (Output, tempfile::TempDir) {
        signal(&self.child, "-TERM");
        let out = self
            .child
            .wait_within(EXIT_WITHIN, "the service to exit after SIGTERM");
        (out, self.dir)
    }
}

/// Sends `signal` ("-TERM") to `child` (`kill`, which returns at once).
fn signal(child: &Watched, signal: &str) {
    let status = Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(status.success(), "kill {signal} {}", child.id());
}

/// A client connected by `connect` within [`REPLY_WITHIN`], whose every
/// later wait for a reply (or to send) fails past it, with an error the
/// test's `expect` names, instead of blocking.
fn bounded_client(
    what: &str,
    connect: impl FnOnce() -> std::io::Result<Client> + Send + 'static,
) -> Client {
    let mut client =
        deadline::within(REPLY_WITHIN, what, connect).unwrap_or_else(|e| panic!("{what}: {e}"));
    let stream = client.stream();
    stream
        .set_read_timeout(Some(REPLY_WITHIN))
        .expect("a read timeout");
    stream
        .set_write_timeout(Some(REPLY_WITHIN))
        .expect("a write timeout");
    client
}

/// `connect`, tried again while the service refuses it for up to a
/// second: the socket's file appears when it is bound, a moment before the
/// service listens on it, and a loaded machine once put a test's first
/// connection in that moment (ECONNREFUSED).
fn refused_at_first(
    mut connect: impl FnMut() -> std::io::Result<Client>,
) -> std::io::Result<Client> {
    for _ in 0..100 {
        match connect() {
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                std::thread::sleep(Duration::from_millis(10));
            }
            other => return other,
        }
    }
    connect()
}

fn wait_until(what: &str, ok: impl FnMut() -> bool) {
    deadline::wait_until_within(Duration::from_secs(120), what, ok);
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
    nedrt_service::present::rgb8_of_rgba8(&rgba)
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
