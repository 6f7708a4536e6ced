//! The bad-input catalogue (docs/reliability.md lists the rows): every
//! kind of hostile or broken input a user can give, as one table. Each row
//! runs the binary on one bad input and must get a non-zero exit, no
//! panic, exactly one `error:` line holding the row's text (which names the
//! file or field and the reason), and no output file. The protocol rows run
//! the service's own header and hello checks (the socket tests in
//! tests/service run the same cases through a live service).

use super::*;

use std::time::Duration;

use nedrt_protocol::PixelFormat;
use nedrt_protocol::{FrameHeader, HELLO_LEN, Hello, valid_shm_name};
use nedrt_service::pipeline::source::socket::admit;
use nedrt_service::pipeline::source::socket::v2;

/// One bad input: a name (the row in docs/reliability.md), the command
/// line (`{dir}` is the row's scratch folder holding the prepared files,
/// `{out}` an output path that must stay unwritten), and the text the one
/// error line must hold.
struct Row {
    name: &'static str,
    args: &'static [&'static str],
    needle: &'static str,
}

const fn row(name: &'static str, args: &'static [&'static str], needle: &'static str) -> Row {
    Row { name, args, needle }
}

/// `--sim` on the small-aperture calibration with an input image.
const SIM: &[&str] = &["--sim", "--accom", "1", "--out", "{out}"];

const ROWS: &[Row] = &[
    // Images.
    row(
        "image: missing file",
        &["--input", "{dir}/none.png"],
        "none.png: cannot read image",
    ),
    row(
        "image: a folder",
        &["--input", "{dir}"],
        "cannot read image",
    ),
    row(
        "image: empty file",
        &["--input", "{dir}/empty.png"],
        "empty.png: cannot decode image",
    ),
    row(
        "image: text named .png",
        &["--input", "{dir}/text.png"],
        "text.png: cannot decode image",
    ),
    row(
        "image: truncated PNG",
        &["--input", "{dir}/truncated.png"],
        "truncated.png: cannot decode image",
    ),
    row(
        "image: transparency",
        &["--input", "{dir}/alpha.png"],
        "alpha.png: has transparency",
    ),
    row(
        "image: 1×1 pixel",
        &["--input", "{dir}/tiny.png"],
        "tiny.png: 1×1",
    ),
    row(
        "image: 30000×1 pixels",
        &["--input", "{dir}/line.png"],
        "line.png: 30000×1 image is larger than the 1920×1080 panel that shows it",
    ),
    row(
        "image: header claims 20000×20000",
        &["--input", "{dir}/claims.png"],
        "claims.png: 20000×20000 image is larger",
    ),
    row(
        "image: 224-byte JPEG claiming 2048×9734 (found by fuzzing)",
        &[
            "--input",
            "{repo}/fuzz/seeds/image/found-timeout-progressive-jpeg-2048x9734.jpg",
        ],
        "2048×9734 image is larger than the 1920×1080 panel that shows it",
    ),
    row(
        "image: larger than the panel",
        &["--input", "{dir}/wide-photo.png"],
        "wide-photo.png: 2000×16 image is larger than the 1920×1080 panel",
    ),
    row(
        "image: NaN in a float TIFF",
        &["--input", "{dir}/nan.tif"],
        "nan.tif: pixel 3,4 channel 0 is NaN",
    ),
    row(
        "image: +inf in a float TIFF",
        &["--input", "{dir}/inf.tif"],
        "inf.tif: pixel 1,2 channel 1 is inf",
    ),
    row(
        "image: value 2.0 in a float TIFF",
        &["--input", "{dir}/bright.tif"],
        "bright.tif: pixel 0,0 channel 2 is 2; display intensities lie in [0, 1]",
    ),
    row(
        "image: negative value in a float TIFF",
        &["--input", "{dir}/negative.tif"],
        "negative.tif: pixel 0,0 channel 0 is -0.5",
    ),
    row(
        "image: /dev/zero",
        &["--input", "/dev/zero"],
        "/dev/zero: cannot read image: larger than 512 MiB",
    ),
    row(
        "image: display image of another size",
        &[
            "--display-image",
            "{dir}/other-size.png",
            "--input",
            "{dir}/good.png",
        ],
        "other-size.png",
    ),
    // Calibrations.
    row(
        "calibration: missing file",
        &["--calib", "{dir}/none.toml"],
        "none.toml",
    ),
    row(
        "calibration: a folder",
        &["--calib", "{dir}"],
        "cannot read",
    ),
    row(
        "calibration: not UTF-8",
        &["--calib", "{dir}/latin1.toml"],
        "latin1.toml: cannot read calibration",
    ),
    row(
        "calibration: malformed TOML",
        &["--calib", "{dir}/syntax.toml"],
        "syntax.toml: malformed TOML",
    ),
    row(
        "calibration: unknown key",
        &["--calib", "{dir}/unknown-key.toml"],
        "unknown field `pixel_pich_um`",
    ),
    row(
        "calibration: unknown key with a 2 MB value",
        &["--calib", "{dir}/long-value.toml"],
        "long-value.toml",
    ),
    row(
        "calibration: over 1 MiB",
        &["--calib", "{dir}/huge.toml"],
        "huge.toml: cannot read calibration: larger than 1 MiB",
    ),
    row(
        "calibration: /dev/zero",
        &["--calib", "/dev/zero"],
        "larger than 1 MiB",
    ),
    row(
        "calibration: missing section",
        &["--calib", "{dir}/no-lens.toml"],
        "missing field `lens`",
    ),
    row(
        "calibration: a number as text",
        &["--calib", "{dir}/text-number.toml"],
        "invalid type: string \"8.7\", expected f64",
    ),
    row(
        "calibration: NaN pitch",
        &["--calib", "{dir}/nan-pitch.toml"],
        "panel.pixel_pitch_um",
    ),
    row(
        "calibration: negative focal length",
        &["--calib", "{dir}/negative-focal.toml"],
        "lens.focal_length_mm",
    ),
    row(
        "calibration: panel past the focal length",
        &["--calib", "{dir}/no-image.toml"],
        "no virtual image",
    ),
    row(
        "calibration: zero-width panel",
        &["--calib", "{dir}/zero-width.toml"],
        "panel.width_px",
    ),
    row(
        "calibration: 100000-pixel-wide panel",
        &["--calib", "{dir}/wide.toml"],
        "panel.width_px",
    ),
    row(
        "calibration: zero refresh rate",
        &["--calib", "{dir}/zero-refresh.toml"],
        "panel.refresh_hz",
    ),
    row(
        "calibration: two gamma values",
        &["--calib", "{dir}/two-gammas.toml"],
        "panel.transfer_gamma",
    ),
    row(
        "calibration: index below 1",
        &["--calib", "{dir}/low-index.toml"],
        "index",
    ),
    row(
        "calibration: design channel not a channel",
        &["--calib", "{dir}/design-channel.toml"],
        "doe.design_channel",
    ),
    row(
        "calibration: depth range reversed",
        &["--calib", "{dir}/reversed-range.toml"],
        "depths.range_d",
    ),
    row(
        "calibration: window energy above 1",
        &["--calib", "{dir}/window-energy.toml"],
        "simulation.window_energy",
    ),
    row(
        "calibration: its DOE file missing",
        &["--calib", "{dir}/missing-doe.toml"],
        "gone.safetensors",
    ),
    // DOE files (with --method doe-only).
    row(
        "DOE: missing file",
        &["--method", "doe-only", "--doe", "{dir}/none.safetensors"],
        "none.safetensors",
    ),
    row(
        "DOE: not safetensors",
        &["--method", "doe-only", "--doe", "{dir}/text.safetensors"],
        "text.safetensors: invalid DOE file: not a safetensors file",
    ),
    row(
        "DOE: header length past the end",
        &[
            "--method",
            "doe-only",
            "--doe",
            "{dir}/long-header.safetensors",
        ],
        "long-header.safetensors: invalid DOE file: not a safetensors file",
    ),
    row(
        "DOE: no metadata",
        &[
            "--method",
            "doe-only",
            "--doe",
            "{dir}/no-metadata.safetensors",
        ],
        "no-metadata.safetensors: invalid DOE file: no metadata",
    ),
    row(
        "DOE: pitch missing",
        &[
            "--method",
            "doe-only",
            "--doe",
            "{dir}/no-pitch.safetensors",
        ],
        "metadata key `pitch_um` is missing",
    ),
    row(
        "DOE: pitch not a number",
        &[
            "--method",
            "doe-only",
            "--doe",
            "{dir}/text-pitch.safetensors",
        ],
        "pitch_um",
    ),
    row(
        "DOE: NaN height",
        &[
            "--method",
            "doe-only",
            "--doe",
            "{dir}/nan-height.safetensors",
        ],
        "nan-height.safetensors",
    ),
    row(
        "DOE: data shorter than its shape",
        &[
            "--method",
            "doe-only",
            "--doe",
            "{dir}/short-data.safetensors",
        ],
        "short-data.safetensors: invalid DOE file",
    ),
    row(
        "DOE: /dev/zero",
        &["--method", "doe-only", "--doe", "/dev/zero"],
        "larger than 512 MiB",
    ),
    row(
        "DOE: a grid too coarse for the aperture",
        &["--method", "doe-only", "--doe", "{dir}/coarse.safetensors"],
        "coarse.safetensors",
    ),
    // Models (with --method proposed).
    row(
        "model: missing file",
        &["--method", "proposed", "--dcnn", "{dir}/none.onnx"],
        "none.onnx",
    ),
    row(
        "model: empty file",
        &["--method", "proposed", "--dcnn", "{dir}/empty.onnx"],
        "empty.onnx: the file is empty",
    ),
    row(
        "model: garbage bytes",
        &["--method", "proposed", "--dcnn", "{dir}/garbage.onnx"],
        "garbage.onnx: not a valid ONNX protobuf",
    ),
    row(
        "model: truncated",
        &["--method", "proposed", "--dcnn", "{dir}/truncated.onnx"],
        "truncated.onnx",
    ),
    row(
        "model: no graph nodes",
        &["--method", "proposed", "--dcnn", "{dir}/no-nodes.onnx"],
        "no-nodes.onnx: no graph nodes",
    ),
    row(
        "model: an operator nedrt does not run",
        &["--method", "proposed", "--dcnn", "{dir}/gelu.onnx"],
        "Gelu",
    ),
    row(
        "model: a weight initializer missing",
        &["--method", "proposed", "--dcnn", "{dir}/no-weight.onnx"],
        "no-weight.onnx",
    ),
    row(
        "model: four input channels",
        &["--method", "proposed", "--dcnn", "{dir}/four-channels.onnx"],
        "four-channels.onnx",
    ),
    // Command lines.
    row(
        "command line: accommodation NaN",
        &["--sim", "--accom", "nan", "--out", "{out}"],
        "--accom",
    ),
    row(
        "command line: accommodation 1e308",
        &["--sim", "--accom", "1e308", "--out", "{out}"],
        "--accom",
    ),
    row(
        "command line: unknown method",
        &["--method", "sharpest"],
        "sharpest",
    ),
    row(
        "command line: unknown design",
        &["--design", "nosuch"],
        "nosuch",
    ),
    row(
        "command line: output format not written",
        &["--sim", "--accom", "1", "--out", "{dir}/out.xyz"],
        "out.xyz",
    ),
    row(
        "command line: output folder missing",
        &["--sim", "--accom", "1", "--out", "{dir}/no/such/out.png"],
        "no/such/out.png",
    ),
    row(
        "command line: negative accommodation",
        &["--sim", "--accom", "-1", "--out", "{out}"],
        "--accom -1: accommodation must be ≥ 0 D",
    ),
    row(
        "command line: display image missing",
        &[
            "--input",
            "{dir}/good.png",
            "--display-image",
            "{dir}/none.png",
        ],
        "none.png: cannot read image: No such file or directory (os error 2)",
    ),
    row(
        "view: image missing",
        &[
            "view",
            "--headless",
            "--screenshot",
            "{out}",
            "--input",
            "{dir}/none.png",
        ],
        "none.png: cannot read image",
    ),
    row(
        "view: unknown method",
        &[
            "view",
            "--headless",
            "--screenshot",
            "{out}",
            "--methods",
            "conventional,holographic",
        ],
        "'holographic'",
    ),
    row(
        "view: --headless without --screenshot",
        &["view", "--headless"],
        "--headless needs --screenshot",
    ),
    row(
        "view: accommodation NaN",
        &[
            "view",
            "--headless",
            "--screenshot",
            "{out}",
            "--accom",
            "nan",
        ],
        "--accom NaN",
    ),
    row(
        "view: screenshot not a PNG",
        &["view", "--headless", "--screenshot", "{out}.jpg"],
        "out.png.jpg: cannot write image: unsupported extension",
    ),
    row(
        "view: crop outside the image",
        &[
            "view",
            "--headless",
            "--screenshot",
            "{out}",
            "--crop",
            "600x10+0+0",
        ],
        "--crop 600x10+0+0: outside data/images/test/astronaut.png (512×512)",
    ),
    row(
        "view: crop malformed",
        &[
            "view",
            "--headless",
            "--screenshot",
            "{out}",
            "--crop",
            "10x10",
        ],
        "expected WxH+X+Y",
    ),
    row(
        "sweep: animation format unknown",
        &["sweep", "--out", "{out}.mp4"],
        "out.png.mp4: cannot write image: unsupported extension",
    ),
    row(
        "sweep: step 0",
        &["sweep", "--step", "0", "--out", "{out}"],
        "the step must be > 0",
    ),
    row(
        "sweep: range reversed",
        &["sweep", "--from", "2", "--to", "1", "--out", "{out}"],
        "the range ascending",
    ),
    row(
        "sweep: negative start",
        &["sweep", "--from", "-0.5", "--out", "{out}"],
        "--from -0.5: accommodation must be ≥ 0 D",
    ),
    row(
        "sweep: GIF faster than 50 fps",
        &["sweep", "--fps", "60", "--out", "{out}.gif"],
        "a GIF plays at most 50 frames a second",
    ),
    row(
        "prefilter: unknown kind",
        &["--prefilter", "wiener"],
        "unknown prefilter \"wiener\"",
    ),
    row(
        "prefilter: refinement of 0 steps",
        &["--prefilter", "refine:0"],
        "the number of steps must be a whole number from 1 to 1000",
    ),
    row(
        "prefilter: objective unknown",
        &["--prefilter", "optimal@blurry"],
        "unknown objective \"blurry\"",
    ),
    row(
        "prefilter command: image folder missing",
        &["prefilter", "--images", "{dir}/none", "--out-dir", "{out}"],
        "none: cannot read folder",
    ),
    row(
        "prefilter command: a D-CNN method without a prefilter",
        &[
            "prefilter",
            "--images",
            "{dir}",
            "--out-dir",
            "{out}",
            "--method",
            "proposed",
            "--prefilter",
            "native",
        ],
        "needs --prefilter lsq, refine:K, admm:K or optimal",
    ),
    row(
        "prefilter command: unclamped output of a prefilter without a clamp to undo",
        &[
            "prefilter",
            "--images",
            "{dir}",
            "--out-dir",
            "{out}",
            "--unclamped",
        ],
        "--unclamped writes a Wiener prefilter's output before the clamp",
    ),
    row(
        "prefilter command: kernel size 0",
        &[
            "prefilter",
            "--images",
            "{dir}",
            "--out-dir",
            "{out}",
            "--operator",
            "0x8",
        ],
        "sides must be integers in 1..=16384",
    ),
    row(
        "view: --screenshot without --headless",
        &["view", "--screenshot", "{out}"],
        "--screenshot FILE needs --headless",
    ),
    row(
        "view: screenshot folder missing",
        &["view", "--screenshot-dir", "{dir}/no-shots"],
        "no-shots: --screenshot-dir: not a folder",
    ),
    row(
        "sweep: fps NaN",
        &["sweep", "--fps", "nan", "--out", "{out}"],
        "--fps NaN",
    ),
    row(
        "run: source rate NaN",
        &[
            "run",
            "--calib",
            "{panel}",
            "--source-rate",
            "nan",
            "--sink",
            "record",
            "--record-dir",
            "{out}",
        ],
        "--source-rate",
    ),
    row(
        "run: two views that overlap",
        &[
            "run",
            "--calib",
            "{dir}/overlapping-views.toml",
            "--sink",
            "record",
            "--record-dir",
            "{out}",
        ],
        "view[1].region_px: overlaps view",
    ),
    row(
        "run: source rate 1e-300 Hz",
        &[
            "run",
            "--calib",
            "{panel}",
            "--source-rate",
            "1e-300",
            "--sink",
            "record",
            "--record-dir",
            "{out}",
        ],
        "--source-rate",
    ),
    row(
        "run: shared-memory folder missing",
        &[
            "run",
            "--calib",
            "{panel}",
            "--source",
            "socket",
            "--socket",
            "{dir}/s.sock",
            "--shm-dir",
            "{dir}/no-shm",
            "--sink",
            "record",
            "--record-dir",
            "{out}",
        ],
        "no-shm: not a folder",
    ),
    row(
        "run: socket path held by a file",
        &[
            "run",
            "--calib",
            "{panel}",
            "--source",
            "socket",
            "--socket",
            "{dir}/good.png",
            "--sink",
            "record",
            "--record-dir",
            "{out}",
        ],
        "exists and is not a socket",
    ),
    row(
        "run: input folder missing",
        &[
            "run",
            "--calib",
            "{panel}",
            "--source",
            "dir",
            "--input",
            "{dir}/no-frames",
            "--sink",
            "record",
            "--record-dir",
            "{out}",
        ],
        "no-frames",
    ),
    row(
        "run: frame of the wrong size",
        &[
            "run",
            "--calib",
            "{panel}",
            "--source",
            "dir",
            "--input",
            "{dir}/good.png",
            "--sink",
            "record",
            "--record-dir",
            "{out}",
        ],
        "good.png: 16×16 image for a 64×48 panel",
    ),
    row(
        "eval: image folder missing",
        &["eval", "--images", "{dir}/no-images", "--out-dir", "{out}"],
        "no-images",
    ),
    row(
        "eval: image folder empty",
        &[
            "eval",
            "--images",
            "{dir}/empty-folder",
            "--out-dir",
            "{out}",
        ],
        "empty-folder",
    ),
    row(
        "bench: a per-layer peak rate that is not positive",
        &[
            "bench",
            "inference",
            "--per-layer",
            "--sizes",
            "32x32",
            "--peak-gmacs",
            "0",
        ],
        "--peak-gmacs 0: must be a positive rate",
    ),
    row(
        "bench: a tensor-core peak rate that is not a number",
        &[
            "bench",
            "inference",
            "--per-layer",
            "--sizes",
            "32x32",
            "--peak-tensor-gmacs",
            "NaN",
        ],
        "--peak-tensor-gmacs NaN: must be a positive rate",
    ),
    row(
        "bench: a pipeline of no frames",
        &["bench", "pipeline", "--frames", "0"],
        "--frames 0 and --max-seconds 120 must be positive",
    ),
    row(
        "run: unknown frame path",
        &[
            "run",
            "--calib",
            "{panel}",
            "--frame-path",
            "gpu",
            "--sink",
            "record",
            "--record-dir",
            "{out}",
        ],
        "invalid value 'gpu' for '--frame-path",
    ),
    row(
        "pick: tradeoff table missing",
        &[
            "pick",
            "--table",
            "{dir}/none.json",
            "--min-psnr",
            "20",
            "--budget-ms",
            "10",
        ],
        "none.json",
    ),
    row(
        "psf --at: accommodation out of range",
        &["psf", "--at", "40", "--out-dir", "{out}"],
        "--at 4e1: beyond what an eye accommodates",
    ),
    row(
        "psf: --method without --at",
        &["psf", "--method", "ai", "--out-dir", "{out}"],
        "required arguments were not provided",
    ),
    row(
        "calib patterns: a margin under 1",
        &["calib", "patterns", "--out", "{out}", "--margin", "0.5"],
        "--margin 0.5: must be at least 1",
    ),
    row(
        "calib patterns: a panel too small for one dot",
        &[
            "--calib",
            "{repo}/tests/data/small-aperture.toml",
            "calib",
            "patterns",
            "--out",
            "{out}",
            "--margin",
            "20",
        ],
        "panel holds no dot",
    ),
    row(
        "calib psfs: no captures manifest",
        &["calib", "psfs", "--captures", "{dir}", "--out", "{out}"],
        "captures.toml: No such file",
    ),
    row(
        "calib synth: an etch scale out of range",
        &[
            "calib",
            "synth",
            "--patterns",
            "{dir}",
            "--out",
            "{out}",
            "--etch",
            "2",
        ],
        "etch_scale = 2: must lie in [0.5, 1.5]",
    ),
    row(
        "calib synth: one level",
        &[
            "calib",
            "synth",
            "--patterns",
            "{dir}",
            "--out",
            "{out}",
            "--levels",
            "1",
        ],
        "levels = 1: must be 0 (continuous) or 2 to 256",
    ),
    row(
        "--psfs: not a bundle",
        &[
            "--psfs", "{dir}", "--sim", "--accom", "1", "--out", "{out}", "--method", "doe-only",
        ],
        "bundle.toml: No such file",
    ),
    row(
        "calib truth: a bandwidth out of range",
        &[
            "calib",
            "truth",
            "--out",
            "{out}",
            "--bandwidths-nm",
            "0,-1,0",
        ],
        "bandwidths_nm = [0.0, -1.0, 0.0]: each must lie in [0, 60] nm (FWHM)",
    ),
    row(
        "calib synth: a decentre of one number",
        &[
            "calib",
            "synth",
            "--patterns",
            "{dir}",
            "--out",
            "{out}",
            "--decentre-mm",
            "0.1",
        ],
        "1 numbers; give 2, comma-separated",
    ),
    row(
        "prefilter --mirror-psfs without --psfs",
        &[
            "prefilter",
            "--images",
            "{dir}",
            "--out-dir",
            "{out}",
            "--mirror-psfs",
        ],
        "give the bundle with --psfs",
    ),
    row(
        "calib psfs: field zones left to auto",
        &[
            "calib",
            "psfs",
            "--captures",
            "{dir}",
            "--out",
            "{out}",
            "--field-zones",
            "auto",
        ],
        "give N or NxM (auto is for the simulator's own zones)",
    ),
    row(
        "calib truth: more field zones than the simulator renders",
        &["calib", "truth", "--out", "{out}", "--field-zones", "9x1"],
        "give N or NxM with 1 ≤ N, M ≤ 8 (e.g. 2 or 2x1)",
    ),
    row(
        "tolerance --replot without a sweep's report",
        &["tolerance", "--replot", "--out", "{out}"],
        "--replot reads the JSON a sweep wrote beside --out",
    ),
    row(
        "bench tune: a tile the conv kernel does not build",
        &["bench", "tune", "--tiles", "12x4"],
        "a conv tile is 8, 16 or 32 pixels wide and 1, 2, 4, 8 or 16 tall",
    ),
    row(
        "bench fft: a workgroup shape the kernels do not take",
        &["bench", "fft", "--fft-variants", "256x3"],
        "not THREADSxPAIRS (threads 32 to 1024, pairs 1, 2, 4 or 8; e.g. 256x4)",
    ),
];

/// Rows that take the small-aperture calibration and the `--sim` arguments
/// unless they name their own command.
fn command_line(r: &Row, dir: &Path, out: &Path) -> Vec<String> {
    let own_command = r.args.iter().any(|a| {
        [
            "--sim",
            "run",
            "eval",
            "pick",
            "view",
            "sweep",
            "prefilter",
            "bench",
            "psf",
            "calib",
            "tolerance",
        ]
        .contains(a)
    });
    let own_calib = r.args.contains(&"--calib");
    let mut args: Vec<String> = Vec::new();
    if !own_calib && !own_command {
        args.extend(["--calib".to_string(), path(&small_calib()).to_string()]);
    }
    let fill = |a: &str| {
        a.replace("{dir}", path(dir))
            .replace("{out}", path(out))
            .replace("{panel}", path(&small_panel()))
            .replace("{repo}", path(&repo()))
    };
    if !own_command {
        args.extend(SIM.iter().map(|a| fill(a)));
    }
    args.extend(r.args.iter().map(|a| fill(a)));
    args
}

fn safetensors(header: &str, data: &[u8]) -> Vec<u8> {
    let mut b = (header.len() as u64).to_le_bytes().to_vec();
    b.extend_from_slice(header.as_bytes());
    b.extend_from_slice(data);
    b
}

/// A 4×4 f32 height map (`values` at its start, the rest 0) with the given
/// metadata (a JSON object's inside), its data cut to `data_len` bytes.
fn doe_file(metadata: &str, values: &[f32], data_len: usize) -> Vec<u8> {
    let header = format!(
        "{{\"__metadata__\":{{{metadata}}},\"height_um\":{{\"dtype\":\"F32\",\"shape\":[4,4],\
         \"data_offsets\":[0,64]}}}}"
    );
    let mut heights = [0f32; 16];
    heights[..values.len()].copy_from_slice(values);
    let data: Vec<u8> = heights.iter().flat_map(|v| v.to_le_bytes()).collect();
    safetensors(&header, &data[..data_len.min(64)])
}

fn float_tiff(path: &Path, x: u32, y: u32, value: [f32; 3]) {
    let mut im = image::Rgb32FImage::from_pixel(16, 16, image::Rgb([0.5, 0.5, 0.5]));
    im.put_pixel(x, y, image::Rgb(value));
    image::DynamicImage::ImageRgb32F(im)
        .save(path)
        .expect("tiff");
}

fn model_file(dir: &Path, name: &str, edit: impl FnOnce(&mut Vec<u8>)) {
    let mut bytes = std::fs::read(dcnn_model()).expect("model");
    edit(&mut bytes);
    std::fs::write(dir.join(name), bytes).expect("write model");
}

/// Every bad file the rows name.
fn prepare(dir: &Path) {
    let w = |name: &str, bytes: &[u8]| std::fs::write(dir.join(name), bytes).expect("write");
    write_png(&dir.join("good.png"), 16, 16);
    write_png(&dir.join("other-size.png"), 24, 16);
    w("empty.png", b"");
    w("text.png", b"this is not an image");
    let png = std::fs::read(dir.join("good.png")).expect("png");
    w("truncated.png", &png[..png.len() / 2]);
    image::RgbaImage::from_pixel(16, 16, image::Rgba([9, 9, 9, 128]))
        .save(dir.join("alpha.png"))
        .expect("alpha");
    write_png(&dir.join("tiny.png"), 1, 1);
    let panel = std::fs::read_to_string(small_panel()).expect("small-panel.toml");
    w(
        "overlapping-views.toml",
        (panel
            + "\n[[view]]\nname = \"left\"\nregion_px = [0, 0, 40, 48]\n\
               \n[[view]]\nname = \"right\"\nregion_px = [32, 0, 32, 48]\n")
            .as_bytes(),
    );
    write_png(&dir.join("line.png"), 30000, 1);
    write_png(&dir.join("wide-photo.png"), 2000, 16);
    // A PNG signature and an IHDR chunk claiming 20000×20000, nothing after.
    let mut claims = b"\x89PNG\r\n\x1a\n\x00\x00\x00\x0dIHDR".to_vec();
    let ihdr = [
        &20000u32.to_be_bytes()[..],
        &20000u32.to_be_bytes(),
        &[8, 2, 0, 0, 0],
    ]
    .concat();
    claims.extend_from_slice(&ihdr);
    let crc = crc32(&[&b"IHDR"[..], &ihdr].concat());
    claims.extend_from_slice(&crc.to_be_bytes());
    // One tiny IDAT (a zlib stream of a few zero bytes) and IEND: the
    // header is complete, the data far too short.
    for (kind, data) in [
        (
            &b"IDAT"[..],
            &[0x78, 0x9c, 0x63, 0x00, 0x00, 0x00, 0x01, 0x00, 0x01][..],
        ),
        (&b"IEND"[..], &[][..]),
    ] {
        claims.extend_from_slice(&(data.len() as u32).to_be_bytes());
        claims.extend_from_slice(kind);
        claims.extend_from_slice(data);
        claims.extend_from_slice(&crc32(&[kind, data].concat()).to_be_bytes());
    }
    w("claims.png", &claims);
    float_tiff(&dir.join("nan.tif"), 3, 4, [f32::NAN, 0.5, 0.5]);
    float_tiff(&dir.join("inf.tif"), 1, 2, [0.5, f32::INFINITY, 0.5]);
    float_tiff(&dir.join("bright.tif"), 0, 0, [0.5, 0.5, 2.0]);
    float_tiff(&dir.join("negative.tif"), 0, 0, [-0.5, 0.5, 0.5]);

    let shipped = std::fs::read_to_string(small_calib()).expect("calib");
    let edit = |name: &str, from: &str, to: &str| {
        assert!(shipped.contains(from), "{from}");
        w(name, shipped.replacen(from, to, 1).as_bytes());
    };
    w("latin1.toml", b"[panel]\npixel_pitch_um = 8.7 # \xb5m\n");
    w("syntax.toml", b"[panel\npixel_pitch_um = 8.7");
    edit("unknown-key.toml", "pixel_pitch_um", "pixel_pich_um");
    w(
        "long-value.toml",
        format!("{shipped}\n[extra]\nnote = \"{}\"\n", "x".repeat(900_000)).as_bytes(),
    );
    w(
        "huge.toml",
        format!("{shipped}\n# {}\n", "y".repeat(2 << 20)).as_bytes(),
    );
    let no_lens: String = {
        let start = shipped.find("[lens]").expect("[lens]");
        let end = shipped.find("[material]").expect("[material]");
        format!("{}{}", &shipped[..start], &shipped[end..])
    };
    w("no-lens.toml", no_lens.as_bytes());
    edit(
        "text-number.toml",
        "pixel_pitch_um = 8.7",
        "pixel_pitch_um = \"8.7\"",
    );
    edit(
        "nan-pitch.toml",
        "pixel_pitch_um = 8.7",
        "pixel_pitch_um = nan",
    );
    edit(
        "negative-focal.toml",
        "focal_length_mm = 30.0",
        "focal_length_mm = -30.0",
    );
    edit(
        "no-image.toml",
        "lens_distance_mm = 28.57",
        "lens_distance_mm = 31",
    );
    edit("zero-width.toml", "width_px = 1920", "width_px = 0");
    edit("wide.toml", "width_px = 1920", "width_px = 100000");
    edit("zero-refresh.toml", "refresh_hz = 90.0", "refresh_hz = 0.0");
    edit(
        "two-gammas.toml",
        "transfer_gamma = [2.2, 2.2, 2.2]",
        "transfer_gamma = [2.2, 2.2]",
    );
    edit("low-index.toml", "index = 1.461", "index = 0.9");
    edit(
        "design-channel.toml",
        "design_channel = \"G\"",
        "design_channel = \"Y\"",
    );
    edit(
        "reversed-range.toml",
        "range_d = [0.0, 3.0]",
        "range_d = [3.0, 0.0]",
    );
    edit(
        "window-energy.toml",
        "window_energy = 0.999",
        "window_energy = 1.5",
    );
    edit(
        "missing-doe.toml",
        "file = \"\"",
        "file = \"gone.safetensors\"",
    );

    w("text.safetensors", b"not a safetensors file at all");
    w(
        "long-header.safetensors",
        &[0xff, 0xff, 0xff, 0xff, 0, 0, 0, 0, b'{', b'}'],
    );
    let meta = "\"format\":\"nedrt-doe\",\"version\":\"1\",\"pitch_um\":\"6\",\
                \"max_height_um\":\"3\",\"design_wavelength_nm\":\"530\",\"levels\":\"0\",\
                \"material\":\"fused silica\"";
    let no_meta = safetensors(
        "{\"height_um\":{\"dtype\":\"F32\",\"shape\":[4,4],\"data_offsets\":[0,64]}}",
        &[0u8; 64],
    );
    w("no-metadata.safetensors", &no_meta);
    w(
        "no-pitch.safetensors",
        &doe_file(&meta.replace("\"pitch_um\":\"6\",", ""), &[], 64),
    );
    w(
        "text-pitch.safetensors",
        &doe_file(
            &meta.replace("\"pitch_um\":\"6\"", "\"pitch_um\":\"six\""),
            &[],
            64,
        ),
    );
    w(
        "nan-height.safetensors",
        &doe_file(meta, &[0.0, f32::NAN], 64),
    );
    w("short-data.safetensors", &doe_file(meta, &[], 32));
    w("coarse.safetensors", &doe_file(meta, &[], 64));

    w("empty.onnx", b"");
    w("garbage.onnx", &[0xff; 64]);
    model_file(dir, "truncated.onnx", |b| b.truncate(b.len() / 3));
    let mut proto = nedrt_infer::synth::unet(2, 2, 1);
    let graph = proto.graph.as_mut().expect("graph");
    graph.node.clear();
    w("no-nodes.onnx", &nedrt_infer::synth::encode(&proto));
    let mut proto = nedrt_infer::synth::unet(2, 2, 1);
    let graph = proto.graph.as_mut().expect("graph");
    graph.node[1].op_type = "Gelu".into();
    w("gelu.onnx", &nedrt_infer::synth::encode(&proto));
    let mut proto = nedrt_infer::synth::unet(2, 2, 1);
    let graph = proto.graph.as_mut().expect("graph");
    graph.initializer.remove(0);
    w("no-weight.onnx", &nedrt_infer::synth::encode(&proto));
    let mut proto = nedrt_infer::synth::unet(2, 2, 1);
    let graph = proto.graph.as_mut().expect("graph");
    let input_dims = graph.input[0]
        .r#type
        .as_mut()
        .and_then(|t| t.value.as_mut());
    use nedrt_infer::synth::pb::{tensor_shape_proto::dimension, type_proto};
    if let Some(type_proto::Value::TensorType(t)) = input_dims
        && let Some(shape) = t.shape.as_mut()
    {
        shape.dim[1].value = Some(dimension::Value::DimValue(4));
    }
    w("four-channels.onnx", &nedrt_infer::synth::encode(&proto));

    std::fs::create_dir_all(dir.join("empty-folder")).expect("mkdir");
}

/// CRC-32 (ISO-HDLC) of a PNG chunk's type and data.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xffff_ffffu32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xedb8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// Files under `dir`, recursively.
fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                out.extend(files_under(&p));
            } else {
                out.push(p);
            }
        }
    }
    out
}

