//! The diffractive optical element as heights d ≥ 0 (docs/model.md §5): a 2-D
//! map on a square grid centred on the axis, or a radial profile d(ρ) for a
//! rotationally symmetric element (the three-lens DOE, most lens-like
//! designs), which the radial (Hankel) propagator computes ≥ 10× faster.
//! Its phase at any wavelength, the three-lens initialisation, Keys cubic
//! resampling to another grid, and the slope bound used by sampling rule 2.
//! File I/O is in [`super::doe_file`]; the radial profile's own operations
//! in [`radial`].

use std::f64::consts::PI;

use num_complex::Complex64 as c64;
use rayon::prelude::*;

use super::pupil::PupilGrid;
use nedrt_core::calib::Calibration;

mod radial;

/// How a DOE's heights are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Profile {
    /// N×N map: sample (i, j) at t = (i − (N−1)/2)·pitch, s = (j − (N−1)/2)·pitch.
    Map,
    /// Rotationally symmetric: N samples, sample n at ρ = (n + ½)·pitch; the
    /// element is d(√(s² + t²)), Keys cubic between samples with the
    /// half-sample even extension at the axis (so d'(0) = 0).
    Radial,
}

/// A DOE's heights: a 2-D map or a radial profile ([`Profile`]). Heights are
/// metres; a map is row-major (N² values), a profile holds N values.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightMap {
    pub profile: Profile,
    /// N: the map is N×N, the radial profile has N samples.
    pub samples: usize,
    pub pitch_m: f64,
    pub height_m: Vec<f64>,
    /// Fabrication depth: every height lies in [0, max_height_m].
    pub max_height_m: f64,
    /// Number of equally spaced height levels from 0 to max_height_m
    /// inclusive, or 0 for a continuous profile.
    pub levels: u32,
    pub material: String,
    pub design_wavelength_m: f64,
    /// Where it came from ("three-lens initialisation", a file path, …).
    pub description: String,
}

/// The three-lens phase of docs/model.md §5 at normalised radius² `rho2`:
/// arg Σ_i exp(−j Ψ_i ρ²) wrapped to [0, 2π), radians.
fn three_lens_phase(psis: &[f64], rho2: f64) -> f64 {
    let sum: c64 = psis.iter().map(|p| c64::from_polar(1.0, -p * rho2)).sum();
    let phi = sum.arg().rem_euclid(2.0 * PI);
    // rem_euclid can return 2π for −0 round-off; keep [0, 2π).
    if phi >= 2.0 * PI { 0.0 } else { phi }
}

impl HeightMap {
    /// Coordinate of sample `n` of a map along either axis, metres (for a
    /// radial profile see [`HeightMap::radius_m`]).
    pub fn coord_m(&self, n: usize) -> f64 {
        (n as f64 - (self.samples as f64 - 1.0) / 2.0) * self.pitch_m
    }

    /// The map's grid as a pupil grid (same centring convention); for a
    /// radial profile the square grid of the same pitch that reaches its
    /// last sample (2N + 1 samples across).
    pub fn grid(&self) -> PupilGrid {
        PupilGrid {
            samples: match self.profile {
                Profile::Map => self.samples,
                Profile::Radial => 2 * self.samples + 1,
            },
            step_m: self.pitch_m,
        }
    }

    /// The samples of a map (not a radial profile) whose grid coincides with `grid`.
    fn is_on(&self, grid: PupilGrid) -> bool {
        self.profile == Profile::Map
            && grid.samples == self.samples
            && (grid.step_m - self.pitch_m).abs() <= 1e-12 * self.pitch_m
    }

