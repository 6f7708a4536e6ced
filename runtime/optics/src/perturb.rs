//! The display as built (docs/calibration.md, docs/tolerance.md): a DOE
//! and an eyepiece that differ from their design by what fabrication and
//! assembly leave: etch depth, level quantisation, the DOE's decentre on
//! the lens, eye relief, the panel's distance, the primaries' wavelengths.

use serde::{Deserialize, Serialize};

use crate::doe::{HeightMap, Profile, keys_weight};
use crate::spectrum::cauchy_fit;
use nedrt_core::calib::Calibration;

/// A perturbation out of its range, naming the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field} = {value}: {reason}")]
pub struct PerturbError {
    pub field: String,
    pub value: String,
    pub reason: String,
}

/// Errors from the design, each 0 (or 1 for the etch scale) as designed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Perturbation {
    /// Etched depth over the designed depth (1.08: 8 % too deep).
    pub etch_scale: f64,
    /// Height levels the profile was fabricated with (0: continuous, as
    /// designed).
    pub levels: u32,
    /// The DOE's centre from the lens's axis, across and down, mm.
    pub decentre_mm: [f64; 2],
    /// Added to the eye relief, mm.
    pub eye_relief_mm: f64,
    /// Added to the lens-to-panel distance, mm.
    pub panel_distance_mm: f64,
    /// Added to each primary's wavelength, nm (the calibration's order).
    pub primaries_nm: [f64; 3],
    /// Each primary's spectral width, nm (full width at half maximum of
    /// a Gaussian line; 0: one wavelength, as the design assumes).
    #[serde(default)]
    pub bandwidths_nm: [f64; 3],
}

/// Gauss–Hermite nodes and weights (5 points, weights over √π): the mean
/// over a Gaussian spectrum, exact for a PSF polynomial of degree 9 in the
/// wavelength.
const HERMITE_NODES: [(f64, f64); 5] = [
    (
        -2.020_182_870_456_086,
        0.019_953_242_059_045_9 / 1.772_453_850_905_516,
    ),
    (
        -0.958_572_464_613_819,
        0.393_619_323_152_241 / 1.772_453_850_905_516,
    ),
    (0.0, 0.945_308_720_482_942 / 1.772_453_850_905_516),
    (
        0.958_572_464_613_819,
        0.393_619_323_152_241 / 1.772_453_850_905_516,
    ),
    (
        2.020_182_870_456_086,
        0.019_953_242_059_045_9 / 1.772_453_850_905_516,
    ),
];

impl Default for Perturbation {
    fn default() -> Self {
        Self {
            etch_scale: 1.0,
            levels: 0,
            decentre_mm: [0.0; 2],
            eye_relief_mm: 0.0,
            panel_distance_mm: 0.0,
            primaries_nm: [0.0; 3],
            bandwidths_nm: [0.0; 3],
        }
    }
}

impl Perturbation {
    pub fn is_nominal(&self) -> bool {
        *self == Self::default()
    }

    /// Checks each field's range; the error names the field.
    pub fn check(&self) -> Result<(), PerturbError> {
        let bad = |field: &str, v: String, why: &str| {
            Err(PerturbError {
                field: field.into(),
                value: v,
                reason: why.into(),
            })
        };
        if !(self.etch_scale.is_finite() && (0.5..=1.5).contains(&self.etch_scale)) {
            return bad(
                "etch_scale",
                self.etch_scale.to_string(),
                "must lie in [0.5, 1.5]",
            );
        }
        if self.levels == 1 || self.levels > 256 {
            return bad(
                "levels",
                self.levels.to_string(),
                "must be 0 (continuous) or 2 to 256",
            );
        }
        if self
            .decentre_mm
            .iter()
            .any(|d| !(d.is_finite() && d.abs() <= 2.0))
        {
            return bad(
                "decentre_mm",
                format!("{:?}", self.decentre_mm),
                "each must lie in [−2, 2] mm",
            );
        }
        if !(self.eye_relief_mm.is_finite() && self.eye_relief_mm.abs() <= 20.0) {
            return bad(
                "eye_relief_mm",
                self.eye_relief_mm.to_string(),
                "must lie in [−20, 20] mm",
            );
        }
        if !(self.panel_distance_mm.is_finite() && self.panel_distance_mm.abs() <= 2.0) {
            return bad(
                "panel_distance_mm",
                self.panel_distance_mm.to_string(),
                "must lie in [−2, 2] mm",
            );
        }
        if self
            .primaries_nm
            .iter()
            .any(|d| !(d.is_finite() && d.abs() <= 50.0))
        {
            return bad(
                "primaries_nm",
                format!("{:?}", self.primaries_nm),
                "each must lie in [−50, 50] nm",
            );
        }
        if self
            .bandwidths_nm
            .iter()
            .any(|w| !(w.is_finite() && (0.0..=60.0).contains(w)))
        {
            return bad(
                "bandwidths_nm",
                format!("{:?}", self.bandwidths_nm),
                "each must lie in [0, 60] nm (FWHM)",
            );
        }
        Ok(())
    }

