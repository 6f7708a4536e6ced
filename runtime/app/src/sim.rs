//! `nedrt --sim`: the perceived image at one accommodation, written to a
//! file and scored against the sharp image and the multifocal target.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use super::{AppError, CommonOptions};
use nedrt_core::image_io::{self, DEFAULT_INPUT_NAME, DEFAULT_INPUT_PNG, LoadedImage};
use nedrt_optics::sim::{Method, Optics, ZoneRequest};
use nedrt_stages::preprocess::Prefilter;

/// Options of `nedrt --sim`.
#[derive(Debug, Clone)]
pub struct SimOptions {
    pub accommodation_d: f64,
    /// Input image; `None` = the shipped test image.
    pub input: Option<PathBuf>,
    pub method: Method,
    pub out: PathBuf,
    /// Simulate this display image instead of a method's preprocessing.
    pub display_image: Option<PathBuf>,
    /// Optics for `display_image`.
    pub optics: Optics,
    /// Also write the display frame (what the panel shows) here: `.png`
    /// 16-bit or `.tif` 32-bit float.
    pub display_out: Option<PathBuf>,
    /// How the display image is made from the input (not with `display_image`).
    pub prefilter: Prefilter,
    /// Zones of field angle for the perceived image and the target.
    pub zones: ZoneRequest,
    /// Also score every method at this accommodation, one table (the
    /// first run's "how does this compare").
    pub compare: bool,
}

impl SimOptions {
    /// The shipped system: the D-CNN co-designed with its DOE (`proposed`)
    /// where its model is here, else the design's DOE with its Wiener.
    pub fn shipped_method(common: &CommonOptions) -> Method {
        if common.dcnn.path.is_file() {
            Method::Proposed
        } else {
            Method::DoeWiener
        }
    }
}

/// What `--out` and `--display-out` write: 16-bit PNG, or 32-bit float TIFF (exact).
const DISPLAY_OUT_FORMATS: &[&str] = &["png", "tif", "tiff"];

pub use crate::frames::Score;

/// Everything `nedrt --sim` reports.
#[derive(Debug, Clone)]
pub struct SimReport {
    pub text: String,
    pub vs_sharp: Score,
    pub vs_target: Score,
}

impl std::fmt::Display for SimReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.text)
    }
}

pub fn load_input(
    input: Option<&std::path::Path>,
    panel: (usize, usize),
) -> Result<(LoadedImage, String), AppError> {
    Ok(match input {
        Some(p) => (image_io::load_for_panel(p, panel)?, p.display().to_string()),
        None => (
            image_io::decode_for_panel(DEFAULT_INPUT_PNG, DEFAULT_INPUT_NAME, panel)?,
            DEFAULT_INPUT_NAME.to_string(),
        ),
    })
}

/// Runs one simulation. Warnings (accommodation range, conversions) are
/// logged through `tracing` as they arise.
/// The perceived image of `opts.method`, written to `opts.out`, scored;
/// with `opts.compare`, a table of every method at the same accommodation
/// follows (each scored as `nedrt sim --method M` would, nothing written).
pub fn run(common: &CommonOptions, opts: &SimOptions) -> Result<SimReport, AppError> {
    let mut report = simulate(common, opts, true)?;
    if opts.compare && opts.display_image.is_none() {
        report.text = format!(
            "{}

{}",
            report.text,
            compare(common, opts, &report)?
        );
    }
    Ok(report)
}

