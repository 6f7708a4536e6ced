//! The eye's command-line overrides of the calibration's `[eye]`
//! (docs/model.md §4a): global, so every study and the simulator take them.

use clap::Args;
use nedrt_core::calib::{EyeLca, EyeOverrides};

#[derive(Args, Debug, Clone, Default)]
pub struct EyeArgs {
    /// The eye's entrance-pupil diameter in mm (default: the calibration's
    /// `eye.pupil_diameter_mm`; without one the eyepiece's aperture is the
    /// stop, the paper's eye).
    #[arg(long, global = true, value_name = "MM")]
    pub pupil_mm: Option<f64>,
    /// From the eyepiece to the eye's pupil, mm (default: `eye.relief_mm`, 15).
    #[arg(long, global = true, value_name = "MM")]
    pub eye_relief_mm: Option<f64>,
    /// Horizontal field angle looked at, degrees, as seen from the eye's
    /// pupil (default: `eye.field_deg`, 0).
    #[arg(long, global = true, value_name = "DEG", allow_negative_numbers = true)]
    pub field_deg: Option<f64>,
    /// The eye's longitudinal chromatic aberration: on (Thibos et al. 1992)
    /// or off (default: `eye.lca`, off).
    #[arg(long, global = true, value_name = "on|off", value_parser = parse_lca)]
    pub eye_lca: Option<EyeLca>,
}

/// `on` is Thibos 1992 (the calibration file names the model itself).
fn parse_lca(s: &str) -> Result<EyeLca, String> {
    match s {
        "on" => Ok(EyeLca::Thibos1992),
        _ => s.parse().map_err(|e: String| format!("{e}, or on")),
    }
}

impl EyeArgs {
    pub fn overrides(&self) -> EyeOverrides {
        EyeOverrides {
            pupil_diameter_mm: self.pupil_mm.map(Some),
            relief_mm: self.eye_relief_mm,
            field_deg: self.field_deg,
            lca: self.eye_lca,
        }
    }
}

/// How `nedrt sim` renders a field whose PSF changes across the image
/// (an eye pupil smaller than the eyepiece; docs/model.md §4b).
#[derive(Args, Debug, Clone)]
pub struct ZoneArgs {
    /// Zones of field angle, each rendered through its own PSFs and blended
    /// bilinearly: auto (as many as --zone-tolerance-db needs, up to 8 a
    /// side), N (N×N) or NxM (N columns, M rows). Without an eye pupil the
    /// PSF is the same everywhere: one zone.
    #[arg(long, default_value = "auto", value_name = "auto|N|NxM")]
    pub field_zones: String,
    /// For --field-zones auto: the PSNR (dB) within which a zone's edge
    /// must render as its centre does.
    #[arg(
        long,
        default_value_t = nedrt_optics::sim::zones::DEFAULT_TOLERANCE_DB,
        value_name = "DB",
        allow_negative_numbers = true
    )]
    pub zone_tolerance_db: f64,
}

impl ZoneArgs {
    pub fn request(&self) -> anyhow::Result<nedrt_optics::sim::ZoneRequest> {
        use nedrt_optics::sim::ZoneRequest;
        let t = self.zone_tolerance_db;
        if !(t.is_finite() && t > 0.0) {
            anyhow::bail!("--zone-tolerance-db {t}: give a positive number of dB (e.g. 40)");
        }
        match self
            .field_zones
            .parse::<ZoneRequest>()
            .map_err(|e| anyhow::anyhow!("--field-zones {e}"))?
        {
            ZoneRequest::Auto { .. } => Ok(ZoneRequest::Auto { tolerance_db: t }),
            fixed => Ok(fixed),
        }
    }
}