    /// The spectrum as single-wavelength displays to average: (weight,
    /// the same perturbation with each primary moved to a node of its
    /// Gaussian line and no bandwidth). One node, weight 1, for lines.
    pub fn spectral_nodes(&self) -> Vec<(f64, Perturbation)> {
        let line = Perturbation {
            bandwidths_nm: [0.0; 3],
            ..*self
        };
        if self.bandwidths_nm == [0.0; 3] {
            return vec![(1.0, line)];
        }
        HERMITE_NODES
            .iter()
            .map(|&(t, w)| {
                let mut p = line;
                for (shift, fwhm) in p.primaries_nm.iter_mut().zip(self.bandwidths_nm) {
                    // σ = FWHM / (2√(2 ln 2)); the node at √2·σ·t.
                    *shift +=
                        std::f64::consts::SQRT_2 * fwhm / (2.0 * (2.0 * 2f64.ln()).sqrt()) * t;
                }
                (w, p)
            })
            .collect()
    }

    /// One line naming what differs from the design.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if self.etch_scale != 1.0 {
            parts.push(format!("etch {:+.1} %", (self.etch_scale - 1.0) * 100.0));
        }
        if self.levels != 0 {
            parts.push(format!("{} levels", self.levels));
        }
        if self.decentre_mm != [0.0; 2] {
            parts.push(format!(
                "decentre ({}, {}) mm",
                self.decentre_mm[0], self.decentre_mm[1]
            ));
        }
        if self.eye_relief_mm != 0.0 {
            parts.push(format!("eye relief {:+} mm", self.eye_relief_mm));
        }
        if self.panel_distance_mm != 0.0 {
            parts.push(format!("panel distance {:+} mm", self.panel_distance_mm));
        }
        if self.primaries_nm != [0.0; 3] {
            parts.push(format!("primaries {:+?} nm", self.primaries_nm));
        }
        if self.bandwidths_nm != [0.0; 3] {
            parts.push(format!("bandwidths {:?} nm FWHM", self.bandwidths_nm));
        }
        if parts.is_empty() {
            "as designed".into()
        } else {
            parts.join(", ")
        }
    }

    /// The fabricated DOE: the design's profile quantised to `levels` per
    /// wave (`wave_height_m`, the height of one wave at the design
    /// wavelength: the profile is first wrapped to one wave, which changes
    /// nothing at that wavelength, then rounded to `levels` equal steps of
    /// it, a whole wave being none: a multilevel element one wave deep, as
    /// it is fabricated, whatever the depth the design's optimiser was
    /// allowed), etched `etch_scale` deep, and
    /// shifted by the decentre (flat substrate, height 0, where the shifted
    /// map leaves the aperture uncovered). A radial profile stays radial
    /// (its PSFs come from the Hankel transform, a small fraction of a 2-D
    /// map's time and memory) unless decentred, when it becomes a map.
    pub fn doe(&self, design: &HeightMap, wave_height_m: f64) -> HeightMap {
        let decentred = self.decentre_mm != [0.0; 2];
        let mut map = if design.profile == Profile::Radial && decentred {
            let grid = design.grid();
            HeightMap {
                profile: Profile::Map,
                samples: grid.samples,
                height_m: design.heights_on(grid),
                ..design.clone()
            }
        } else {
            design.clone()
        };
        if self.levels >= 2 {
            let step = wave_height_m / self.levels as f64;
            let levels = self.levels as f64;
            map.height_m.iter_mut().for_each(|h| {
                let q = (h.rem_euclid(wave_height_m) / step).round();
                *h = if q >= levels { 0.0 } else { q * step };
            });
            map.levels = self.levels;
            // The format's levels run from 0 to the depth inclusive
            // (docs/doe-format.md): the top one is a step short of a wave.
            map.max_height_m = wave_height_m * (levels - 1.0) / levels;
        }
        if self.etch_scale != 1.0 {
            map.height_m.iter_mut().for_each(|h| *h *= self.etch_scale);
            map.max_height_m *= self.etch_scale;
        }
        if decentred {
            map.height_m = shifted(&map, self.decentre_mm[0] * 1e-3, self.decentre_mm[1] * 1e-3);
        }
        map.description = format!("{} as built ({})", design.description, self.describe());
        map
    }

    /// The calibration of the built eyepiece: eye relief, panel distance and
    /// the primaries moved (each index from the glass's Cauchy fit, its
    /// residual at the design wavelength kept).
    pub fn calibration(&self, design: &Calibration) -> Calibration {
        let mut c = design.clone();
        c.eye.relief_m += self.eye_relief_mm * 1e-3;
        c.lens_distance_m += self.panel_distance_mm * 1e-3;
        let (a, b) = cauchy_fit(design);
        for (ch, d_nm) in c.channels.iter_mut().zip(self.primaries_nm) {
            if d_nm == 0.0 {
                continue;
            }
            let residual = ch.index - (a + b / ch.wavelength_m.powi(2));
            ch.wavelength_m += d_nm * 1e-9;
            ch.index = a + b / ch.wavelength_m.powi(2) + residual;
        }
        if !self.is_nominal() {
            c.source = format!("{} as built ({})", design.source, self.describe());
        }
        c
    }
}