#[test]
fn every_row_of_the_bad_input_catalogue_is_a_clean_error_with_nothing_written() {
    let inputs = tempfile::tempdir().expect("tempdir");
    prepare(inputs.path());
    let reliability =
        std::fs::read_to_string(repo().join("docs/reliability.md")).expect("docs/reliability.md");
    let mut failures = Vec::new();
    // A row that has not ended by then is killed and reported (one that
    // waits on its input, a FIFO, would never end). Most end at once; a few
    // load the network first, which in a debug build beside the suite's
    // other tests took over 120 s ("output folder missing").
    let limit = Duration::from_secs(if cfg!(debug_assertions) { 600 } else { 120 });
    for r in ROWS {
        let scratch = tempfile::tempdir().expect("tempdir");
        let out = scratch.path().join("out.png");
        let args = command_line(r, inputs.path(), &out);
        let o = match nedrt()
            .current_dir(repo())
            .args(&args)
            .try_output_within(limit, r.name)
        {
            Ok(o) => o,
            Err(o) => {
                failures.push(format!(
                    "{}: still running after {limit:?} (killed); stderr {}",
                    r.name,
                    nedrt_core::util::bounded(&stderr(&o), 600)
                ));
                continue;
            }
        };
        let err = stderr(&o);
        let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
        // No cause quoted twice ("…: No such file: No such file").
        let repeated = lines.first().is_some_and(|l| {
            let parts: Vec<&str> = l.split(": ").collect();
            parts.windows(2).any(|w| w[0] == w[1])
        });
        let ok = !o.status.success()
            && !repeated
            && !err.contains("panicked")
            && lines.len() == 1
            && lines[0].contains(r.needle)
            && lines[0].len() < 2000
            && files_under(scratch.path()).is_empty();
        if !ok {
            failures.push(format!(
                "{}: exit {:?}, written {:?}, stderr {}",
                r.name,
                o.status.code(),
                files_under(scratch.path()),
                nedrt_core::util::bounded(&err, 600)
            ));
        }
        if !reliability.contains(r.name) {
            failures.push(format!("{}: not listed in docs/reliability.md", r.name));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Protocol rows: a hello or frame header and the reason the service
/// gives, from the functions the socket source runs on every message.
#[test]
fn every_bad_protocol_message_is_refused_with_its_reason() {
    let panel = (64usize, 48usize);
    let good = FrameHeader::new(PixelFormat::Rgba8Linear, 64, 48, 7, 0);
    let shm = (64 * 48 * 4) as u64;
    let hello = |f: fn(&mut [u8; HELLO_LEN])| {
        let mut b = Hello {
            name_len: 8,
            shm_size: shm,
        }
        .to_bytes();
        f(&mut b);
        Hello::parse(&b).expect_err("refused").to_string()
    };
    let header = |f: fn(&mut FrameHeader)| {
        let mut h = good;
        f(&mut h);
        admit(&h.to_bytes(), panel, shm)
            .expect_err("refused")
            .to_string()
    };
    let mut rows: Vec<(&str, String, &str)> = vec![
        (
            "protocol: hello with a bad magic",
            hello(|b| b[0] = b'X'),
            "bad hello (magic",
        ),
        (
            "protocol: hello of another version",
            hello(|b| b[4] = 9),
            "version 9",
        ),
        (
            "protocol: hello with an empty name",
            hello(|b| b[6..8].fill(0)),
            "shared-memory name of 0 bytes",
        ),
        (
            "protocol: hello with a 300-byte name",
            hello(|b| b[6..8].copy_from_slice(&300u16.to_le_bytes())),
            "shared-memory name of 300 bytes",
        ),
        (
            "protocol: header with a bad magic",
            {
                let mut b = good.to_bytes();
                b[0] = b'X';
                admit(&b, panel, shm).expect_err("refused").to_string()
            },
            "malformed",
        ),
        (
            "protocol: header of another version",
            header(|h| h.version = 2),
            "protocol version 2",
        ),
        (
            "protocol: unknown pixel format",
            header(|h| h.format = 77),
            "pixel format 77",
        ),
        (
            "protocol: frame of the wrong size",
            header(|h| h.width = 65),
            "65×48 frame for a 64×48 panel",
        ),
        (
            "protocol: payload length mismatch",
            header(|h| h.length -= 1),
            "12287 payload bytes, 12288 needed",
        ),
        (
            "protocol: offset + length overflows",
            header(|h| h.offset = u64::MAX),
            "lies outside the 12288-byte shared memory",
        ),
        (
            "protocol: payload past the shared memory",
            header(|h| h.offset = 1),
            "payload at 1+12288 lies outside",
        ),
    ];
    rows.extend(version_2_rows(panel, shm));
    let reliability =
        std::fs::read_to_string(repo().join("docs/reliability.md")).expect("docs/reliability.md");
    for (name, got, needle) in &rows {
        assert!(got.contains(needle), "{name}: {got:?} lacks {needle:?}");
        assert!(
            reliability.contains(name),
            "{name}: not listed in docs/reliability.md"
        );
    }
    for name in ["../etc/passwd", "a/b", ".hidden", "", "sp ace"] {
        assert!(
            !valid_shm_name(name),
            "{name:?} accepted as a shared-memory name"
        );
    }
    assert!(
        ROWS.len() + rows.len() >= 60,
        "{} rows",
        ROWS.len() + rows.len()
    );
}

/// Protocol version 2 rows: a submission header the service's version 2
/// check refuses, or a quad the compositor refuses.
fn version_2_rows(panel: (usize, usize), shm: u64) -> Vec<(&'static str, String, &'static str)> {
    use nedrt_protocol::v2::{HeaderV2, QuadFormat};
    use nedrt_service::compose::{Placement, QuadLayer, ViewGeometry};
    let quad = HeaderV2::quad(
        0,
        4,
        0,
        Placement::Pixels { x: 0, y: 0 },
        QuadFormat::Rgba8Premultiplied,
        (8, 6),
        7,
        0,
    );
    let admit_v2 = |h: HeaderV2, patch: fn(&mut [u8; 72])| {
        let mut b = h.to_bytes();
        patch(&mut b);
        v2::admit(&b, panel, &[panel], shm)
            .expect_err("refused")
            .to_string()
    };
    let view = ViewGeometry {
        width: panel.0,
        height: panel.1,
        pixels_per_tan: 4597.7,
    };
    let place = |x: i64, c: f32, a: f32| {
        QuadLayer {
            layer: 4,
            z: 0,
            placement: Placement::Pixels { x, y: 0 },
            width: 8,
            height: 6,
            rgba: [c, c, c, a].repeat(48),
        }
        .place(&view)
        .expect_err("refused")
        .to_string()
    };
    vec![
        (
            "protocol v2: unknown layer kind",
            admit_v2(quad, |b| b[48] = 3),
            "layer kind 3",
        ),
        (
            "protocol v2: projection for a view the service does not run",
            admit_v2(
                HeaderV2::projection(1, PixelFormat::Rgba8Linear, panel, 7, 0),
                |_| {},
            ),
            "view 1 (this service runs 1 view",
        ),
        (
            "protocol v2: quad larger than its view",
            admit_v2(quad, |b| b[8..12].copy_from_slice(&65u32.to_le_bytes())),
            "a 65×6 quad on a 64×48 view",
        ),
        (
            "protocol v2: unknown quad texel format",
            admit_v2(quad, |b| b[6..8].copy_from_slice(&9u16.to_le_bytes())),
            "texel format 9",
        ),
        (
            "protocol v2: placement in degrees that is not finite",
            admit_v2(quad, |b| {
                b[50] = 1;
                b[60..64].copy_from_slice(&f32::INFINITY.to_le_bytes());
            }),
            "is not finite",
        ),
        (
            "protocol v2: quad outside the view",
            place(60, 0.1, 0.5),
            "is not inside the 64×48 view",
        ),
        (
            "protocol v2: quad colour over its alpha",
            place(0, 0.6, 0.5),
            "premultiplied colour is at most its alpha",
        ),
    ]
}
