//! End-to-end tests of the `nedrt` binary: the README's main command, every
//! kind of bad input named in the issue (a clear one-line error, non-zero
//! exit, nothing half-written), the PSF cache, eval and the plots. One test
//! binary; a module per command family, the helpers here.

mod bad_input;
mod calib;
mod dcnn;
#[path = "../common/deadline.rs"]
mod deadline;
mod eval;
mod plan;
mod prefilter;
mod run;
mod sim;
mod stereo;
mod studies;
mod unrolled;
mod view;
#[path = "../common/xwd.rs"]
mod xwd;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use deadline::CommandWithin;

/// The tests' shared PSF cache's bound, in GB (`NEDRT_CACHE_MAX_GB`, which
/// overrides it): a few of the largest entries.
const TEST_CACHE_MAX_GB: &str = "2";

fn nedrt() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_nedrt"));
    // One shared cache for the whole test run, inside the build folder.
    c.env(
        "NEDRT_CACHE_DIR",
        Path::new(env!("CARGO_TARGET_TMPDIR")).join("psf-cache"),
    );
    // Bounded, as CI's disk is limited: unbounded, the run's PSFs took 5.3 GB.
    if std::env::var_os("NEDRT_CACHE_MAX_GB").is_none() {
        c.env("NEDRT_CACHE_MAX_GB", TEST_CACHE_MAX_GB);
    }
    c.env_remove("NEDRT_LOG");
    c
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn small_calib() -> PathBuf {
    repo().join("tests/data/small-aperture.toml")
}

/// `nedrt` with `args`, to its end ([`deadline::COMMAND`] at most).
fn run(args: &[&str]) -> Output {
    nedrt().args(args).output_within(deadline::COMMAND, "nedrt")
}

/// `nedrt --sim --accom D --out OUT` with extra arguments.
/// `nedrt --sim` of one method: the conventional display unless `extra`
/// names one or a display image (without either, `--sim` runs the shipped
/// system and scores every method beside it: the README test's case).
fn sim(accom: &str, out: &Path, extra: &[&str]) -> Output {
    let one = if extra.contains(&"--method") || extra.contains(&"--display-image") {
        &[][..]
    } else {
        &["--method", "conventional"][..]
    };
    run(&[
        &["--sim", "--accom", accom, "--out", path(out)][..],
        one,
        extra,
    ]
    .concat())
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

/// The small test panel (64×48 at 240 Hz) for the service.
fn small_panel() -> PathBuf {
    repo().join("tests/data/small-panel.toml")
}

/// `nedrt run --calib <small panel> --backend cpu` from the repository root
/// (where the shipped model is), to be given its source and sink.
fn run_on_small_panel() -> Command {
    let mut c = nedrt();
    c.current_dir(repo())
        .args(["run", "--calib", path(&small_panel()), "--backend", "cpu"])
        // The shipped system fixed: these runs are about the service, not
        // the frame budget's ladder (tests/cli/plan.rs, tests/service).
        .args(["--preprocess", "proposed"]);
    c
}
