//! The generalised pupil function Q(s, t) = A · exp(jΦ) · exp(jΨρ²) (paper
//! Eq. 2, docs/model.md §4) sampled on a square grid centred on the optical axis.

use num_complex::Complex64 as c64;
use rayon::prelude::*;

use nedrt_core::calib::EyeStop;

/// Square pupil sampling grid centred on the axis: sample `n` of either axis
/// lies at s_n = (n − (N − 1)/2) · Δs metres. Arrays on it are row-major,
/// rows along t (y), columns along s (x).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PupilGrid {
    pub samples: usize,
    pub step_m: f64,
}

impl PupilGrid {
    /// The smallest grid of pitch `step_m` that holds an aperture of radius
    /// `radius_m` together with its anti-aliased edge (which reaches Δs/2 past r).
    pub fn covering(radius_m: f64, step_m: f64) -> Self {
        let samples = (2.0 * radius_m / step_m).ceil() as usize + 2;
        Self { samples, step_m }
    }

    /// Coordinate of sample `n` along either axis, metres.
    pub fn coord_m(&self, n: usize) -> f64 {
        (n as f64 - (self.samples as f64 - 1.0) / 2.0) * self.step_m
    }
}

/// Amplitude transmission of a circular aperture of radius `radius_m` for a
/// pupil sample at radius `rho_m` on a grid of pitch `step_m`: the linear
/// ramp clamp((r − ρ)/Δs + ½, 0, 1), the first-order area fraction of the
/// sample's cell inside the circle. It keeps the aperture's area (and so the
/// Airy scale and the MTF) right to O(Δs²) instead of the O(Δs) of a hard
/// 0/1 edge. The trainer implements the same formula (docs/optics-model.md).
pub fn aperture_amplitude(rho_m: f64, radius_m: f64, step_m: f64) -> f64 {
    ((radius_m - rho_m) / step_m + 0.5).clamp(0.0, 1.0)
}

/// Samples Q = A · exp(j(Φ + Ψ ρ²)), ρ² = (s² + t²)/r², on `grid`.
/// `doe_phase_rad` (row-major on the same grid) is the DOE's phase Φ_λ, or
/// `None` for the lens alone. Returns N×N complex samples (dimensionless).
pub fn pupil_field(
    grid: PupilGrid,
    radius_m: f64,
    psi_rad: f64,
    doe_phase_rad: Option<&[f64]>,
) -> Vec<c64> {
    let n = grid.samples;
    if let Some(phase) = doe_phase_rad {
        assert_eq!(
            phase.len(),
            n * n,
            "DOE phase must be sampled on the pupil grid"
        );
    }
    let mut q = vec![c64::new(0.0, 0.0); n * n];
    let r2 = radius_m * radius_m;
    q.par_chunks_mut(n).enumerate().for_each(|(i, row)| {
        let t = grid.coord_m(i);
        for (j, out) in row.iter_mut().enumerate() {
            let s = grid.coord_m(j);
            let rho2 = s * s + t * t;
            let a = aperture_amplitude(rho2.sqrt(), radius_m, grid.step_m);
            if a > 0.0 {
                let phi = psi_rad * rho2 / r2 + doe_phase_rad.map_or(0.0, |p| p[i * n + j]);
                *out = c64::from_polar(a, phi);
            }
        }
    });
    q
}

