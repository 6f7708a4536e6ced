//! `nedrt calib`'s subcommands: the patterns, synthetic captures, the PSFs
//! from captures, and a bundle shown against the design.

use std::path::PathBuf;

use clap::{Args, Subcommand};

#[derive(Args, Debug)]
pub struct CalibArgs {
    #[command(subcommand)]
    pub action: Option<CalibAction>,
}

#[derive(Subcommand, Debug)]
pub enum CalibAction {
    /// The patterns a lab shows on the built display and photographs: per
    /// channel, a grid of lit pixels whose PSFs never overlap over the
    /// calibrated range; a checkerboard to register camera pixels to panel
    /// pixels; flat and dark fields; patterns.toml naming each.
    Patterns(CalibPatternsArgs),
    /// Synthetic captures: what a camera at the eye photographs of the
    /// patterns through optics perturbed from the design (etch depth,
    /// levels, decentre, eye relief, panel distance, primaries), with the
    /// camera's pitch, rotation, distortion, noise and quantisation; the
    /// true PSFs beside them (truth/, a PSF bundle).
    Synth(CalibSynthArgs),
    /// The true PSFs of a display as built, computed, no camera: what
    /// `calib synth` writes as truth/, alone (an oracle to judge a
    /// measured bundle by, or a bundle to try --psfs with).
    Truth(CalibTruthArgs),
    /// From captures to PSFs: dark and flat fields, camera-to-panel
    /// registration from the checkerboard, each dot cut at its registered
    /// place, averaged, deconvolved from its pixel, a noise floor; a PSF
    /// bundle (psfs.safetensors + bundle.toml) that --psfs reads.
    Psfs(CalibPsfsArgs),
    /// A PSF bundle against the design's own PSFs (and another bundle,
    /// e.g. a synthetic capture's truth): the light in the window, the
    /// centroid, the distance of the pixel responses.
    Show(CalibShowArgs),
}

#[derive(Args, Debug)]
pub struct CalibShowArgs {
    /// The PSF bundle's folder.
    #[arg(long, value_name = "DIR")]
    pub bundle: PathBuf,
    /// Another bundle to compare with (`calib synth`'s truth/).
    #[arg(long, value_name = "DIR")]
    pub against: Option<PathBuf>,
    /// Also chart it: STEM.png and STEM.svg (centre rows against the
    /// design's, and the distance to the design against accommodation).
    #[arg(long, value_name = "STEM")]
    pub chart: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct CalibSynthArgs {
    /// The patterns' folder (`calib patterns --out`).
    #[arg(long, value_name = "DIR")]
    pub patterns: PathBuf,
    /// The captures' folder (new, or empty).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Where the camera is focused, diopters, one set of captures each.
    #[arg(long, value_delimiter = ',', default_values = ["0", "0.5", "1", "1.5", "2", "2.5", "3"], value_name = "D,...")]
    pub accommodations: Vec<f64>,
    #[command(flatten)]
    pub built: PerturbArgs,
    /// The camera (TOML: pitch_cells, rotation_deg, offset_px,
    /// distortion_k1, full_well_e, read_noise_e, dark_dn, bits, qe,
    /// flux_e_per_ms, field_margin; what it leaves out is the default).
    #[arg(long, value_name = "FILE")]
    pub camera: Option<PathBuf>,
    /// The noise's seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Field zones, N or NxM (columns × rows of equal rectangles over the
    /// panel): PSFs for each besides the whole field's, for a display whose
    /// PSF changes across the field (docs/calibration.md, "Field zones").
    #[arg(long, default_value = "1", value_name = "N|NxM")]
    pub field_zones: ZoneGrid,
}

#[derive(Args, Debug)]
pub struct CalibPsfsArgs {
    /// The captures' folder, with captures.toml.
    #[arg(long, value_name = "DIR")]
    pub captures: PathBuf,
    /// The PSF bundle's folder (new, or a bundle to replace).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Field zones, N or NxM (columns × rows of equal rectangles over the
    /// panel): PSFs for each besides the whole field's, for a display whose
    /// PSF changes across the field (docs/calibration.md, "Field zones").
    #[arg(long, default_value = "1", value_name = "N|NxM")]
    pub field_zones: ZoneGrid,
}

#[derive(Args, Debug)]
pub struct CalibPatternsArgs {
    /// The folder the images and patterns.toml go to (made if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Room for the built optics' blur: dots 2 × margin × the design PSF's
    /// radius apart (its 99.9 % light), at least 1.
    #[arg(long, default_value_t = 1.5, value_name = "F")]
    pub margin: f64,
    /// Shifted copies of each channel's grid, N across × N down, a
    /// pattern each, to sample the field more densely (1 to 8).
    #[arg(long, default_value_t = 2, value_name = "N")]
    pub shifts: usize,
}

#[derive(Args, Debug)]
pub struct ToleranceArgs {
    /// Folder of images to score (validation images, never the reserved evaluation sets).
    #[arg(long, default_value = "data/images/val", value_name = "DIR")]
    pub images: PathBuf,
    /// How many of them (the first, by name).
    #[arg(long, default_value_t = 2, value_name = "N")]
    pub max_images: usize,
    /// Each image's centre crop, pixels a side.
    #[arg(long, default_value_t = 96, value_name = "PX")]
    pub crop: usize,
    /// The report (Markdown); the JSON and the chart go beside it.
    #[arg(long, default_value = "out/tolerance.md", value_name = "FILE")]
    pub out: PathBuf,
    /// The methods to sweep (default: conventional, ai, doe-only,
    /// doe+wiener, and proposed where its D-CNN is there, whose DOE then
    /// serves every DOE method).
    #[arg(long, value_delimiter = ',', value_parser = crate::args::named::<nedrt_optics::sim::Method>(), value_name = "METHOD,...")]
    pub methods: Vec<nedrt_optics::sim::Method>,
    /// Rewrite --out, its tolerances and its chart from the JSON a sweep
    /// wrote beside it, without sweeping.
    #[arg(long)]
    pub replot: bool,
}

/// How the display as built differs from the design (`calib synth`,
/// `calib truth`).
#[derive(Args, Debug)]
pub struct PerturbArgs {
    /// Etched depth over the designed depth (1.08: 8 % too deep).
    #[arg(long, default_value_t = 1.0, value_name = "SCALE")]
    pub etch: f64,
    /// Height levels of the fabricated profile (0: continuous).
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub levels: u32,
    /// The DOE's centre from the lens's axis, across and down, mm.
    #[arg(long, default_value = "0,0", value_parser = numbers::<2>, allow_hyphen_values = true, value_name = "X,Y")]
    pub decentre_mm: [f64; 2],
    /// Added to the eye relief, mm (not the global --eye-relief-mm, the
    /// relief itself, whose name this must not share: clap would set the
    /// global one to this default).
    #[arg(
        long = "eye-relief-error-mm",
        default_value_t = 0.0,
        allow_hyphen_values = true,
        value_name = "MM"
    )]
    pub eye_relief_error_mm: f64,
    /// Added to the lens-to-panel distance, mm.
    #[arg(
        long,
        default_value_t = 0.0,
        allow_hyphen_values = true,
        value_name = "MM"
    )]
    pub panel_distance_mm: f64,
    /// Added to each primary's wavelength, nm (R,G,B).
    #[arg(long, default_value = "0,0,0", value_parser = numbers::<3>, allow_hyphen_values = true, value_name = "R,G,B")]
    pub primaries_nm: [f64; 3],
    /// Each primary's spectral width, nm FWHM (R,G,B; 0: one wavelength).
    #[arg(long, default_value = "0,0,0", value_parser = numbers::<3>, value_name = "R,G,B")]
    pub bandwidths_nm: [f64; 3],
}

