//! The viewer's eye (docs/model.md §4a): its entrance pupil, where it sits
//! behind the eyepiece, its longitudinal chromatic aberration and the field
//! angle it looks at. The defaults are the paper's eye: a pupil that does
//! not limit (the eyepiece's aperture is the stop), no eye LCA, on axis.

use serde::Serialize;

use super::raw::{DEFAULT_RELIEF_MM, RawEye};
use super::{CalibError, Calibration};

/// The eye's longitudinal chromatic aberration (`eye.lca`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
pub enum EyeLca {
    /// No chromatic aberration of the eye (the paper's model).
    #[default]
    #[serde(rename = "off")]
    Off,
    /// Thibos, Ye, Zhang and Bradley 1992, "The chromatic eye" (Appl. Opt.
    /// 31, 3594): the chromatic difference of refraction R(λ) = p − q/(λ − c).
    #[serde(rename = "thibos1992")]
    Thibos1992,
}

impl std::fmt::Display for EyeLca {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Off => "off",
            Self::Thibos1992 => "thibos1992",
        })
    }
}

impl std::str::FromStr for EyeLca {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "off" => Ok(Self::Off),
            "thibos1992" => Ok(Self::Thibos1992),
            _ => Err(format!("{s:?} is not an eye LCA model (off, thibos1992)")),
        }
    }
}

/// The eye as the optics see it (SI units).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EyeSettings {
    /// Entrance-pupil diameter; `None`: the eyepiece's aperture is the
    /// stop (the paper's model) and the other geometric fields do nothing.
    pub pupil_diameter_m: Option<f64>,
    /// From the lens plane (eyepiece) to the eye's entrance pupil.
    pub relief_m: f64,
    pub lca: EyeLca,
    /// Horizontal field angle of the point looked at, as seen from the
    /// eye's pupil, radians (0 on axis).
    pub field_rad: f64,
    /// Vertical field angle, radians: not in the file (`[eye]` names the
    /// horizontal one); the simulator's field zones set it for each zone's
    /// PSFs. Left out of the PSF cache's key while 0, so the keys of every
    /// PSF computed before it existed still hold.
    #[serde(skip_serializing_if = "is_zero")]
    pub field_y_rad: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl Default for EyeSettings {
    fn default() -> Self {
        Self {
            pupil_diameter_m: None,
            relief_m: DEFAULT_RELIEF_MM * 1e-3,
            lca: EyeLca::Off,
            field_rad: 0.0,
            field_y_rad: 0.0,
        }
    }
}

/// Smallest entrance pupil accepted (a bright-adapted eye's is ≈ 2 mm; a
/// 0.5 mm pupil's Airy pattern outgrows the largest PSF window).
pub const MIN_PUPIL_MM: f64 = 1.0;
/// Largest entrance pupil accepted (a dark-adapted young eye's is ≈ 8 mm).
pub const MAX_PUPIL_MM: f64 = 12.0;
/// Largest eye relief accepted.
pub const MAX_RELIEF_MM: f64 = 100.0;
/// Largest field angle accepted (the paraxial model's reach and beyond).
pub const MAX_FIELD_DEG: f64 = 45.0;

/// Thibos et al. 1992's constants: R(λ) = p − q/(λ − c), λ in µm, R in
/// diopters (0 at c + q/p = 590 nm; negative, i.e. myopic, at short
/// wavelengths).
const THIBOS_P_D: f64 = 1.68524;
const THIBOS_Q_D_UM: f64 = 0.63346;
const THIBOS_C_UM: f64 = 0.21410;

/// The chromatic difference of refraction of Thibos et al. 1992 at
/// `wavelength_m`, diopters: the refractive error of the eye at λ relative
/// to its refraction at 590 nm.
pub fn thibos_refraction_d(wavelength_m: f64) -> f64 {
    THIBOS_P_D - THIBOS_Q_D_UM / (wavelength_m * 1e6 - THIBOS_C_UM)
}

/// The eye's pupil projected onto the lens plane along the rays of the
/// channel's image (docs/model.md §4a): a disk of `radius_m` centred at
/// (`centre_m`, `centre_y_m`): on the horizontal axis unless a field zone
/// looks above or below it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EyeStop {
    pub centre_m: f64,
    pub centre_y_m: f64,
    pub radius_m: f64,
}