/// A map's heights moved by (dx, dy) metres (across = columns, down =
/// rows), Keys cubic between samples, 0 beyond the map.
fn shifted(map: &HeightMap, dx_m: f64, dy_m: f64) -> Vec<f64> {
    let n = map.samples;
    let taps = |shift_m: f64| -> Vec<Vec<(usize, f64)>> {
        (0..n)
            .map(|k| {
                let u = k as f64 - shift_m / map.pitch_m;
                let base = u.floor();
                (-1..=2)
                    .filter_map(|o| {
                        let src = base + o as f64;
                        let w = keys_weight(u - src);
                        (src >= 0.0 && src < n as f64 && w != 0.0).then_some((src as usize, w))
                    })
                    .collect()
            })
            .collect()
    };
    let (tx, ty) = (taps(dx_m), taps(dy_m));
    let max = map.max_height_m;
    let mut out = vec![0.0; n * n];
    for (i, row) in out.chunks_mut(n).enumerate() {
        for (j, o) in row.iter_mut().enumerate() {
            let v: f64 = ty[i]
                .iter()
                .map(|&(si, wi)| {
                    tx[j]
                        .iter()
                        .map(|&(sj, wj)| wj * map.height_m[si * n + sj])
                        .sum::<f64>()
                        * wi
                })
                .sum();
            *o = v.clamp(0.0, max);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn design() -> (Calibration, HeightMap) {
        let c = Calibration::default_embedded().expect("calib");
        let m = HeightMap::three_lens_init(&c, 60e-6);
        (c, m)
    }

    #[test]
    fn a_radial_profile_stays_radial_unless_decentred() {
        let (_, m) = design();
        let radial = HeightMap {
            profile: Profile::Radial,
            samples: 50,
            height_m: (0..50).map(|i| m.max_height_m * i as f64 / 50.0).collect(),
            ..m.clone()
        };
        let built = Perturbation {
            levels: 4,
            etch_scale: 1.05,
            ..Default::default()
        }
        .doe(&radial, radial.max_height_m);
        assert_eq!((built.profile, built.samples), (Profile::Radial, 50));
        let step = radial.max_height_m / 4.0 * 1.05;
        for h in &built.height_m {
            let q = h / step;
            assert!((q - q.round()).abs() < 1e-9 && q.round() < 4.0, "{h}");
        }
        let moved = Perturbation {
            decentre_mm: [0.01, 0.0],
            ..Default::default()
        }
        .doe(&radial, radial.max_height_m);
        assert_eq!(moved.profile, Profile::Map);
    }

    #[test]
    fn levels_are_steps_of_one_wave_whatever_depth_the_design_was_allowed() {
        // The shipped companion DOE: a profile 1.24 waves deep in an element
        // allowed 3 µm (2.6 waves). Its 8 levels are eighths of a wave, not
        // of 3 µm, and heights a whole wave apart are the same level.
        let (c, m) = design();
        let wave = c.doe_wave_height_m();
        let deep = HeightMap {
            profile: Profile::Radial,
            samples: 6,
            height_m: [0.0, 0.3, 0.6, 1.0, 1.1, 1.24].map(|w| w * wave).to_vec(),
            max_height_m: 2.6 * wave,
            ..m
        };
        let built = Perturbation {
            levels: 8,
            ..Default::default()
        }
        .doe(&deep, wave);
        let eighths: Vec<f64> = built.height_m.iter().map(|h| h / wave * 8.0).collect();
        let want = [0.0, 2.0, 5.0, 0.0, 1.0, 2.0];
        for (got, want) in eighths.iter().zip(want) {
            assert!((got - want).abs() < 1e-9, "{eighths:?}");
        }
        assert_eq!(built.levels, 8);
        assert!((built.max_height_m - 7.0 / 8.0 * wave).abs() < 1e-18);
        // At the design wavelength the phase of each sample moves by at
        // most half a step.
        for (a, b) in deep.height_m.iter().zip(&built.height_m) {
            let d = ((a - b) / wave).rem_euclid(1.0);
            assert!(d.min(1.0 - d) <= 0.5 / 8.0 + 1e-12, "{a} → {b}");
        }
    }

    #[test]
    fn nominal_is_the_design() {
        let (c, m) = design();
        let p = Perturbation::default();
        assert!(p.check().is_ok());
        assert_eq!(p.doe(&m, c.doe_wave_height_m()).height_m, m.height_m);
        assert_eq!(p.calibration(&c), c);
    }

    #[test]
    fn levels_etch_and_decentre_do_what_they_say() {
        let (c, m) = design();
        let p = Perturbation {
            levels: 4,
            etch_scale: 1.1,
            ..Default::default()
        };
        let built = p.doe(&m, c.doe_wave_height_m());
        let step = m.max_height_m / 4.0 * 1.1;
        for h in &built.height_m {
            let q = h / step;
            assert!((q - q.round()).abs() < 1e-9 && q.round() < 4.0, "{h}");
        }
        // 4 levels from 0 to ¾ of a wave, etched 1.1 deep.
        assert!((built.max_height_m - 1.1 * 0.75 * m.max_height_m).abs() < 1e-15);
        // A decentre of whole samples moves the map by as many samples.
        let shift = Perturbation {
            decentre_mm: [3.0 * m.pitch_m * 1e3, 0.0],
            ..Default::default()
        }
        .doe(&m, c.doe_wave_height_m());
        let n = m.samples;
        let mid = n / 2;
        for j in 3..n {
            let (a, b) = (shift.height_m[mid * n + j], m.height_m[mid * n + j - 3]);
            assert!((a - b).abs() < 1e-12 * m.max_height_m, "column {j}");
        }
        assert!(
            shift.height_m[mid * n..mid * n + 2]
                .iter()
                .all(|h| *h == 0.0)
        );
        let moved = Perturbation {
            primaries_nm: [5.0, 0.0, -5.0],
            panel_distance_mm: 0.1,
            ..Default::default()
        }
        .calibration(&c);
        assert!(moved.channels[0].wavelength_m > c.channels[0].wavelength_m);
        assert!(moved.channels[0].index < c.channels[0].index);
        assert_eq!(moved.channels[1], c.channels[1]);
        assert!((moved.lens_distance_m - c.lens_distance_m - 1e-4).abs() < 1e-12);
        let wide = Perturbation {
            bandwidths_nm: [20.0, 0.0, 30.0],
            ..Default::default()
        };
        let nodes = wide.spectral_nodes();
        assert_eq!(nodes.len(), 5);
        let total: f64 = nodes.iter().map(|(w, _)| w).sum();
        assert!((total - 1.0).abs() < 1e-12, "{total}");
        // The nodes' spread is the line's: variance σ² = (FWHM/2.3548)².
        let var: f64 = nodes
            .iter()
            .map(|(w, p)| w * p.primaries_nm[0].powi(2))
            .sum();
        assert!((var.sqrt() - 20.0 / 2.354_820_045).abs() < 1e-9, "{var}");
        assert!(
            nodes
                .iter()
                .all(|(_, p)| p.primaries_nm[1] == 0.0 && p.bandwidths_nm == [0.0; 3])
        );
        assert_eq!(Perturbation::default().spectral_nodes().len(), 1);
        assert!(
            Perturbation {
                bandwidths_nm: [0.0, -1.0, 0.0],
                ..Default::default()
            }
            .check()
            .is_err_and(|e| e.field == "bandwidths_nm")
        );
        assert!(
            Perturbation {
                levels: 1,
                ..Default::default()
            }
            .check()
            .is_err_and(|e| e.field == "levels")
        );
    }
}
