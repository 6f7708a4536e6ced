//! Calibration: parse `calib/*.toml` strictly, validate every field against
//! its physical meaning, and resolve once into [`Calibration`] (SI units) from
//! which the optics derive everything else (docs/model.md §2–§4).

mod eye;
mod raw;
mod validate;
pub mod views;

pub use eye::{EyeLca, EyeOverrides, EyeSettings, EyeStop, thibos_refraction_d};

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use raw::RawCalibration;
use serde::Serialize;

/// The calibration shipped with the project, embedded so that `nedrt` runs
/// from any directory on a fresh checkout.
pub const DEFAULT_CALIBRATION_TOML: &str = include_str!("../../../../calib/default.toml");
/// Name under which the embedded calibration is reported in messages.
pub const DEFAULT_CALIBRATION_NAME: &str = "calib/default.toml";

/// The largest calibration file read (the shipped one is about 5 KB).
pub const MAX_CALIBRATION_BYTES: u64 = 1 << 20;

/// A calibration problem, always naming the file and (where there is one) the field.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    #[error("{path}: cannot read calibration: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: malformed TOML: {message}")]
    Parse { path: String, message: String },
    #[error("{path}: {field}: {reason}")]
    Invalid {
        path: String,
        field: String,
        reason: String,
    },
}

/// One display primary simulated as a monochromatic channel.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Channel {
    pub name: String,
    pub wavelength_m: f64,
    /// Refractive index of the lens/DOE material at this wavelength.
    pub index: f64,
}

/// Settings of the PSF model (docs/model.md §6–§8).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SimulationSettings {
    pub window_energy: f64,
    pub min_pupil_samples: usize,
    pub max_pupil_samples: usize,
    /// Forced pupil step; `None` lets the sampling rules choose.
    pub pupil_step_m: Option<f64>,
    /// Which propagator the PSF planner may use (`simulation.propagator`).
    pub propagator: PropagatorSetting,
}

/// `simulation.propagator`: `Auto` takes the radial (Hankel) path for
/// rotationally symmetric pupils (lens alone, radial DOEs) and the 2-D path
/// for free-form maps; `TwoD` forces the 2-D path (comparisons, studies).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum PropagatorSetting {
    Auto,
    TwoD,
}

/// Wiener preprocessing constants (docs/model.md §13).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WienerSettings {
    pub average_step_d: f64,
    pub ai_k: f64,
    pub doe_k: f64,
    pub doe_k_tuned_for: String,
}

/// The panel as the runtime drives it: resolution, refresh and the
/// transfer curve from linear intensity to code values.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PanelSettings {
    pub width_px: usize,
    pub height_px: usize,
    pub refresh_hz: f64,
    /// Per channel (in `channels` order): emitted intensity = code^γ, so a
    /// linear intensity x is sent as code x^(1/γ).
    pub transfer_gamma: Vec<f64>,
}

/// A validated calibration in SI units. Construct with [`Calibration::load`],
/// [`Calibration::from_toml`] or [`Calibration::default_embedded`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Calibration {
    /// Where it came from, for messages.
    pub source: String,
    pub pixel_pitch_m: f64,
    pub lens_distance_m: f64,
    pub focal_length_spec_m: f64,
    pub spec_wavelength_m: f64,
    pub aperture_radius_m: f64,
    pub material_name: String,
    pub index_at_spec: f64,
    pub channels: Vec<Channel>,
    /// Index into `channels` of the design wavelength λ0.
    pub design_channel: usize,
    pub doe_design_pitch_m: f64,
    pub doe_fabrication_pitch_m: f64,
    pub doe_max_height_m: f64,
    /// Height-map file, resolved against the calibration's folder; `None` = initial DOE.
    pub doe_file: Option<PathBuf>,
    pub range_d: [f64; 2],
    pub main_d: Vec<f64>,
    pub intermediate_d: Vec<f64>,
    pub target_blur_psi_rad: f64,
    pub ai_planes_d: Vec<f64>,
    pub wiener: WienerSettings,
    pub simulation: SimulationSettings,
    pub panel: PanelSettings,
    /// The viewer's eye (docs/model.md §4a); the default is the paper's.
    pub eye: EyeSettings,
    /// The headset's views (`[[view]]`): where each eye's image lies on the
    /// panel and its design; empty: one view, the whole panel.
    pub views: Vec<views::ViewSettings>,
}

/// Largest panel side the runtime accepts (pixels): a guard against typos
/// that would allocate gigabytes per frame.
pub const MAX_PANEL_SIDE_PX: usize = 16384;

/// Depths closer than this are the same depth (diopters).
pub const DEPTH_TOLERANCE_D: f64 = 1e-9;

impl Calibration {
    /// The embedded default calibration (`calib/default.toml`).
    pub fn default_embedded() -> Result<Self, CalibError> {
        Self::from_toml(DEFAULT_CALIBRATION_TOML, DEFAULT_CALIBRATION_NAME, None)
    }