    /// The three-lens initial DOE of docs/model.md §5 on a grid of `pitch_m`:
    /// Φ = arg Σ_i exp(−j Ψ_λ0(D_i) ρ²) over the main depths, wrapped to
    /// [0, 2π), as height d = Φ λ0 / (2π (n_λ0 − 1)).
    pub fn three_lens_init(calib: &Calibration, pitch_m: f64) -> Self {
        let r = calib.aperture_radius_m;
        let samples = map_samples(r, pitch_m);
        let ch = calib.design_channel;
        let psis: Vec<f64> = calib.main_d.iter().map(|&d| calib.psi_rad(ch, d)).collect();
        let wave_height = calib.doe_wave_height_m();
        let mut map = Self {
            profile: Profile::Map,
            samples,
            pitch_m,
            height_m: vec![0.0; samples * samples],
            max_height_m: wave_height,
            levels: 0,
            material: calib.material_name.clone(),
            design_wavelength_m: calib.channels[ch].wavelength_m,
            description: format!(
                "three-lens initialisation for {:?} D at {} nm",
                calib.main_d,
                calib.channels[ch].wavelength_m * 1e9
            ),
        };
        let coords: Vec<f64> = (0..samples).map(|n| map.coord_m(n)).collect();
        map.height_m
            .par_chunks_mut(samples)
            .enumerate()
            .for_each(|(i, row)| {
                for (j, h) in row.iter_mut().enumerate() {
                    let rho2 = (coords[i] * coords[i] + coords[j] * coords[j]) / (r * r);
                    *h = three_lens_phase(&psis, rho2) / (2.0 * PI) * wave_height;
                }
            });
        map
    }

    /// Heights sampled on the square `grid` (Keys bicubic interpolation,
    /// a = −½, with clamped edges, then clamped to [0, max height]: a
    /// fabricated profile cannot leave its depth range). Identity when the
    /// grids coincide. A radial profile is evaluated at each sample's radius.
    pub fn heights_on(&self, grid: PupilGrid) -> Vec<f64> {
        if self.profile == Profile::Radial {
            return self.radial_heights_on(grid);
        }
        if self.is_on(grid) {
            return self.height_m.clone();
        }
        let taps: Vec<[(usize, f64); 4]> = (0..grid.samples)
            .map(|k| {
                keys_taps(
                    grid.coord_m(k) / self.pitch_m + (self.samples as f64 - 1.0) / 2.0,
                    self.samples,
                )
            })
            .collect();
        let n_in = self.samples;
        let n_out = grid.samples;
        // Along s (columns) for every source row, then along t.
        let mut along_s = vec![0.0; n_in * n_out];
        along_s
            .par_chunks_mut(n_out)
            .enumerate()
            .for_each(|(i, row)| {
                let src = &self.height_m[i * n_in..(i + 1) * n_in];
                for (out, t) in row.iter_mut().zip(&taps) {
                    *out = t.iter().map(|&(k, w)| w * src[k]).sum();
                }
            });
        let mut out = vec![0.0; n_out * n_out];
        let max = self.max_height_m;
        out.par_chunks_mut(n_out).enumerate().for_each(|(i, row)| {
            let t = &taps[i];
            for (j, o) in row.iter_mut().enumerate() {
                let v: f64 = t.iter().map(|&(k, w)| w * along_s[k * n_out + j]).sum();
                *o = v.clamp(0.0, max);
            }
        });
        out
    }

    /// The same element resampled (Keys cubic) at `pitch_m` over the same
    /// extent, e.g. the 3 µm fabrication grid: a map stays a map, a radial
    /// profile a radial profile.
    pub fn resampled(&self, pitch_m: f64) -> Self {
        if self.profile == Profile::Radial {
            return self.radial_resampled(pitch_m);
        }
        let half_extent = (self.samples as f64 - 1.0) / 2.0 * self.pitch_m;
        let samples = 2 * (half_extent / pitch_m + 1e-9).floor() as usize + 1;
        let grid = PupilGrid {
            samples,
            step_m: pitch_m,
        };
        Self {
            samples,
            pitch_m,
            height_m: self.heights_on(grid),
            levels: 0,
            description: format!("{} (bicubic to {:.3} µm)", self.description, pitch_m * 1e6),
            ..self.clone()
        }
    }

    /// Phase Φ_λ = 2π (n_λ − 1) d / λ on `grid` for `channel` (paper Eq. 6), radians.
    pub fn phase_on(&self, grid: PupilGrid, calib: &Calibration, channel: usize) -> Vec<f64> {
        let k = calib.doe_phase_per_m(channel);
        let mut h = self.heights_on(grid);
        h.iter_mut().for_each(|v| *v *= k);
        h
    }