/// [`pupil_field`] through the eye's pupil as well (docs/model.md §4a): the
/// aperture is the eyepiece's disk times the eye stop's (each with the
/// linear-ramp edge), and the defocus is centred on the stop's centre,
/// Ψ |s − c|²/r², since the eye focuses about its own pupil.
///
/// Only the stop's square of `grid` is returned, as a grid of its own
/// centred on the axis (`grid`'s step, 2⌈r_e/Δs⌉ + 5 samples): the far
/// field's intensity does not change when the pupil is translated, and the
/// smaller grid is what the propagator's cost grows with (a 4 mm pupil's
/// square is 6× fewer samples than the 10 mm aperture's). `doe_phase_rad`
/// is on `grid`; samples of the square beyond `grid` lie outside the
/// aperture (zero).
pub fn pupil_field_through(
    grid: PupilGrid,
    radius_m: f64,
    psi_rad: f64,
    doe_phase_rad: Option<&[f64]>,
    stop: EyeStop,
) -> (Vec<c64>, PupilGrid) {
    let n = grid.samples;
    if let Some(phase) = doe_phase_rad {
        assert_eq!(
            phase.len(),
            n * n,
            "DOE phase must be sampled on the pupil grid"
        );
    }
    let square = stop_square(grid.step_m, stop);
    let side = square.samples;
    let half = (side / 2) as isize;
    let mid = (n as f64 - 1.0) / 2.0;
    // The square's first sample, in `grid`'s indices (may lie outside it).
    // On the axis the rows stay where they always were (floor of the middle).
    let row0 = if stop.centre_y_m == 0.0 {
        mid.floor() as isize
    } else {
        (stop.centre_y_m / grid.step_m + mid).round() as isize
    } - half;
    let col0 = (stop.centre_m / grid.step_m + mid).round() as isize - half;
    let r2 = radius_m * radius_m;
    let mut q = vec![c64::new(0.0, 0.0); side * side];
    q.par_chunks_mut(side).enumerate().for_each(|(i, row)| {
        let gi = row0 + i as isize;
        if gi < 0 || gi >= n as isize {
            return;
        }
        let t = grid.coord_m(gi as usize);
        for (j, out) in row.iter_mut().enumerate() {
            let gj = col0 + j as isize;
            if gj < 0 || gj >= n as isize {
                continue;
            }
            let s = grid.coord_m(gj as usize);
            let a = aperture_amplitude(s.hypot(t), radius_m, grid.step_m);
            let seen = (s - stop.centre_m).hypot(t - stop.centre_y_m);
            let a = a * aperture_amplitude(seen, stop.radius_m, grid.step_m);
            if a > 0.0 {
                let k = gi as usize * n + gj as usize;
                let phi = psi_rad * seen * seen / r2 + doe_phase_rad.map_or(0.0, |p| p[k]);
                *out = c64::from_polar(a, phi);
            }
        }
    });
    (q, square)
}

/// The square of step `step_m` that [`pupil_field_through`] computes for
/// `stop`: 2⌈r_e/Δs⌉ + 5 samples, the stop and its ramped edge with a
/// sample to spare each side.
pub fn stop_square(step_m: f64, stop: EyeStop) -> PupilGrid {
    PupilGrid {
        samples: 2 * (stop.radius_m / step_m).ceil() as usize + 5,
        step_m,
    }
}

/// Σ|Q|² over the grid: the light through the aperture, in units of one
/// sample's worth (multiply by Δs² for m²).
pub fn pupil_energy(q: &[c64]) -> f64 {
    q.par_iter().map(|z| z.norm_sqr()).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_is_centred_and_covers_the_edge() {
        let g = PupilGrid::covering(5e-3, 6e-6);
        assert!((g.coord_m(0) + g.coord_m(g.samples - 1)).abs() < 1e-15);
        assert!(g.coord_m(g.samples - 1) >= 5e-3 + 3e-6);
    }

    #[test]
    fn aperture_area_is_right_to_second_order() {
        // Σ A Δs² against πr² on a coarse grid: the ramp edge keeps the area.
        let r = 5e-3;
        for samples_across in [64.0, 256.0] {
            let g = PupilGrid::covering(r, 2.0 * r / samples_across);
            let mut area = 0.0;
            for i in 0..g.samples {
                for j in 0..g.samples {
                    let rho = g.coord_m(i).hypot(g.coord_m(j));
                    area += aperture_amplitude(rho, r, g.step_m) * g.step_m * g.step_m;
                }
            }
            let rel = area / (std::f64::consts::PI * r * r) - 1.0;
            assert!(
                rel.abs() < 4.0 / (samples_across * samples_across),
                "{samples_across}: {rel}"
            );
        }
    }

    #[test]
    fn phase_is_psi_rho_squared() {
        let g = PupilGrid {
            samples: 5,
            step_m: 1.0,
        };
        let q = pupil_field(g, 2.0, 3.0, None);
        // Sample (2, 3) lies at s = 1, t = 0: ρ² = 1/4, so the phase is 0.75 rad.
        let z = q[2 * 5 + 3];
        assert!((z.arg() - 0.75).abs() < 1e-12 && (z.norm() - 1.0).abs() < 1e-12);
        // Outside the aperture (corner) the field is zero.
        assert_eq!(q[0], c64::new(0.0, 0.0));
    }
}
