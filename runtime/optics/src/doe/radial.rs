//! Radial DOE profiles: d(ρ) sampled at ρ_n = (n + ½)·pitch, n = 0…N−1.
//! Between samples the element is the Keys cubic (a = −½) through them, with
//! the half-sample even extension at the axis (sample −1−k mirrors sample k,
//! so the surface is smooth there, d'(0) = 0) and clamped beyond the last
//! sample; values are clamped to [0, max height] like the 2-D map's.
//! A profile converts to the 2-D map it describes ([`HeightMap::to_map`]) so
//! the 2-D path can simulate the same element.

use super::*;

/// The four (sample index, weight) Keys taps at radius ρ = `u_pitches`·pitch
/// of a profile of `n` samples: fractional index u − ½, even extension at the
/// axis, clamped at the far end.
fn radial_taps(u_pitches: f64, n: usize) -> [(usize, f64); 4] {
    let x = u_pitches - 0.5;
    let base = x.floor();
    let f = x - base;
    let index = |k: f64| {
        let k = if k < 0.0 { -1.0 - k } else { k };
        (k as usize).min(n - 1)
    };
    [
        (index(base - 1.0), keys_weight(1.0 + f)),
        (index(base), keys_weight(f)),
        (index(base + 1.0), keys_weight(1.0 - f)),
        (index(base + 2.0), keys_weight(2.0 - f)),
    ]
}

impl HeightMap {
    /// Radius of sample `n` of a radial profile, (n + ½)·pitch, metres.
    pub fn radius_m(&self, n: usize) -> f64 {
        (n as f64 + 0.5) * self.pitch_m
    }

    /// The three-lens initial DOE of docs/model.md §5 as a radial profile of
    /// pitch `pitch_m`: N = ⌈r/p⌉ samples at (n + ½)·p (N·p ≥ r), each the
    /// wrapped phase arg Σ_i exp(−j Ψ_λ0(D_i) ρ²) as a height. The same
    /// element as [`HeightMap::three_lens_init`], rotationally symmetric by
    /// construction.
    pub fn three_lens_radial(calib: &Calibration, pitch_m: f64) -> Self {
        let r = calib.aperture_radius_m;
        let samples = (r / pitch_m - 1e-9).ceil().max(1.0) as usize;
        let ch = calib.design_channel;
        let psis: Vec<f64> = calib.main_d.iter().map(|&d| calib.psi_rad(ch, d)).collect();
        let wave_height = calib.doe_wave_height_m();
        let height_m = (0..samples)
            .map(|n| {
                let rho = (n as f64 + 0.5) * pitch_m / r;
                three_lens_phase(&psis, rho * rho) / (2.0 * PI) * wave_height
            })
            .collect();
        Self {
            profile: Profile::Radial,
            samples,
            pitch_m,
            height_m,
            max_height_m: wave_height,
            levels: 0,
            material: calib.material_name.clone(),
            design_wavelength_m: calib.channels[ch].wavelength_m,
            description: format!(
                "three-lens initialisation (radial) for {:?} D at {} nm",
                calib.main_d,
                calib.channels[ch].wavelength_m * 1e9
            ),
        }
    }

    /// Heights of a radial profile at `radii_m` (Keys cubic, see the module
    /// doc), metres; `None` for a 2-D map, which is not rotationally
    /// symmetric. Identity at the profile's own sample radii.
    pub fn heights_at_radii(&self, radii_m: &[f64]) -> Option<Vec<f64>> {
        (self.profile == Profile::Radial).then(|| {
            radii_m
                .par_iter()
                .map(|&rho| self.radial_height(rho))
                .collect()
        })
    }

    /// Phase Φ_λ = 2π (n_λ − 1) d / λ of a radial profile at `radii_m` for
    /// `channel` (paper Eq. 6), radians; `None` for a 2-D map.
    pub fn phase_at_radii(
        &self,
        radii_m: &[f64],
        calib: &Calibration,
        channel: usize,
    ) -> Option<Vec<f64>> {
        let k = calib.doe_phase_per_m(channel);
        self.heights_at_radii(radii_m)
            .map(|h| h.into_iter().map(|v| v * k).collect())
    }

