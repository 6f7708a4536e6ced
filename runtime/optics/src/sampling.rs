//! Sampling rules of docs/model.md §8, as pure functions of the request: the
//! coarsest pupil step that resolves the aperture (rule 4), the DOE (rule 1)
//! and the smooth phase (rule 2), and per channel a period λ/Δs holding a
//! whole number of retinal cells for the FFT propagator (rule 3 then bounds
//! the window by that period).

use std::f64::consts::PI;

use serde::{Deserialize, Serialize};

use super::OpticsError;
use super::doe::HeightMap;
use super::pupil::PupilGrid;
use nedrt_core::calib::Calibration;

/// One PSF to compute: a channel and its defocus coefficient Ψ (radians);
/// whether the DOE is in the pupil is a property of the whole request.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PsfSpec {
    pub channel: usize,
    pub psi_rad: f64,
}

/// The rule that set the pupil step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum StepRule {
    /// Rule 1: no coarser than the DOE's grid pitch.
    DoePitch,
    /// Rule 2: smooth pupil phase resolved (max |∇φ|·Δs ≤ π/2).
    SmoothPhase,
    /// Rule 3: the period λ/Δs must hold the PSF window.
    Window,
    /// Rule 4: at least the minimum number of samples across the aperture.
    ApertureSamples,
    /// Capped by `simulation.pupil_step_um`.
    Configured,
    /// Radial path: the J0 kernel resolved out to the window's corner,
    /// Δρ ≤ λ_min / (2 θ_corner) (the radial counterpart of rule 3).
    KernelNyquist,
}

impl std::fmt::Display for StepRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::DoePitch => "rule 1 (DOE pitch)",
            Self::SmoothPhase => "rule 2 (smooth phase)",
            Self::Window => "rule 3 (window within one period)",
            Self::ApertureSamples => "rule 4 (samples across the aperture)",
            Self::Configured => "simulation.pupil_step_um",
            Self::KernelNyquist => "the radial kernel's Nyquist limit at the window corner",
        })
    }
}

/// Largest phase gradient of the pupil for `spec` (rad/m): lens defocus at
/// the aperture edge, 2|Ψ|/r, plus the DOE's smooth slope at this channel
/// (a bound: the two maxima need not coincide).
pub fn max_phase_gradient(calib: &Calibration, spec: PsfSpec, doe_slope: f64) -> f64 {
    2.0 * spec.psi_rad.abs() / calib.aperture_radius_m
        + calib.doe_phase_per_m(spec.channel) * doe_slope
}

/// The coarsest pupil step allowed by rules 1, 2 and 4 for these PSFs, and
/// the rule that set it.
pub fn max_pupil_step(
    calib: &Calibration,
    specs: &[PsfSpec],
    doe: Option<&HeightMap>,
) -> (f64, StepRule) {
    let r = calib.aperture_radius_m;
    // Rule 4 counts samples across the stop: the eye's pupil where it limits.
    let stop = specs
        .iter()
        .map(|s| stop_radius_m(calib, s.channel))
        .fold(r, f64::min);
    let mut best = (
        2.0 * stop / calib.simulation.min_pupil_samples as f64,
        StepRule::ApertureSamples,
    );
    let mut doe_slope = 0.0;
    if let Some(d) = doe {
        if d.pitch_m < best.0 {
            best = (d.pitch_m, StepRule::DoePitch);
        }
        doe_slope = d.max_smooth_slope(r, calib.doe_wave_height_m());
    }
    for s in specs {
        let g = max_phase_gradient(calib, *s, doe_slope);
        if g > 0.0 && (PI / 2.0) / g < best.0 {
            best = ((PI / 2.0) / g, StepRule::SmoothPhase);
        }
    }
    best
}

/// Geometric half-width (in retinal cells) of the defocus blur of `spec`
/// plus a diffraction margin: the edge-diffraction tail of a circular pupil
/// leaves ≈ 2/(πx) of the light beyond x = 2πrθ/λ, so 0.1 % lies beyond
/// x ≈ 640. The first guess of the window; the computed PSF decides.
pub fn predicted_half_width_cells(calib: &Calibration, spec: PsfSpec) -> f64 {
    let lambda = calib.channels[spec.channel].wavelength_m;
    let r = calib.aperture_radius_m;
    // Through the eye's pupil (radius a ≤ r): blur (V − D)·a = Ψλa/(πr²),
    // and the diffraction tail of the smaller disk.
    let a = stop_radius_m(calib, spec.channel);
    let dtheta = calib.retinal_step_rad();
    let geometric = spec.psi_rad.abs() * lambda * a / (PI * r * r * dtheta);
    let diffraction = 640.0 * lambda / (2.0 * PI * a * dtheta);
    geometric + diffraction
}

/// The radius of the stop a channel's light passes: the eye's pupil in the
/// lens plane where it limits, else the eyepiece's aperture, metres.
pub fn stop_radius_m(calib: &Calibration, channel: usize) -> f64 {
    calib
        .eye_stop(channel)
        .map_or(calib.aperture_radius_m, |s| {
            s.radius_m.min(calib.aperture_radius_m)
        })
}

