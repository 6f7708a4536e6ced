//! Calibration: parse `calib/*.toml` strictly, validate every field against
//! its physical meaning, and resolve once into [`Calibration`] (SI units) from
//! which the optics derive everything else (docs/model.md §2–§4).

mod raw;

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use raw::RawCalibration;
use serde::Serialize;

/// The calibration shipped with the project, embedded so that `nedrt` runs
/// from any directory on a fresh checkout.
pub const DEFAULT_CALIBRATION_TOML: &str = include_str!("../../../calib/default.toml");
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

    fn from_raw(
        raw: RawCalibration,
        name: &str,
        base_dir: Option<&Path>,
    ) -> Result<Self, CalibError> {
        let v = Validator { path: name };
        v.positive("panel.pixel_pitch_um", raw.panel.pixel_pitch_um)?;
        v.positive("panel.lens_distance_mm", raw.panel.lens_distance_mm)?;
        v.positive("lens.focal_length_mm", raw.lens.focal_length_mm)?;
        v.wavelength("lens.spec_wavelength_nm", raw.lens.spec_wavelength_nm)?;
        v.positive("lens.aperture_radius_mm", raw.lens.aperture_radius_mm)?;
        v.index("material.index_at_spec", raw.material.index_at_spec)?;
        if raw.channel.is_empty() {
            return Err(v.err("channel", "at least one [[channel]] is needed"));
        }
        let mut channels = Vec::with_capacity(raw.channel.len());
        for (i, c) in raw.channel.iter().enumerate() {
            let field = format!("channel[{i}] ({})", c.name);
            v.wavelength(&format!("{field}.wavelength_nm"), c.wavelength_nm)?;
            v.index(&format!("{field}.index"), c.index)?;
            if raw.channel[..i].iter().any(|o| o.name == c.name) {
                return Err(v.err(&field, "duplicate channel name"));
            }
            channels.push(Channel {
                name: c.name.clone(),
                wavelength_m: c.wavelength_nm * 1e-9,
                index: c.index,
            });
        }
        let design_channel = channels
            .iter()
            .position(|c| c.name == raw.doe.design_channel)
            .ok_or_else(|| {
                v.err(
                    "doe.design_channel",
                    &format!("no [[channel]] is named {:?}", raw.doe.design_channel),
                )
            })?;

        let focal_length_spec_m = raw.lens.focal_length_mm * 1e-3;
        let lens_distance_m = raw.panel.lens_distance_mm * 1e-3;
        for c in &channels {
            let f = focal_length_spec_m * (raw.material.index_at_spec - 1.0) / (c.index - 1.0);
            if lens_distance_m >= f {
                return Err(v.err(
                    "panel.lens_distance_mm",
                    &format!(
                        "{} mm is at or beyond the focal length of channel {} ({:.3} mm): the panel would form no virtual image",
                        raw.panel.lens_distance_mm,
                        c.name,
                        f * 1e3
                    ),
                ));
            }
        }

        v.positive("doe.design_pitch_um", raw.doe.design_pitch_um)?;
        v.positive("doe.fabrication_pitch_um", raw.doe.fabrication_pitch_um)?;
        v.positive("doe.max_height_um", raw.doe.max_height_um)?;
        let aperture_radius_m = raw.lens.aperture_radius_mm * 1e-3;
        for (field, pitch_um) in [
            ("doe.design_pitch_um", raw.doe.design_pitch_um),
            ("doe.fabrication_pitch_um", raw.doe.fabrication_pitch_um),
        ] {
            if pitch_um * 1e-6 * 16.0 > 2.0 * aperture_radius_m {
                return Err(v.err(
                    field,
                    &format!(
                        "{pitch_um} µm leaves fewer than 16 samples across the {} mm aperture",
                        2.0 * raw.lens.aperture_radius_mm
                    ),
                ));
            }
        }
        let doe_file = match raw.doe.file.trim() {
            "" => None,
            f => Some(match base_dir {
                Some(dir) => dir.join(f),
                None => PathBuf::from(f),
            }),
        };

        let [lo, hi] = raw.depths.range_d;
        if !(lo.is_finite() && hi.is_finite() && lo >= 0.0 && hi > lo) {
            return Err(v.err(
                "depths.range_d",
                &format!("[{lo}, {hi}] must be finite, increasing and ≥ 0 D"),
            ));
        }
        v.depth_list("depths.main_d", &raw.depths.main_d, [lo, hi], false)?;
        v.depth_list(
            "depths.intermediate_d",
            &raw.depths.intermediate_d,
            [lo, hi],
            true,
        )?;
        for d in &raw.depths.main_d {
            if raw
                .depths
                .intermediate_d
                .iter()
                .any(|i| (i - d).abs() < DEPTH_TOLERANCE_D)
            {
                return Err(v.err(
                    "depths.intermediate_d",
                    &format!("{d} D is also a main depth; a depth has one target"),
                ));
            }
        }
        if !raw.target_blur.psi_rad.is_finite() || raw.target_blur.psi_rad < 0.0 {
            return Err(v.err("target_blur.psi_rad", "must be a finite defocus ≥ 0 rad"));
        }
        v.depth_list("ai.planes_d", &raw.ai.planes_d, [lo, hi], false)?;

        let w = &raw.wiener;
        if !(w.average_step_d > 0.0 && w.average_step_d <= hi - lo) {
            return Err(v.err(
                "wiener.average_step_d",
                "must be > 0 and no larger than the depth range",
            ));
        }
        v.positive("wiener.ai_k", w.ai_k)?;
        v.positive("wiener.doe_k", w.doe_k)?;

        let s = &raw.simulation;
        if !(s.window_energy > 0.5 && s.window_energy < 1.0) {
            return Err(v.err(
                "simulation.window_energy",
                "must be a fraction in (0.5, 1): the share of light the PSF window holds",
            ));
        }
        if s.min_pupil_samples < 16 {
            return Err(v.err(
                "simulation.min_pupil_samples",
                "fewer than 16 samples cannot resolve the aperture edge",
            ));
        }
        if s.max_pupil_samples < s.min_pupil_samples {
            return Err(v.err(
                "simulation.max_pupil_samples",
                "must be at least simulation.min_pupil_samples",
            ));
        }
        if !(s.pupil_step_um.is_finite() && s.pupil_step_um >= 0.0) {
            return Err(v.err("simulation.pupil_step_um", "must be ≥ 0 (0 = automatic)"));
        }
        let propagator = match s.propagator.as_str() {
            "auto" => PropagatorSetting::Auto,
            "2d" => PropagatorSetting::TwoD,
            _ => return Err(v.err("simulation.propagator", "must be \"auto\" or \"2d\"")),
        };

        let p = &raw.panel;
        for (field, px) in [
            ("panel.width_px", p.width_px),
            ("panel.height_px", p.height_px),
        ] {
            if !(1..=MAX_PANEL_SIDE_PX).contains(&px) {
                return Err(v.err(
                    field,
                    &format!("{px} must lie in 1..={MAX_PANEL_SIDE_PX} pixels"),
                ));
            }
        }
        if !(p.refresh_hz.is_finite() && (1.0..=1000.0).contains(&p.refresh_hz)) {
            return Err(v.err(
                "panel.refresh_hz",
                &format!("{} must lie in 1–1000 Hz", p.refresh_hz),
            ));
        }
        if p.transfer_gamma.len() != channels.len() {
            return Err(v.err(
                "panel.transfer_gamma",
                &format!(
                    "{} values for {} [[channel]]s: one exponent per primary",
                    p.transfer_gamma.len(),
                    channels.len()
                ),
            ));
        }
        for g in &p.transfer_gamma {
            if !(g.is_finite() && (0.5..=4.0).contains(g)) {
                return Err(v.err(
                    "panel.transfer_gamma",
                    &format!("{g} is not a display gamma (0.5–4)"),
                ));
            }
        }
        let panel = PanelSettings {
            width_px: p.width_px,
            height_px: p.height_px,
            refresh_hz: p.refresh_hz,
            transfer_gamma: p.transfer_gamma.clone(),
        };

        Ok(Calibration {
            source: name.to_string(),
            pixel_pitch_m: raw.panel.pixel_pitch_um * 1e-6,
            lens_distance_m,
            focal_length_spec_m,
            spec_wavelength_m: raw.lens.spec_wavelength_nm * 1e-9,
            aperture_radius_m,
            material_name: raw.material.name,
            index_at_spec: raw.material.index_at_spec,
            channels,
            design_channel,
            doe_design_pitch_m: raw.doe.design_pitch_um * 1e-6,
            doe_fabrication_pitch_m: raw.doe.fabrication_pitch_um * 1e-6,
            doe_max_height_m: raw.doe.max_height_um * 1e-6,
            doe_file,
            range_d: [lo, hi],
            main_d: raw.depths.main_d,
            intermediate_d: raw.depths.intermediate_d,
            target_blur_psi_rad: raw.target_blur.psi_rad,
            ai_planes_d: raw.ai.planes_d,
            wiener: WienerSettings {
                average_step_d: w.average_step_d,
                ai_k: w.ai_k,
                doe_k: w.doe_k,
                doe_k_tuned_for: w.doe_k_tuned_for.clone(),
            },
            simulation: SimulationSettings {
                window_energy: s.window_energy,
                min_pupil_samples: s.min_pupil_samples,
                max_pupil_samples: s.max_pupil_samples,
                pupil_step_m: (s.pupil_step_um > 0.0).then_some(s.pupil_step_um * 1e-6),
                propagator,
            },
            panel,
        })
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

    /// Defocus coefficient Ψ_λ(D) = (π/λ)(V_λ − D) r² (docs/model.md §4), radians.
    pub fn psi_rad(&self, channel: usize, accommodation_d: f64) -> f64 {
        self.psi_for_vergence(channel, self.vergence_d(channel) - accommodation_d)
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
        };
        let json = serde_json::to_string(&o).unwrap_or_default();
        blake3::hash(json.as_bytes()).to_hex()[..16].to_string()
    }
}