    /// Largest slope |∇d| of the smooth part of the profile inside the
    /// aperture (dimensionless, m/m): neighbour differences larger than a
    /// quarter wave at λ0 (a phase step over π/2, which no resolved smooth
    /// profile takes between samples) count as wraps or zone edges.
    pub fn max_smooth_slope(&self, aperture_radius_m: f64, wave_height_m: f64) -> f64 {
        if self.profile == Profile::Radial {
            return self.radial_max_smooth_slope(aperture_radius_m, wave_height_m);
        }
        let n = self.samples;
        let jump = wave_height_m / 4.0;
        let inside =
            |i: usize, j: usize| self.coord_m(i).hypot(self.coord_m(j)) <= aperture_radius_m;
        (0..n.saturating_sub(1))
            .into_par_iter()
            .map(|i| {
                let mut worst: f64 = 0.0;
                for j in 0..n - 1 {
                    if !(inside(i, j) && inside(i + 1, j) && inside(i, j + 1)) {
                        continue;
                    }
                    let h = self.height_m[i * n + j];
                    let dx = self.height_m[i * n + j + 1] - h;
                    let dy = self.height_m[(i + 1) * n + j] - h;
                    let dx = if dx.abs() > jump { 0.0 } else { dx };
                    let dy = if dy.abs() > jump { 0.0 } else { dy };
                    worst = worst.max(dx.hypot(dy) / self.pitch_m);
                }
                worst
            })
            .reduce(|| 0.0, f64::max)
    }

    /// Content hash over everything that shapes the element's optics. A
    /// radial profile hashes differently from a map of the same numbers.
    pub fn content_hash(&self) -> String {
        let mut h = blake3::Hasher::new();
        h.update(match self.profile {
            // The map's prefix predates radial profiles: map hashes (and the
            // calibration's `doe_k_tuned_for`) stay valid.
            Profile::Map => b"nedrt-doe/1".as_slice(),
            Profile::Radial => b"nedrt-doe/1/radial".as_slice(),
        });
        h.update(&(self.samples as u64).to_le_bytes());
        for v in [self.pitch_m, self.max_height_m, self.design_wavelength_m] {
            h.update(&v.to_le_bytes());
        }
        h.update(&self.levels.to_le_bytes());
        h.update(self.material.as_bytes());
        for v in &self.height_m {
            h.update(&v.to_le_bytes());
        }
        h.finalize().to_hex()[..16].to_string()
    }
}

/// Samples of the standard DOE grid of pitch `pitch_m` covering an aperture
/// of radius `radius_m`: N = ⌈2r/p⌉ + 1, so (N − 1)/2·p ≥ r.
pub fn map_samples(radius_m: f64, pitch_m: f64) -> usize {
    (2.0 * radius_m / pitch_m - 1e-9).ceil() as usize + 1
}

/// Keys (1981) cubic convolution kernel with a = −½: interpolating, third-order accurate.
pub fn keys_weight(x: f64) -> f64 {
    let a = -0.5;
    let x = x.abs();
    if x <= 1.0 {
        ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0
    } else if x < 2.0 {
        ((a * x - 5.0 * a) * x + 8.0 * a) * x - 4.0 * a
    } else {
        0.0
    }
}

