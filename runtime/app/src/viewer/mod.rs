//! `nedrt view` and `nedrt sweep`: what the eye sees through each method as
//! it focuses from far to near. The viewer is a window whose accommodation
//! follows the wheel, the arrow keys or a slider; a sweep renders the same
//! side-by-side picture over a range of accommodations into an animated
//! file. Both show one [`scene::FocusScene`] through [`compose::compose`].

pub mod animation;
pub mod compose;
pub mod scene;
pub mod window;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use nedrt_core::calib::Calibration;
use nedrt_optics::sim::{Image, Method};
use nedrt_service::present::window::WindowOptions;

use crate::{AppError, CommonOptions};
use compose::{Layout, Picture};
pub use scene::Panel;
use scene::{FocusScene, Shown};

/// The viewer's grid step: PSFs for every 0.05 D of the calibrated range.
pub const VIEW_STEP_D: f64 = 0.05;

/// The PSF depths for showing `depths_d`: the viewer's grid when they all
/// lie on it (the viewer, and sweeps in steps of 0.05 D, 0.1 D, …, then share
/// one cached request and show identical pictures), else `depths_d`.
fn psf_depths(calib: &Calibration, depths_d: &[f64]) -> Vec<f64> {
    let [lo, hi] = calib.range_d;
    // A calibrated range too long for the grid: the depths asked for alone.
    let Ok(grid) = depth_grid(lo, hi, VIEW_STEP_D) else {
        return depths_d.to_vec();
    };
    let on_grid = depths_d
        .iter()
        .all(|d| grid.iter().any(|g| (g - d).abs() < 1e-9));
    if on_grid { grid } else { depths_d.to_vec() }
}

/// Most accommodations one scene prepares (each is a PSF per channel and optics).
const MAX_DEPTHS: usize = 601;

/// `from`, `from + step`, … up to `to` (inclusive within 1e-9 D), rounded
/// to 1e-12 D so that 15 × 0.1 is the 1.5 D of the calibration's lists.
pub fn depth_grid(from_d: f64, to_d: f64, step_d: f64) -> Result<Vec<f64>, AppError> {
    let grid = || format!("accommodations {from_d}..{to_d} step {step_d}");
    if !(from_d.is_finite() && to_d.is_finite() && step_d.is_finite()) {
        return Err(AppError::option(grid(), "not numbers of diopters"));
    }
    if step_d <= 0.0 || to_d < from_d {
        return Err(AppError::option(
            grid(),
            "the step must be > 0 and the range ascending",
        ));
    }
    // Counted in floating point first: a tiny step makes the count overflow.
    let steps = ((to_d - from_d) / step_d + 1e-9).floor();
    if steps.is_nan() || steps >= MAX_DEPTHS as f64 {
        return Err(AppError::option(
            grid(),
            format!(
                "{} depths, at most {MAX_DEPTHS}; take a larger step",
                steps + 1.0
            ),
        ));
    }
    let n = steps as usize + 1;
    Ok((0..n)
        .map(|i| ((from_d + i as f64 * step_d) * 1e12).round() / 1e12)
        .collect())
}

/// A region of the input: `width`×`height` pixels at (`x`, `y`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Crop {
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

/// The input and the methods a view or a sweep shows.
#[derive(Debug, Clone)]
pub struct SceneSource {
    /// Input image; `None` = the shipped test image.
    pub input: Option<PathBuf>,
    /// Only this region of the input.
    pub crop: Option<Crop>,
    /// The panels side by side: methods, or frame-budget levels.
    pub panels: Vec<Panel>,
}

/// How `nedrt view` shows its scene.
#[derive(Debug, Clone)]
pub struct ViewOptions {
    /// Step of the accommodation grid over the calibrated range.
    pub step_d: f64,
    /// Where the eye focuses first.
    pub accommodation_d: f64,
    pub shown: Shown,
    /// Render one picture to `screenshot` and open no window.
    pub headless: bool,
    /// Headless: the picture's file (PNG). In the window, key `c` saves
    /// into `screenshot_dir` instead.
    pub screenshot: Option<PathBuf>,
    pub screenshot_dir: PathBuf,
    /// The largest window; a larger picture is drawn scaled down into it.
    pub max_window: (u32, u32),
    pub window: WindowOptions,
}

/// `nedrt sweep`: the picture over a range of accommodations.
#[derive(Debug, Clone)]
pub struct SweepOptions {
    pub from_d: f64,
    pub to_d: f64,
    pub step_d: f64,
    pub fps: f64,
    /// `.png`/`.apng` (animated PNG) or `.gif`.
    pub out: PathBuf,
}

fn load_scene(
    common: &CommonOptions,
    calib: &Calibration,
    source: &SceneSource,
    depths_d: &[f64],
) -> Result<FocusScene, AppError> {
    let panel = (calib.panel.width_px, calib.panel.height_px);
    let (loaded, name) = crate::sim::load_input(source.input.as_deref(), panel)?;
    for n in &loaded.notes {
        tracing::warn!("{n}");
    }
    let image = match source.crop {
        Some(c) => crop_image(&loaded.image, c, &name)?,
        None => loaded.image,
    };
    scene_of(common, calib, image, name, &source.panels, depths_d)
}