struct Validator<'a> {
    path: &'a str,
}

impl Validator<'_> {
    fn err(&self, field: &str, reason: &str) -> CalibError {
        CalibError::Invalid {
            path: self.path.to_string(),
            field: field.to_string(),
            reason: reason.to_string(),
        }
    }

    fn positive(&self, field: &str, x: f64) -> Result<(), CalibError> {
        if x.is_finite() && x > 0.0 {
            Ok(())
        } else {
            Err(self.err(field, &format!("{x} must be a finite positive number")))
        }
    }

    fn wavelength(&self, field: &str, nm: f64) -> Result<(), CalibError> {
        if nm.is_finite() && (200.0..=2000.0).contains(&nm) {
            Ok(())
        } else {
            Err(self.err(
                field,
                &format!("{nm} nm is not an optical wavelength (200–2000 nm)"),
            ))
        }
    }

    fn index(&self, field: &str, n: f64) -> Result<(), CalibError> {
        if n.is_finite() && n > 1.0 && n < 5.0 {
            Ok(())
        } else {
            Err(self.err(
                field,
                &format!("{n} is not a refractive index of a lens material (1 < n < 5)"),
            ))
        }
    }

    fn depth_list(
        &self,
        field: &str,
        depths: &[f64],
        [lo, hi]: [f64; 2],
        allow_empty: bool,
    ) -> Result<(), CalibError> {
        if depths.is_empty() && !allow_empty {
            return Err(self.err(field, "needs at least one depth"));
        }
        for (i, d) in depths.iter().enumerate() {
            if !d.is_finite() || *d < lo - DEPTH_TOLERANCE_D || *d > hi + DEPTH_TOLERANCE_D {
                return Err(self.err(
                    field,
                    &format!("{d} D lies outside depths.range_d [{lo}, {hi}]"),
                ));
            }
            if i > 0 && *d <= depths[i - 1] {
                return Err(self.err(field, "depths must be strictly increasing"));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