/// Smallest integer ≥ `x` whose prime factors are 2, 3 and 5 (fast FFT sizes).
pub fn smooth_size_at_least(x: f64) -> usize {
    let mut n = x.ceil().max(1.0) as usize;
    loop {
        let mut k = n;
        for p in [2, 3, 5] {
            while k.is_multiple_of(p) {
                k /= p;
            }
        }
        if k == 1 {
            return n;
        }
        n += 1;
    }
}

/// Per-channel sampling: a pupil step no coarser than `step_cap_m` for which
/// the period λ/Δs is a whole (and FFT-friendly) number of retinal cells, at
/// least `min_period_cells`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ChannelSampling {
    pub channel: usize,
    pub grid: GridSpec,
    pub period_cells: usize,
}

/// Serialisable pupil grid.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GridSpec {
    pub samples: usize,
    pub step_m: f64,
}

impl From<GridSpec> for PupilGrid {
    fn from(g: GridSpec) -> Self {
        PupilGrid {
            samples: g.samples,
            step_m: g.step_m,
        }
    }
}

/// Chooses the grid of `channel` for a step cap and a minimum period.
pub fn channel_sampling(
    calib: &Calibration,
    channel: usize,
    step_cap_m: f64,
    min_period_cells: usize,
) -> Result<ChannelSampling, OpticsError> {
    let lambda = calib.channels[channel].wavelength_m;
    let dtheta = calib.retinal_step_rad();
    let period =
        smooth_size_at_least((lambda / (step_cap_m * dtheta)).max(min_period_cells as f64) - 1e-9);
    let step_m = lambda / (period as f64 * dtheta);
    let grid = PupilGrid::covering(calib.aperture_radius_m, step_m);
    if grid.samples > calib.simulation.max_pupil_samples {
        return Err(OpticsError::GridTooLarge {
            channel: calib.channels[channel].name.clone(),
            samples: grid.samples,
            step_um: step_m * 1e6,
            limit: calib.simulation.max_pupil_samples,
        });
    }
    Ok(ChannelSampling {
        channel,
        grid: GridSpec {
            samples: grid.samples,
            step_m,
        },
        period_cells: period,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn calib() -> Calibration {
        Calibration::default_embedded().expect("default calibration")
    }

    #[test]
    fn smooth_sizes() {
        assert_eq!(smooth_size_at_least(491.2), 500);
        assert_eq!(smooth_size_at_least(577.0), 600);
        assert_eq!(smooth_size_at_least(1.0), 1);
        assert_eq!(smooth_size_at_least(7.0), 8);
    }

    #[test]
    fn rule_2_alone_allows_about_12_um_over_0_to_3_d() {
        let c = calib();
        let specs: Vec<PsfSpec> = (0..3)
            .flat_map(|ch| {
                [0.0, 3.0].map(|d| PsfSpec {
                    channel: ch,
                    psi_rad: c.psi_rad(ch, d),
                })
            })
            .collect();
        let g = specs
            .iter()
            .map(|s| max_phase_gradient(&c, *s, 0.0))
            .fold(0.0, f64::max);
        let step = (PI / 2.0) / g;
        assert!(
            (step * 1e6 - 12.0).abs() < 0.1,
            "rule 2 step {} µm",
            step * 1e6
        );
        let (cap, rule) = max_pupil_step(&c, &specs, None);
        assert_eq!(rule, StepRule::SmoothPhase);
        assert!((cap - step).abs() < 1e-15);
    }

    #[test]
    fn doe_pitch_caps_the_step() {
        let c = calib();
        let doe = HeightMap::three_lens_init(&c, 6e-6);
        let (cap, rule) = max_pupil_step(
            &c,
            &[PsfSpec {
                channel: 1,
                psi_rad: 10.0,
            }],
            Some(&doe),
        );
        assert_eq!(rule, StepRule::DoePitch);
        assert_eq!(cap, 6e-6);
    }

    #[test]
    fn period_is_whole_and_step_not_coarser_than_the_cap() {
        let c = calib();
        for ch in 0..3 {
            let s = channel_sampling(&c, ch, 6e-6, 1).expect("fits");
            assert!(s.grid.step_m <= 6e-6);
            let p = c.channels[ch].wavelength_m / (s.grid.step_m * c.retinal_step_rad());
            assert!((p - s.period_cells as f64).abs() < 1e-9);
        }
        // Rule 3 for the window: blue at 6 µm gives ≥ 491 cells.
        let b = channel_sampling(&c, 2, 6e-6, 1).expect("fits");
        assert!(b.period_cells >= 491);
    }

    #[test]
    fn oversized_grids_are_refused() {
        let c = calib();
        let e = channel_sampling(&c, 1, 0.5e-6, 1).expect_err("too fine");
        assert!(e.to_string().contains("max_pupil_samples"), "{e}");
    }
}
