//! Turning the parsed TOML into a [`Calibration`]: every field checked
//! against its physical meaning, with the file, field and reason named on
//! failure, then resolved once to SI units.

use std::path::Path;

use super::raw::RawCalibration;
use super::*;

impl Calibration {
    pub(super) fn from_raw(
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

        let eye = eye::resolve(&raw.eye, name)?;
        let views = super::views::resolve(&raw.view, (p.width_px, p.height_px), name)?;

        let calib = Calibration {
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
            eye,
            views,
        };
        eye::check_sees_light(&calib, name)?;
        Ok(calib)
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