impl EyeStop {
    /// How far the stop's centre is from the axis, metres.
    pub fn offset_m(&self) -> f64 {
        self.centre_m.hypot(self.centre_y_m)
    }
}

impl Calibration {
    /// The eye's chromatic difference of refraction at a channel relative
    /// to the design channel (0 with `eye.lca = "off"`), diopters.
    pub fn eye_lca_d(&self, channel: usize) -> f64 {
        match self.eye.lca {
            EyeLca::Off => 0.0,
            EyeLca::Thibos1992 => {
                thibos_refraction_d(self.channels[channel].wavelength_m)
                    - thibos_refraction_d(self.channels[self.design_channel].wavelength_m)
            }
        }
    }

    /// The vergence at which the eye sees channel `channel` of the lens
    /// image in focus: V_λ + ΔR_eye(λ) (docs/model.md §4a), diopters. An eye
    /// myopic in blue (ΔR < 0) focuses blue on the retina only when it
    /// accommodates nearer, as if the image were farther.
    pub fn seen_vergence_d(&self, channel: usize) -> f64 {
        self.vergence_d(channel) + self.eye_lca_d(channel)
    }

    /// The eye's pupil in the lens plane for a channel, or `None` where it
    /// does not limit (no pupil given, or one whose projection covers the
    /// whole aperture): the paper's model exactly.
    pub fn eye_stop(&self, channel: usize) -> Option<EyeStop> {
        let diameter = self.eye.pupil_diameter_m?;
        let e = self.eye.relief_m;
        // Rays from the virtual image point (vergence V, distance 1/V before
        // the lens) to the pupil's rim cross the lens plane at r_eye/(1 + eV);
        // the chief ray to the pupil's centre at e·tanθ.
        let stop = EyeStop {
            centre_m: e * self.eye.field_rad.tan(),
            centre_y_m: e * self.eye.field_y_rad.tan(),
            radius_m: 0.5 * diameter / (1.0 + e * self.vergence_d(channel)),
        };
        (stop.radius_m < stop.offset_m() + self.aperture_radius_m).then_some(stop)
    }

    /// One line on the eye, for reports: the paper's, or the pupil, where
    /// its projection lands in the lens plane (design channel) and the LCA.
    pub fn eye_summary(&self) -> String {
        let e = &self.eye;
        let pupil = match (e.pupil_diameter_m, self.eye_stop(self.design_channel)) {
            (None, _) => format!(
                "the eyepiece's {:.1} mm aperture is the stop (the paper's eye)",
                2e3 * self.aperture_radius_m
            ),
            (Some(d), None) => format!(
                "pupil {:.1} mm at {:.1} mm, {:.1}° field: it does not limit the eyepiece's aperture",
                d * 1e3,
                e.relief_m * 1e3,
                e.field_rad.to_degrees()
            ),
            (Some(d), Some(stop)) => format!(
                "pupil {:.1} mm at {:.1} mm, {:.1}° field: in the lens plane {:.2} mm wide, {:.2} mm off axis",
                d * 1e3,
                e.relief_m * 1e3,
                e.field_rad.to_degrees(),
                2e3 * stop.radius_m,
                stop.offset_m() * 1e3
            ),
        };
        let lca = match e.lca {
            EyeLca::Off => "no eye LCA".to_string(),
            EyeLca::Thibos1992 => {
                let per: Vec<String> = (0..self.channels.len())
                    .map(|c| format!("{} {:+.2} D", self.channels[c].name, self.eye_lca_d(c)))
                    .collect();
                format!("eye LCA (Thibos 1992) {}", per.join(", "))
            }
        };
        format!("{pupil}; {lca}")
    }

    /// Whether some channel's eye stop lies off the axis (the PSFs then lose
    /// their rotational symmetry).
    pub fn eye_stop_off_axis(&self) -> bool {
        (0..self.channels.len()).any(|c| self.eye_stop(c).is_some_and(|s| s.offset_m() != 0.0))
    }
}

