//! `nedrt view` and `nedrt sweep`: the focus viewer's command lines (clap
//! definitions only, as in [`crate::args`]).

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use nedrt_optics::sim::Method;

use crate::args::{named, parse_size};

/// What the panels show first (keys s, t, p switch in the window).
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShownArg {
    Perceived,
    Sharp,
    Target,
}

/// What `view` and `sweep` show: the input and the methods.
#[derive(Args, Debug)]
pub struct SceneArgs {
    /// Input image (default: the shipped data/images/test/astronaut.png).
    #[arg(long, value_name = "IMG")]
    pub input: Option<PathBuf>,
    /// Display systems side by side.
    #[arg(long, value_delimiter = ',', value_parser = named::<Method>(), default_values = ["conventional", "ai", "proposed"])]
    pub methods: Vec<Method>,
    /// Instead of --methods: levels of `nedrt run`'s frame budget by the
    /// names its report gives (none, wiener, admm:K, refine:K, dcnn), side by side
    /// on the optics they run on (the shipped system's DOE).
    #[arg(
        long,
        value_delimiter = ',',
        value_name = "LEVEL",
        conflicts_with = "methods"
    )]
    pub levels: Vec<String>,
    /// Show only this region of the input, WxH+X+Y (every retinal pixel 1:1).
    #[arg(long, value_parser = parse_crop, value_name = "WxH+X+Y")]
    pub crop: Option<nedrt_app::viewer::Crop>,
}

impl SceneArgs {
    /// The scene's source and the options it is prepared with: `--levels`
    /// run on the optics `nedrt run`'s ladder puts them on.
    pub fn source(
        self,
        common: nedrt_app::CommonOptions,
    ) -> Result<(nedrt_app::CommonOptions, nedrt_app::viewer::SceneSource), nedrt_app::AppError>
    {
        let (common, panels) = if self.levels.is_empty() {
            let panels = self
                .methods
                .into_iter()
                .map(nedrt_app::viewer::Panel::of)
                .collect();
            (common, panels)
        } else {
            let mut panels = Vec::new();
            let mut optics = common.clone();
            for label in self.levels {
                let (c, method, prefilter) = nedrt_run::level_system(&common, &label)?;
                optics = c;
                panels.push(nedrt_app::viewer::Panel {
                    label,
                    method,
                    prefilter,
                });
            }
            (optics, panels)
        };
        let source = nedrt_app::viewer::SceneSource {
            input: self.input,
            crop: self.crop,
            panels,
        };
        Ok((common, source))
    }
}

#[derive(Args, Debug)]
pub struct ViewArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Where the eye focuses first, in diopters.
    #[arg(
        long,
        value_name = "D",
        default_value_t = 1.5,
        allow_negative_numbers = true
    )]
    pub accom: f64,
    /// Step of the accommodation grid over 0–3 D (PSFs for every step are
    /// computed once and cached).
    #[arg(long, value_name = "D", default_value_t = 0.05)]
    pub step: f64,
    #[arg(long, value_enum, default_value = "perceived")]
    pub show: ShownArg,
    /// Open no window: render the picture at --accom to --screenshot.
    #[arg(long)]
    pub headless: bool,
    /// The PNG --headless writes (in the window, key c saves into --screenshot-dir).
    #[arg(long, value_name = "FILE")]
    pub screenshot: Option<PathBuf>,
    /// Where key `c` saves screenshots of the window.
    #[arg(long, value_name = "DIR", default_value = ".")]
    pub screenshot_dir: PathBuf,
    /// The largest window; a larger picture is scaled down into it.
    #[arg(long, value_parser = parse_size, default_value = "1600x1000", value_name = "WxH")]
    pub max_window: (usize, usize),
}

#[derive(Args, Debug)]
pub struct SweepArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// First accommodation, diopters.
    #[arg(
        long,
        value_name = "D",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    pub from: f64,
    /// Last accommodation, diopters.
    #[arg(
        long,
        value_name = "D",
        default_value_t = 3.0,
        allow_negative_numbers = true
    )]
    pub to: f64,
    #[arg(long, value_name = "D", default_value_t = 0.1)]
    pub step: f64,
    /// Frames a second of the animation.
    #[arg(long, default_value_t = 8.0)]
    pub fps: f64,
    /// The animation: .png (animated PNG, lossless) or .gif.
    #[arg(long, value_name = "FILE", default_value = "sweep.png")]
    pub out: PathBuf,
}

/// `WxH+X+Y` (a region `W`×`H` at `X`, `Y`; as ImageMagick's geometry).
fn parse_crop(s: &str) -> Result<nedrt_app::viewer::Crop, String> {
    let bad = || format!("{s:?}: expected WxH+X+Y, e.g. 128x128+200+100");
    let (size, offset) = s.split_once('+').ok_or_else(bad)?;
    let (x, y) = offset.split_once('+').ok_or_else(bad)?;
    let (width, height) = parse_size(size)?;
    let number = |v: &str| v.parse::<usize>().map_err(|_| bad());
    Ok(nedrt_app::viewer::Crop {
        x: number(x)?,
        y: number(y)?,
        width,
        height,
    })
}