fn crop_image(image: &Image, c: Crop, name: &str) -> Result<Image, AppError> {
    let fits = c.x.checked_add(c.width).is_some_and(|r| r <= image.width)
        && c.y.checked_add(c.height).is_some_and(|b| b <= image.height);
    if !fits {
        return Err(AppError::option(
            format!("--crop {}x{}+{}+{}", c.width, c.height, c.x, c.y),
            format!("outside {name} ({}×{})", image.width, image.height),
        ));
    }
    Ok(image.crop(c.x, c.y, c.width, c.height))
}

fn scene_of(
    common: &CommonOptions,
    calib: &Calibration,
    image: Image,
    name: String,
    panels: &[Panel],
    depths_d: &[f64],
) -> Result<FocusScene, AppError> {
    if image.width < 8 || image.height < 8 {
        return Err(AppError::input(
            &name,
            format!("{}×{} pixels, smaller than 8×8", image.width, image.height),
        ));
    }
    let short = Path::new(&name)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or(name);
    let psf_depths_d = psf_depths(calib, depths_d);
    FocusScene::new(common, calib, image, short, panels, depths_d, &psf_depths_d)
}

/// The picture of a scene at grid depth `depth`.
pub fn picture_at(
    scene: &FocusScene,
    layout: &Layout,
    depth: usize,
    shown: Shown,
) -> Result<Picture, AppError> {
    let rendered = scene.render_all(depth)?;
    compose::compose(scene, layout, depth, shown, &rendered)
}

/// Writes a picture as an 8-bit PNG, atomically.
pub fn save_picture(picture: &Picture, path: &Path) -> Result<(), AppError> {
    use image::ImageEncoder as _;
    nedrt_core::image_io::check_extension(path, &["png"])?;
    let mut bytes = Vec::new();
    image::codecs::png::PngEncoder::new(&mut bytes)
        .write_image(
            &picture.rgb8,
            picture.width as u32,
            picture.height as u32,
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| AppError::output(path, e))?;
    nedrt_core::util::write_atomic(path, &bytes).map_err(|e| AppError::output(path, e))
}

/// `nedrt view`: the window, or with `headless` one picture to a file.
pub fn view(
    common: &CommonOptions,
    source: &SceneSource,
    opts: &ViewOptions,
) -> Result<String, AppError> {
    let calib = common.calibration()?;
    let [lo, hi] = calib.range_d;
    // Headless: the file the picture goes to. In the window: none.
    let headless_out = match (opts.headless, &opts.screenshot) {
        (true, Some(p)) => {
            nedrt_core::image_io::check_extension(p, &["png"])?;
            Some(p.as_path())
        }
        (true, None) => {
            return Err(AppError::Conflict(
                "--headless needs --screenshot FILE.png (the picture it renders)".into(),
            ));
        }
        (false, Some(_)) => {
            return Err(AppError::Conflict(
                "--screenshot FILE needs --headless (in the window, key c saves into --screenshot-dir)"
                    .into(),
            ));
        }
        (false, None) => None,
    };
    crate::check_accommodation(&calib, opts.accommodation_d)?;
    if headless_out.is_none() && !opts.screenshot_dir.is_dir() {
        return Err(AppError::output(
            &opts.screenshot_dir,
            "--screenshot-dir: not a folder",
        ));
    }
    let depths = depth_grid(lo, hi, opts.step_d)?;
    let start = Instant::now();
    let scene = load_scene(common, &calib, source, &depths)?;
    let prepared_s = start.elapsed().as_secs_f64();
    let depth = scene.nearest_depth(opts.accommodation_d);
    let mut text = String::new();
    let _ = writeln!(
        text,
        "nedrt view: {} through {} at {} accommodations ({lo}–{hi} D, step {} D); prepared in {prepared_s:.1} s",
        scene.input_name,
        scene.labels.join(", "),
        scene.depths_d.len(),
        opts.step_d
    );
    for line in scene.psf_reports() {
        let _ = writeln!(text, "{line}");
    }
    if let Some(path) = headless_out {
        let layout = Layout::of(&scene, false);
        let picture = picture_at(&scene, &layout, depth, opts.shown)?;
        save_picture(&picture, path)?;
        let _ = writeln!(
            text,
            "wrote {} ({}×{}, {} at {:.2} D)",
            path.display(),
            picture.width,
            picture.height,
            opts.shown.label(),
            scene.depths_d[depth]
        );
        return Ok(text);
    }
    let summary = window::interactive(&scene, opts, depth)?;
    let _ = write!(text, "{summary}");
    Ok(text)
}