    /// The element as a 2-D map on the standard DOE grid of pitch `pitch_m`
    /// for an aperture of radius `radius_m` (N = ⌈2r/p⌉ + 1): for a radial
    /// profile h(s, t) = d(√(s² + t²)), for a map its bicubic resampling.
    pub fn to_map(&self, pitch_m: f64, radius_m: f64) -> Self {
        let grid = PupilGrid {
            samples: map_samples(radius_m, pitch_m),
            step_m: pitch_m,
        };
        let same = self.is_on(grid);
        Self {
            profile: Profile::Map,
            samples: grid.samples,
            pitch_m,
            height_m: self.heights_on(grid),
            levels: if same { self.levels } else { 0 },
            description: if same {
                self.description.clone()
            } else {
                format!("{} (2-D map at {:.3} µm)", self.description, pitch_m * 1e6)
            },
            ..self.clone()
        }
    }

    /// One height of a radial profile at radius `rho_m`, clamped to [0, max].
    fn radial_height(&self, rho_m: f64) -> f64 {
        let taps = radial_taps(rho_m / self.pitch_m, self.samples);
        let v: f64 = taps.iter().map(|&(k, w)| w * self.height_m[k]).sum();
        v.clamp(0.0, self.max_height_m)
    }

    /// A radial profile evaluated on a square grid: d(√(s² + t²)).
    pub(super) fn radial_heights_on(&self, grid: PupilGrid) -> Vec<f64> {
        let n = grid.samples;
        let mut out = vec![0.0; n * n];
        out.par_chunks_mut(n).enumerate().for_each(|(i, row)| {
            let t = grid.coord_m(i);
            for (j, h) in row.iter_mut().enumerate() {
                *h = self.radial_height(grid.coord_m(j).hypot(t));
            }
        });
        out
    }

    /// A radial profile at another pitch over (at least) the same extent:
    /// N' = ⌈N·p / p'⌉ samples, so N'·p' ≥ N·p still covers the aperture.
    pub(super) fn radial_resampled(&self, pitch_m: f64) -> Self {
        let samples = (self.samples as f64 * self.pitch_m / pitch_m - 1e-9)
            .ceil()
            .max(1.0) as usize;
        let radii: Vec<f64> = (0..samples).map(|n| (n as f64 + 0.5) * pitch_m).collect();
        let same = samples == self.samples && (pitch_m - self.pitch_m).abs() <= 1e-12 * pitch_m;
        Self {
            samples,
            pitch_m,
            height_m: if same {
                self.height_m.clone()
            } else {
                radii.iter().map(|&r| self.radial_height(r)).collect()
            },
            levels: if same { self.levels } else { 0 },
            description: if same {
                self.description.clone()
            } else {
                format!("{} (cubic to {:.3} µm)", self.description, pitch_m * 1e6)
            },
            ..self.clone()
        }
    }