    /// Read and validate a calibration file (at most
    /// [`MAX_CALIBRATION_BYTES`]: the shipped one is a few KB).
    pub fn load(path: &Path) -> Result<Self, CalibError> {
        let name = path.display().to_string();
        let read = |source| CalibError::Read {
            path: name.clone(),
            source,
        };
        let bytes = crate::util::read_capped(path, MAX_CALIBRATION_BYTES).map_err(read)?;
        let text = String::from_utf8(bytes).map_err(|e| {
            read(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("not UTF-8 text ({e})"),
            ))
        })?;
        Self::from_toml(&text, &name, path.parent())
    }

    /// Parse and validate calibration text; `base_dir` resolves relative file paths.
    pub fn from_toml(text: &str, name: &str, base_dir: Option<&Path>) -> Result<Self, CalibError> {
        let raw: RawCalibration = toml::from_str(text).map_err(|e| CalibError::Parse {
            path: name.to_string(),
            // toml quotes the offending line: keep a huge value from
            // turning the error into megabytes.
            message: crate::util::bounded(e.to_string().replace('\n', " ").trim(), 600),
        })?;
        Self::from_raw(raw, name, base_dir)
    }

    /// Focal length at a channel's wavelength, f_λ = f_s (n_s − 1)/(n_λ − 1)
    /// (docs/model.md §3), metres.
    pub fn focal_length_m(&self, channel: usize) -> f64 {
        self.focal_length_spec_m * (self.index_at_spec - 1.0) / (self.channels[channel].index - 1.0)
    }

    /// Vergence of the lens-only panel image, V_λ = 1/z_d − 1/f_λ, diopters.
    pub fn vergence_d(&self, channel: usize) -> f64 {
        1.0 / self.lens_distance_m - 1.0 / self.focal_length_m(channel)
    }

    /// Defocus coefficient Ψ_λ(D) = (π/λ)(V_λ + ΔR_eye,λ − D) r²
    /// (docs/model.md §4, §4a; ΔR_eye = 0 without eye LCA), radians.
    pub fn psi_rad(&self, channel: usize, accommodation_d: f64) -> f64 {
        self.psi_for_vergence(channel, self.seen_vergence_d(channel) - accommodation_d)
    }

    /// Ψ for a given vergence error (image vergence minus accommodation), radians.
    pub fn psi_for_vergence(&self, channel: usize, vergence_error_d: f64) -> f64 {
        PI / self.channels[channel].wavelength_m * vergence_error_d * self.aperture_radius_m.powi(2)
    }

    /// Retinal sampling step Δθ = p / (2 z_d): a display pixel is 2×2 retinal cells, radians.
    pub fn retinal_step_rad(&self) -> f64 {
        self.pixel_pitch_m / (2.0 * self.lens_distance_m)
    }

    /// Phase per metre of DOE height at a channel, 2π(n_λ − 1)/λ (docs/model.md §5),
    /// rad/m.
    pub fn doe_phase_per_m(&self, channel: usize) -> f64 {
        let c = &self.channels[channel];
        2.0 * PI * (c.index - 1.0) / c.wavelength_m
    }

    /// Height of one wave of phase at the design wavelength, λ0/(n_λ0 − 1), metres.
    pub fn doe_wave_height_m(&self) -> f64 {
        let c = &self.channels[self.design_channel];
        c.wavelength_m / (c.index - 1.0)
    }

    /// Whether `accommodation_d` is one of the main (sharp-target) depths.
    pub fn is_main_depth(&self, accommodation_d: f64) -> bool {
        self.main_d
            .iter()
            .any(|d| (d - accommodation_d).abs() < DEPTH_TOLERANCE_D)
    }

    /// The evaluation depths of docs/model.md §17: the main and intermediate depths,
    /// sorted.
    pub fn evaluation_depths_d(&self) -> Vec<f64> {
        let mut d: Vec<f64> = self
            .main_d
            .iter()
            .chain(&self.intermediate_d)
            .copied()
            .collect();
        d.sort_by(f64::total_cmp);
        d
    }

    /// Depths 0..3 D (the calibrated range) in `step_d` steps, both ends included.
    pub fn depth_sweep_d(&self, step_d: f64) -> Vec<f64> {
        let [lo, hi] = self.range_d;
        let n = ((hi - lo) / step_d + 1e-9).floor() as usize;
        // Rounded to 1e-12 D so that 15 × 0.1 is the 1.5 D of the depth lists.
        (0..=n)
            .map(|i| ((lo + i as f64 * step_d) * 1e12).round() / 1e12)
            .collect()
    }

    /// Hash of every value that shapes a PSF (not the Wiener constants): the
    /// cache key's calibration part.
    pub fn optics_fingerprint(&self) -> String {
        #[derive(Serialize)]
        struct Optics<'a> {
            pixel_pitch_m: f64,
            lens_distance_m: f64,
            focal_length_spec_m: f64,
            spec_wavelength_m: f64,
            aperture_radius_m: f64,
            index_at_spec: f64,
            channels: &'a [Channel],
            design_channel: usize,
            simulation: &'a SimulationSettings,
            // Only an eye whose pupil limits changes a PSF beyond its Ψ
            // (which the key holds): the paper's eye keeps the old keys.
            #[serde(skip_serializing_if = "Option::is_none")]
            eye: Option<&'a EyeSettings>,
        }
        let o = Optics {
            pixel_pitch_m: self.pixel_pitch_m,
            lens_distance_m: self.lens_distance_m,
            focal_length_spec_m: self.focal_length_spec_m,
            spec_wavelength_m: self.spec_wavelength_m,
            aperture_radius_m: self.aperture_radius_m,
            index_at_spec: self.index_at_spec,
            channels: &self.channels,
            design_channel: self.design_channel,
            simulation: &self.simulation,
            eye: self.eye.pupil_diameter_m.map(|_| &self.eye),
        };
        let json = serde_json::to_string(&o).unwrap_or_default();
        blake3::hash(json.as_bytes()).to_hex()[..16].to_string()
    }
}

#[cfg(test)]
mod tests;