/// `nedrt sweep`: renders the picture at every accommodation of the range
/// and writes the animation.
pub fn sweep(
    common: &CommonOptions,
    source: &SceneSource,
    opts: &SweepOptions,
) -> Result<String, AppError> {
    animation::check_request(&opts.out, opts.fps)?;
    let calib = common.calibration()?;
    check_range(&calib, opts)?;
    let depths = depth_grid(opts.from_d, opts.to_d, opts.step_d)?;
    let scene = load_scene(common, &calib, source, &depths)?;
    sweep_scene(common, &scene, opts)
}

/// `--from` and `--to` as accommodations, named in the errors.
fn check_range(calib: &Calibration, opts: &SweepOptions) -> Result<(), AppError> {
    for (flag, d) in [("--from", opts.from_d), ("--to", opts.to_d)] {
        match crate::check_accommodation(calib, d) {
            Err(AppError::Option { option, reason }) => {
                return Err(AppError::Option {
                    option: option.replacen("--accom", flag, 1),
                    reason,
                });
            }
            Err(e) => return Err(e),
            Ok(_) => {}
        }
    }
    Ok(())
}

/// The most bytes a sweep's frames may take before they are encoded.
const MAX_SWEEP_BYTES: usize = 4 << 30;

/// The sweep of an already loaded image (`nedrt eval --sweeps`).
pub fn sweep_image(
    common: &CommonOptions,
    calib: &Calibration,
    image: Image,
    name: String,
    methods: &[Method],
    opts: &SweepOptions,
) -> Result<String, AppError> {
    animation::check_request(&opts.out, opts.fps)?;
    let depths = depth_grid(opts.from_d, opts.to_d, opts.step_d)?;
    let panels: Vec<Panel> = methods.iter().map(|&m| Panel::of(m)).collect();
    let scene = scene_of(common, calib, image, name, &panels, &depths)?;
    sweep_scene(common, &scene, opts)
}

fn sweep_scene(
    common: &CommonOptions,
    scene: &FocusScene,
    opts: &SweepOptions,
) -> Result<String, AppError> {
    let layout = Layout::of(scene, false);
    let bytes = 3 * layout.width * layout.height * scene.depths_d.len();
    if bytes > MAX_SWEEP_BYTES {
        return Err(AppError::output(
            &opts.out,
            format!(
                "{} frames of {}×{} are {:.1} GB, more than the {} GB a sweep holds; take a larger --step, \
             fewer --methods or a --crop",
                scene.depths_d.len(),
                layout.width,
                layout.height,
                bytes as f64 / 1e9,
                MAX_SWEEP_BYTES >> 30
            ),
        ));
    }
    let progress = common.progress();
    progress.start("sweep frames", scene.depths_d.len() as u64);
    let start = Instant::now();
    let mut frames = Vec::with_capacity(scene.depths_d.len());
    for depth in 0..scene.depths_d.len() {
        frames.push(picture_at(scene, &layout, depth, Shown::Perceived)?);
        progress.advance(1);
    }
    progress.finish();
    let render_s = start.elapsed().as_secs_f64();
    animation::write(&opts.out, &frames, opts.fps)?;
    let perceived = frames.len() * scene.methods.len();
    let bytes = std::fs::metadata(&opts.out).map(|m| m.len()).unwrap_or(0);
    let reports: String = scene
        .psf_reports()
        .iter()
        .map(|l| format!("{l}\n"))
        .collect();
    Ok(format!(
        "nedrt sweep: {} through {}, {} frames ({:.2}–{:.2} D, step {} D) at {} fps\n\
         wrote {} ({}×{}, {:.1} MB)\n\
         rendered {perceived} perceived images ({}×{}) in {render_s:.2} s: {:.1} a second on {} threads\n\
         {reports}",
        scene.input_name,
        scene.labels.join(", "),
        frames.len(),
        scene.depths_d[0],
        scene.depths_d[scene.depths_d.len() - 1],
        opts.step_d,
        opts.fps,
        opts.out.display(),
        layout.width,
        layout.height,
        bytes as f64 / 1e6,
        scene.width,
        scene.height,
        perceived as f64 / render_s.max(1e-9),
        rayon::current_num_threads()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_holds_the_listed_depths_exactly() {
        let g = depth_grid(0.0, 3.0, 0.05).expect("grid");
        assert_eq!(g.len(), 61);
        assert!(g.contains(&0.5) && g.contains(&1.5) && g.contains(&2.5));
        assert_eq!(g[60], 3.0);
        assert_eq!(depth_grid(1.0, 1.0, 0.1).expect("one"), vec![1.0]);
    }

    #[test]
    fn bad_grids_are_refused_with_the_reason() {
        for (a, b, s) in [
            (0.0, 3.0, 0.0),
            (2.0, 1.0, 0.1),
            (0.0, f64::NAN, 0.1),
            (0.0, 3.0, 1e-4),
            // A count past usize: refused, not wrapped.
            (0.0, 3.0, 5e-324),
            (0.0, 1e300, 1e-300),
        ] {
            let e = depth_grid(a, b, s).expect_err("refused");
            assert!(e.to_string().contains("accommodations"), "{e}");
        }
    }
}