/// Command-line overrides of `[eye]` (`--pupil-mm`, `--eye-relief-mm`,
/// `--field-deg`, `--eye-lca`), in the file's units; `None` keeps the
/// calibration's value.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EyeOverrides {
    /// `Some(None)`: no pupil, the paper's eye, whatever the calibration says.
    pub pupil_diameter_mm: Option<Option<f64>>,
    pub relief_mm: Option<f64>,
    pub field_deg: Option<f64>,
    pub lca: Option<EyeLca>,
}

impl EyeOverrides {
    /// Applies the overrides to `calib`, validated as the file's `[eye]` is.
    pub fn apply(&self, calib: &mut Calibration) -> Result<(), CalibError> {
        if *self == Self::default() {
            return Ok(());
        }
        let e = &calib.eye;
        let raw = RawEye {
            pupil_diameter_mm: self
                .pupil_diameter_mm
                .unwrap_or(e.pupil_diameter_m.map(|d| d * 1e3)),
            relief_mm: self.relief_mm.unwrap_or(e.relief_m * 1e3),
            lca: self.lca.unwrap_or(e.lca).to_string(),
            field_deg: self.field_deg.unwrap_or(e.field_rad.to_degrees()),
        };
        let before = std::mem::replace(&mut calib.eye, resolve(&raw, "the command line")?);
        if let Err(e) = check_sees_light(calib, "the command line") {
            calib.eye = before;
            return Err(e);
        }
        Ok(())
    }
}

/// Refuses an eye whose pupil, projected into the lens plane, misses the
/// eyepiece's aperture: at that field angle the eye sees no light.
pub(super) fn check_sees_light(calib: &Calibration, path: &str) -> Result<(), CalibError> {
    for ch in 0..calib.channels.len() {
        if let Some(stop) = calib.eye_stop(ch)
            && stop.offset_m() >= calib.aperture_radius_m + stop.radius_m
        {
            return Err(CalibError::Invalid {
                path: path.to_string(),
                field: "eye.field_deg".into(),
                reason: format!(
                    "{:.1}°: the pupil's projection ({:.2} mm wide, {:.2} mm off axis) misses the \
                     {:.1} mm aperture: no light reaches the eye",
                    calib.eye.field_rad.to_degrees(),
                    2e3 * stop.radius_m,
                    stop.offset_m() * 1e3,
                    2e3 * calib.aperture_radius_m
                ),
            });
        }
    }
    Ok(())
}

/// Validates `[eye]` and resolves it to SI units.
pub(super) fn resolve(raw: &RawEye, path: &str) -> Result<EyeSettings, CalibError> {
    let err = |field: &str, reason: String| CalibError::Invalid {
        path: path.to_string(),
        field: format!("eye.{field}"),
        reason,
    };
    if let Some(d) = raw.pupil_diameter_mm
        && !(d.is_finite() && (MIN_PUPIL_MM..=MAX_PUPIL_MM).contains(&d))
    {
        return Err(err(
            "pupil_diameter_mm",
            format!(
                "{d} must lie in [{MIN_PUPIL_MM}, {MAX_PUPIL_MM}] mm (leave it out for the paper's \
                 eye; below {MIN_PUPIL_MM} mm, smaller than any eye's, the pupil's diffraction \
                 blur outgrows the PSF window)"
            ),
        ));
    }
    if !(raw.relief_mm.is_finite() && (0.0..=MAX_RELIEF_MM).contains(&raw.relief_mm)) {
        return Err(err(
            "relief_mm",
            format!("{} must lie in [0, {MAX_RELIEF_MM}] mm", raw.relief_mm),
        ));
    }
    if !(raw.field_deg.is_finite() && raw.field_deg.abs() <= MAX_FIELD_DEG) {
        return Err(err(
            "field_deg",
            format!(
                "{} must lie in [−{MAX_FIELD_DEG}, {MAX_FIELD_DEG}]°",
                raw.field_deg
            ),
        ));
    }
    let lca = raw.lca.parse().map_err(|e| err("lca", e))?;
    Ok(EyeSettings {
        pupil_diameter_m: raw.pupil_diameter_mm.map(|d| d * 1e-3),
        relief_m: raw.relief_mm * 1e-3,
        lca,
        field_rad: raw.field_deg.to_radians(),
        field_y_rad: 0.0,
    })
}