impl PerturbArgs {
    pub fn perturbation(&self) -> nedrt_optics::perturb::Perturbation {
        nedrt_optics::perturb::Perturbation {
            etch_scale: self.etch,
            levels: self.levels,
            decentre_mm: self.decentre_mm,
            eye_relief_mm: self.eye_relief_error_mm,
            panel_distance_mm: self.panel_distance_mm,
            primaries_nm: self.primaries_nm,
            bandwidths_nm: self.bandwidths_nm,
        }
    }
}

#[derive(Args, Debug)]
pub struct CalibTruthArgs {
    /// The bundle's folder (new, or a bundle to replace).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Accommodations, diopters.
    #[arg(long, value_delimiter = ',', default_values = ["0", "0.5", "1", "1.5", "2", "2.5", "3"], value_name = "D,...")]
    pub accommodations: Vec<f64>,
    #[command(flatten)]
    pub built: PerturbArgs,
    /// Field zones, N or NxM (columns × rows of equal rectangles over the
    /// panel): PSFs for each besides the whole field's, for a display whose
    /// PSF changes across the field (docs/calibration.md, "Field zones").
    #[arg(long, default_value = "1", value_name = "N|NxM")]
    pub field_zones: ZoneGrid,
}

/// `--field-zones`: columns × rows, parsed as the simulator's zone
/// requests are, without `auto` (a measurement's zones are chosen).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ZoneGrid(pub (usize, usize));

impl std::str::FromStr for ZoneGrid {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        use nedrt_optics::sim::{ZoneRequest, zones::MAX_ZONES_PER_AXIS};
        match s.parse::<ZoneRequest>() {
            Ok(ZoneRequest::Fixed(x, y)) => Ok(Self((x, y))),
            Ok(ZoneRequest::Auto { .. }) => Err(format!(
                "{s:?}: give N or NxM (auto is for the simulator's own zones)"
            )),
            Err(_) => Err(format!(
                "{s:?}: give N or NxM with 1 ≤ N, M ≤ {MAX_ZONES_PER_AXIS} (e.g. 2 or 2x1)"
            )),
        }
    }
}

/// `N` comma-separated numbers ("0.1,0": a decentre across and down).
fn numbers<const N: usize>(text: &str) -> Result<[f64; N], String> {
    let values = text
        .split(',')
        .map(|t| t.trim().parse::<f64>().map_err(|e| format!("{t:?}: {e}")))
        .collect::<Result<Vec<_>, _>>()?;
    values
        .try_into()
        .map_err(|v: Vec<f64>| format!("{} numbers; give {N}, comma-separated", v.len()))
}