/// Every method at `opts.accommodation_d` on the same input: PSNR and SSIM
/// vs sharp and vs target, the best of each column marked.
fn compare(
    common: &CommonOptions,
    opts: &SimOptions,
    main: &SimReport,
) -> Result<String, AppError> {
    // One eyepiece for every row, as `nedrt eval` has it: the D-CNN's DOE
    // where it is here, so doe-only and doe+wiener are its ablations.
    // Its Wiener K is that of the shipped design made on the same DOE
    // (the calibration's K belongs to its own DOE).
    let mut common = common.clone();
    common.doe = common.doe_path_for(&Method::ALL);
    if common.design.is_none()
        && let Some(doe) = &common.doe
    {
        let calib = common.calibration()?;
        let hash =
            |p: &std::path::Path| nedrt_optics::doe_file::load(p, &calib).map(|d| d.content_hash());
        let ours = hash(doe)?;
        for d in crate::design::Design::shipped()? {
            if hash(&d.doe).is_ok_and(|h| h == ours) {
                common.design = Some(d);
                break;
            }
        }
    }
    let common = &common;
    let mut rows: Vec<(String, Option<(Score, Score)>)> = Vec::new();
    for m in Method::ALL {
        if m == opts.method {
            rows.push((m.name().to_string(), Some((main.vs_sharp, main.vs_target))));
            continue;
        }
        let model = match m {
            Method::LensDcnn => Some(&common.dcnn.lens_path),
            Method::Proposed => Some(&common.dcnn.path),
            _ => None,
        };
        if let Some(path) = model.filter(|p| !p.is_file()) {
            rows.push((format!("{} (no {})", m.name(), path.display()), None));
            continue;
        }
        let o = SimOptions {
            method: m,
            compare: false,
            display_out: None,
            ..opts.clone()
        };
        let r = simulate(common, &o, false)?;
        rows.push((m.name().to_string(), Some((r.vs_sharp, r.vs_target))));
    }
    let best = |pick: &dyn Fn(&(Score, Score)) -> f64| {
        rows.iter()
            .filter_map(|(_, s)| s.as_ref().map(pick))
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let best_sharp = best(&|s| s.0.psnr_db);
    let best_target = best(&|s| s.1.psnr_db);
    let eyepiece = match (&common.design, &common.doe) {
        (Some(d), _) => format!("; the DOE rows through the {} design", d.name),
        (None, Some(p)) => format!("; the DOE rows through {}", p.display()),
        (None, None) => String::new(),
    };
    let mut t = format!(
        "Every method at {} D on this input (PSNR dB / SSIM; ◀ the best PSNR of a column{eyepiece}; \
         `nedrt sim --method M` for one):\n\n\
         | method | vs sharp | vs target |\n| --- | --- | --- |\n",
        opts.accommodation_d
    );
    for (name, s) in &rows {
        match s {
            Some((sharp, target)) => {
                let mark = |v: f64, b: f64| if v >= b { " ◀" } else { "" };
                let _ = writeln!(
                    t,
                    "| {name}{} | {:.2} / {:.4}{} | {:.2} / {:.4}{} |",
                    if name == opts.method.name() {
                        " (shown)"
                    } else {
                        ""
                    },
                    sharp.psnr_db,
                    sharp.ssim,
                    mark(sharp.psnr_db, best_sharp),
                    target.psnr_db,
                    target.ssim,
                    mark(target.psnr_db, best_target)
                );
            }
            None => {
                let _ = writeln!(t, "| {name} | – | – |");
            }
        }
    }
    Ok(t.trim_end().to_string())
}

fn simulate(
    common: &CommonOptions,
    opts: &SimOptions,
    write_files: bool,
) -> Result<SimReport, AppError> {
    let start = Instant::now();
    let calib = common.calibration()?;
    let panel = (calib.panel.width_px, calib.panel.height_px);
    let (loaded, input_name) = load_input(opts.input.as_deref(), panel)?;
    for n in &loaded.notes {
        tracing::warn!("{n}");
    }
    image_io::check_extension(&opts.out, DISPLAY_OUT_FORMATS)?;
    if let Some(p) = &opts.display_out {
        image_io::check_extension(p, DISPLAY_OUT_FORMATS)?;
    }
    let input = loaded.image;
    let display_loaded = match &opts.display_image {
        Some(p) => {
            let l = image_io::load_for_panel(p, panel)?;
            for n in &l.notes {
                tracing::warn!("{n}");
            }
            Some(l.image)
        }
        None => None,
    };
    let display_name = opts
        .display_image
        .as_ref()
        .map_or(String::new(), |p| p.display().to_string());
    let frame = crate::frames::simulate(
        common,
        &crate::frames::FrameRequest {
            input: &input,
            input_name: &input_name,
            display_name: &display_name,
            display: display_loaded.as_ref(),
            optics: opts.optics,
            accommodation_d: opts.accommodation_d,
            accommodation_name: "--accom",
            method: opts.method,
            prefilter: opts.prefilter,
            zones: opts.zones,
        },
    )?;
    let (perceived, display, sim) = (&frame.perceived, &frame.display, &frame.sim);
    let (rw, rh) = (frame.sharp.width, frame.sharp.height);
    if write_files {
        image_io::save(perceived, &opts.out, DISPLAY_OUT_FORMATS)?;
        if let Some(p) = &opts.display_out {
            image_io::save(display, p, DISPLAY_OUT_FORMATS)?;
        }
    }
    let (vs_sharp, vs_target) = (frame.vs_sharp, frame.vs_target);
    let method = match display_loaded {
        Some(_) => Method::unprocessed(opts.optics),
        None => opts.method,
    };

    let c = &sim.calib;
    let mut t = String::new();
    let what = match &opts.display_image {
        Some(p) => format!(
            "display image {} through {}",
            p.display(),
            if opts.optics == Optics::Doe {
                "lens + DOE"
            } else {
                "lens"
            }
        ),
        None => format!("method {}", opts.prefilter.label(method.name())),
    };
    let _ = writeln!(
        t,
        "nedrt sim: {what} at {} D ({})",
        opts.accommodation_d, c.source
    );
    if method.optics() == Optics::Doe {
        let _ = writeln!(t, "DOE       {} ({})", sim.doe_hash, sim.doe.description);
    }
    if let Some(line) = &frame.network_line {
        let _ = writeln!(t, "{line}");
    }
    // The prefilter, and where it ran (the CPU, or the device with --backend wgpu).
    if let Some(e) = &frame.engine_line {
        let _ = writeln!(t, "display   {e}");
    }
    let _ = writeln!(
        t,
        "input     {input_name} ({}×{})",
        input.width, input.height
    );
    let _ = writeln!(
        t,
        "wrote     {} ({}×{}, retinal grid {:.3} arcmin, {})",
        opts.out.display(),
        rw,
        rh,
        c.retinal_step_rad().to_degrees() * 60.0,
        if image_io::check_extension(&opts.out, &["png"]).is_ok() {
            "16-bit PNG"
        } else {
            "32-bit float TIFF"
        }
    );
    let target_kind = if c.is_main_depth(opts.accommodation_d) {
        "sharp input: a main depth"
    } else {
        "input blurred by h_b: not a main depth"
    };
    let _ = writeln!(
        t,
        "vs sharp  PSNR {:6.2} dB  SSIM {:.4}",
        vs_sharp.psnr_db, vs_sharp.ssim
    );
    let _ = writeln!(
        t,
        "vs target PSNR {:6.2} dB  SSIM {:.4}  (target: {target_kind})",
        vs_target.psnr_db, vs_target.ssim
    );
    let _ = writeln!(t, "eye       {}", c.eye_summary());
    if let Some(z) = &frame.zones_line {
        let _ = writeln!(t, "zones     {z}");
    }
    for (name, r) in &frame.models {
        let _ = writeln!(t, "model     {name}: {r}");
    }
    let _ = write!(t, "time      {:.2} s", start.elapsed().as_secs_f64());
    Ok(SimReport {
        text: t,
        vs_sharp,
        vs_target,
    })
}