/// The four (index, weight) taps for fractional source position `u` on `n`
/// samples, indices clamped to the grid (edge extension).
fn keys_taps(u: f64, n: usize) -> [(usize, f64); 4] {
    let base = u.floor();
    let f = u - base;
    let clamp = |k: f64| (k.max(0.0) as usize).min(n - 1);
    [
        (clamp(base - 1.0), keys_weight(1.0 + f)),
        (clamp(base), keys_weight(f)),
        (clamp(base + 1.0), keys_weight(1.0 - f)),
        (clamp(base + 2.0), keys_weight(2.0 - f)),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn calib() -> Calibration {
        Calibration::default_embedded().expect("default calibration")
    }

    #[test]
    fn keys_kernel_interpolates_and_sums_to_one() {
        assert_eq!(keys_weight(0.0), 1.0);
        assert_eq!(keys_weight(1.0), 0.0);
        assert_eq!(keys_weight(2.0), 0.0);
        for f in [0.1, 0.25, 0.5, 0.9] {
            let s: f64 = [1.0 + f, f, 1.0 - f, 2.0 - f]
                .iter()
                .map(|x| keys_weight(*x))
                .sum();
            assert!((s - 1.0).abs() < 1e-14);
        }
    }

    #[test]
    fn bicubic_reproduces_quadratics_exactly() {
        // Keys' a = −½ kernel reproduces polynomials up to degree 2.
        let mut m = HeightMap {
            profile: Profile::Map,
            samples: 41,
            pitch_m: 1e-5,
            height_m: vec![0.0; 41 * 41],
            max_height_m: 10.0,
            levels: 0,
            material: "x".into(),
            design_wavelength_m: 5e-7,
            description: String::new(),
        };
        let f = |s: f64, t: f64| 1.0 + 1e3 * s + 2e3 * t + 1e6 * s * s + 3e6 * s * t;
        for i in 0..41 {
            for j in 0..41 {
                m.height_m[i * 41 + j] = f(m.coord_m(j), m.coord_m(i));
            }
        }
        let fine = m.resampled(0.37e-5);
        for i in 5..fine.samples - 5 {
            for j in 5..fine.samples - 5 {
                let want = f(fine.coord_m(j), fine.coord_m(i));
                assert!(
                    (fine.height_m[i * fine.samples + j] - want).abs() < 1e-12,
                    "{i},{j}"
                );
            }
        }
        // Same grid: identity.
        assert_eq!(m.heights_on(m.grid()), m.height_m);
    }

    #[test]
    fn three_lens_init_puts_light_where_optics_md_says() {
        // The superposition is a binary π grating in ρ² (plus a weak lens):
        // its orders carry |c_k|² = 1/9 (k = 0) and 3/π² ≈ 30.4 % (k = ±1).
        let c = calib();
        let doe = HeightMap::three_lens_init(&c, 6e-6);
        assert!(doe.coord_m(doe.samples - 1) >= c.aperture_radius_m);
        let wave = c.doe_wave_height_m();
        assert!(doe.height_m.iter().all(|h| (0.0..wave).contains(h)));
        // Order weights from the mean of exp(jΦ)·exp(+jΨ_i ρ²) over the aperture.
        let ch = c.design_channel;
        let k = c.doe_phase_per_m(ch);
        let r = c.aperture_radius_m;
        let mut sums = [c64::new(0.0, 0.0); 3];
        let mut count = 0.0;
        for i in 0..doe.samples {
            for j in 0..doe.samples {
                let (s, t) = (doe.coord_m(j), doe.coord_m(i));
                let rho2 = (s * s + t * t) / (r * r);
                if rho2 > 1.0 {
                    continue;
                }
                count += 1.0;
                let phi = k * doe.height_m[i * doe.samples + j];
                for (sum, d) in sums.iter_mut().zip(&c.main_d) {
                    *sum += c64::from_polar(1.0, phi + c.psi_rad(ch, *d) * rho2);
                }
            }
        }
        let eff: Vec<f64> = sums.iter().map(|z| (z / count).norm_sqr()).collect();
        assert!((eff[1] - 1.0 / 9.0).abs() < 0.01, "1.5 D order {}", eff[1]);
        for e in [eff[0], eff[2]] {
            assert!((e - 3.0 / (PI * PI)).abs() < 0.01, "±1 order {e}");
        }
        // Between its π steps the profile is nearly flat: rule 2 is set by the lens.
        assert!(doe.max_smooth_slope(r, wave) < 1e-3);
    }

    #[test]
    fn content_hash_tracks_heights() {
        let c = calib();
        let a = HeightMap::three_lens_init(&c, 50e-6);
        let mut b = a.clone();
        assert_eq!(a.content_hash(), b.content_hash());
        b.height_m[7] += 1e-9;
        assert_ne!(a.content_hash(), b.content_hash());
    }
}
