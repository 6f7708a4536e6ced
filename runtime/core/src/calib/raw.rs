//! The calibration file as written: strict serde types mirroring
//! `calib/default.toml` key for key, in the file's units. Nothing here is
//! validated; [`super::Calibration::from_raw`] does that once.

use serde::Deserialize;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawCalibration {
    pub panel: RawPanel,
    pub lens: RawLens,
    pub material: RawMaterial,
    pub channel: Vec<RawChannel>,
    pub doe: RawDoe,
    pub depths: RawDepths,
    pub target_blur: RawTargetBlur,
    pub ai: RawAi,
    pub wiener: RawWiener,
    pub simulation: RawSimulation,
    /// Optional: a file without `[eye]` has the paper's eye.
    #[serde(default)]
    pub eye: RawEye,
    /// Optional: the headset's views (`[[view]]`); none: one, the panel.
    #[serde(default)]
    pub view: Vec<super::views::RawView>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawPanel {
    pub pixel_pitch_um: f64,
    pub lens_distance_mm: f64,
    pub width_px: usize,
    pub height_px: usize,
    pub refresh_hz: f64,
    pub transfer_gamma: Vec<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawLens {
    pub focal_length_mm: f64,
    pub spec_wavelength_nm: f64,
    pub aperture_radius_mm: f64,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawMaterial {
    pub name: String,
    pub index_at_spec: f64,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawChannel {
    pub name: String,
    pub wavelength_nm: f64,
    pub index: f64,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawDoe {
    pub design_channel: String,
    pub design_pitch_um: f64,
    pub fabrication_pitch_um: f64,
    pub max_height_um: f64,
    #[serde(default)]
    pub file: String,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawDepths {
    pub range_d: [f64; 2],
    pub main_d: Vec<f64>,
    pub intermediate_d: Vec<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawTargetBlur {
    pub psi_rad: f64,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawAi {
    pub planes_d: Vec<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawWiener {
    pub average_step_d: f64,
    pub ai_k: f64,
    pub doe_k: f64,
    #[serde(default)]
    pub doe_k_tuned_for: String,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSimulation {
    pub window_energy: f64,
    pub min_pupil_samples: usize,
    pub max_pupil_samples: usize,
    #[serde(default)]
    pub pupil_step_um: f64,
    /// "auto" (radial Hankel path for rotationally symmetric pupils) or "2d".
    #[serde(default = "auto")]
    pub propagator: String,
}

fn auto() -> String {
    "auto".into()
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawEye {
    #[serde(default)]
    pub pupil_diameter_mm: Option<f64>,
    #[serde(default = "default_relief_mm")]
    pub relief_mm: f64,
    #[serde(default = "off")]
    pub lca: String,
    #[serde(default)]
    pub field_deg: f64,
}

impl Default for RawEye {
    fn default() -> Self {
        Self {
            pupil_diameter_mm: None,
            relief_mm: default_relief_mm(),
            lca: off(),
            field_deg: 0.0,
        }
    }
}

/// Eye relief when the calibration names none (a headset's 10–20 mm).
pub const DEFAULT_RELIEF_MM: f64 = 15.0;

fn default_relief_mm() -> f64 {
    DEFAULT_RELIEF_MM
}

fn off() -> String {
    "off".into()
}