    /// Rule 2's slope bound of a radial profile: the largest |Δd|/pitch
    /// between neighbours inside the aperture, steps over a quarter wave
    /// counting as zone edges (as for maps).
    pub(super) fn radial_max_smooth_slope(
        &self,
        aperture_radius_m: f64,
        wave_height_m: f64,
    ) -> f64 {
        let jump = wave_height_m / 4.0;
        self.height_m
            .windows(2)
            .enumerate()
            .take_while(|(n, _)| self.radius_m(n + 1) <= aperture_radius_m)
            .map(|(_, w)| (w[1] - w[0]).abs())
            .filter(|d| *d <= jump)
            .fold(0.0, f64::max)
            / self.pitch_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn calib() -> Calibration {
        Calibration::default_embedded().expect("default calibration")
    }

    fn profile(samples: usize, pitch_m: f64, f: impl Fn(f64) -> f64) -> HeightMap {
        HeightMap {
            profile: Profile::Radial,
            samples,
            pitch_m,
            height_m: (0..samples)
                .map(|n| f((n as f64 + 0.5) * pitch_m))
                .collect(),
            max_height_m: 1e3,
            levels: 0,
            material: "x".into(),
            design_wavelength_m: 5e-7,
            description: String::new(),
        }
    }

    #[test]
    fn keys_radial_reproduces_even_quadratics_and_interpolates() {
        // An even quadratic a + bρ² is reproduced exactly, across the axis
        // too (the even extension is exact for it), and samples are kept.
        let f = |rho: f64| 1.0 + 3e4 * rho * rho;
        let p = profile(40, 1e-3, f);
        let radii: Vec<f64> = (0..200).map(|k| k as f64 * 0.173e-3).collect();
        let got = p.heights_at_radii(&radii).expect("radial");
        for (r, h) in radii.iter().zip(&got) {
            if *r < 37e-3 {
                assert!(
                    (h - f(*r)).abs() < 1e-9 * f(*r),
                    "ρ = {r}: {h} vs {}",
                    f(*r)
                );
            }
        }
        let own: Vec<f64> = (0..40).map(|n| p.radius_m(n)).collect();
        assert_eq!(p.heights_at_radii(&own).expect("radial"), p.height_m);
        // At the axis the taps mirror: 9/8·d0 − 1/8·d1 for any profile.
        let q = profile(8, 1e-3, |r| (r * 1e3).sin().abs());
        let at0 = q.heights_at_radii(&[0.0]).expect("radial")[0];
        assert!((at0 - (1.125 * q.height_m[0] - 0.125 * q.height_m[1])).abs() < 1e-15);
        // A map has no radial heights.
        assert!(
            HeightMap::three_lens_init(&calib(), 400e-6)
                .heights_at_radii(&[0.0])
                .is_none()
        );
    }

    #[test]
    fn three_lens_radial_is_the_map_along_a_radius() {
        let c = calib();
        let radial = HeightMap::three_lens_radial(&c, 6e-6);
        assert!(radial.samples as f64 * radial.pitch_m >= c.aperture_radius_m);
        assert!((radial.samples - 1) as f64 * radial.pitch_m < c.aperture_radius_m);
        // The standard map at the same pitch holds the same formula at
        // √(s² + t²); where a map sample's radius is a profile sample's
        // radius the heights agree.
        let wave = c.doe_wave_height_m();
        assert!(radial.height_m.iter().all(|h| (0.0..wave).contains(h)));
        let map = radial.to_map(6e-6, c.aperture_radius_m);
        let init = HeightMap::three_lens_init(&c, 6e-6);
        assert_eq!(map.samples, init.samples);
        assert_eq!(map.profile, Profile::Map);
        // Where the four profile samples around a radius lie in one zone
        // (no step over a quarter wave), the map is the formula there.
        let n = map.samples;
        let mut compared = 0usize;
        for i in 0..n {
            for j in 0..n {
                let rho = map.coord_m(i).hypot(map.coord_m(j));
                let taps = radial_taps(rho / radial.pitch_m, radial.samples);
                let hs: Vec<f64> = taps.iter().map(|t| radial.height_m[t.0]).collect();
                let spread = hs.iter().cloned().fold(f64::MIN, f64::max)
                    - hs.iter().cloned().fold(f64::MAX, f64::min);
                if spread < wave / 4.0 && rho < c.aperture_radius_m {
                    compared += 1;
                    let (a, b) = (map.height_m[i * n + j], init.height_m[i * n + j]);
                    assert!((a - b).abs() < 1e-3 * wave, "{i},{j}: {a} vs {b}");
                }
            }
        }
        assert!(compared > n * n / 2, "{compared} of {}", n * n);
        assert_ne!(radial.content_hash(), init.content_hash());
        // Rule 2 sees the same nearly flat zones.
        assert!(radial.max_smooth_slope(c.aperture_radius_m, wave) < 1e-3);
    }

    #[test]
    fn radial_resampling_keeps_the_extent_and_the_surface() {
        let f = |rho: f64| 2.0 + 1e4 * rho * rho;
        let p = profile(50, 6e-3, f);
        let fine = p.resampled(2.5e-3);
        assert_eq!(fine.profile, Profile::Radial);
        assert!(fine.samples as f64 * fine.pitch_m >= 50.0 * 6e-3);
        for n in 0..fine.samples {
            let r = fine.radius_m(n);
            if r < 47.0 * 6e-3 {
                assert!((fine.height_m[n] - f(r)).abs() < 1e-9 * f(r));
            }
        }
        assert_eq!(p.resampled(6e-3), p, "same pitch: identity");
        // The radial hash differs from a map's of the same numbers.
        let mut as_map = p.clone();
        as_map.profile = Profile::Map;
        assert_ne!(p.content_hash(), as_map.content_hash());
    }

    #[test]
    fn to_map_evaluates_the_profile_at_each_radius() {
        let f = |rho: f64| 1.0 + 1e4 * rho * rho;
        let p = profile(30, 1e-3, f);
        let map = p.to_map(0.7e-3, 25e-3);
        assert_eq!(map.samples, map_samples(25e-3, 0.7e-3));
        for i in 0..map.samples {
            for j in 0..map.samples {
                let rho = map.coord_m(i).hypot(map.coord_m(j));
                if rho < 28e-3 {
                    let h = map.height_m[i * map.samples + j];
                    assert!((h - f(rho)).abs() < 1e-9 * f(rho), "{i},{j}");
                }
            }
        }
    }
}
