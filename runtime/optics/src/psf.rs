//! PSFs for a request: choose the sampling (docs/model.md §8) and the
//! propagator, compute every PSF with each retinal cell integrated, choose
//! the smallest window that holds the required energy for every PSF of the
//! request, and keep what the window cannot hold as a uniform veil.
//!
//! Two propagators ([`Propagator`]): rotationally symmetric pupils (the lens
//! alone, radial DOE profiles) go through the radial (Hankel) path
//! ([`super::radial`], planned in `radial_plan`), free-form 2-D maps through
//! the 2-D path, which computes each PSF over a whole period with every cell
//! integrated exactly (the limit of the m×m sums of docs/model.md §6, see
//! [`exact_period_cells`]). `simulation.propagator = "2d"` forces the 2-D
//! path. Both report the same window rule and a comparable veil.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::OpticsError;
use super::doe::{HeightMap, Profile};
use super::propagate::{centred_window_energies, crop_centred};
use super::sampling::{
    PsfSpec, StepRule, channel_sampling, max_pupil_step, predicted_half_width_cells,
};
use nedrt_core::calib::{Calibration, PropagatorSetting};

mod radial_plan;
mod two_d;

/// Times the pupil step is halved to fit the window in the period (lens only).
const MAX_REFINEMENTS: usize = 3;

/// A set of PSFs to compute together: they share one sampling plan and one window.
#[derive(Debug, Clone)]
pub struct PsfRequest<'a> {
    pub specs: Vec<PsfSpec>,
    /// The DOE in the pupil, or `None` for the lens alone.
    pub doe: Option<&'a HeightMap>,
}

/// One PSF on the retinal grid: `window`×`window` cells (odd), on-axis cell
/// at the centre, each the fraction of the light through the aperture that
/// falls in it; `veil` is the fraction outside the window.
#[derive(Debug, Clone, PartialEq)]
pub struct Psf {
    pub window: usize,
    pub cells: Vec<f64>,
    pub veil: f64,
}

impl Psf {
    /// A mirror-symmetric Gaussian PSF of standard deviation `sigma` cells,
    /// ±3σ wide, its cells summing to 1 − `veil` (benchmarks and tests: a
    /// kernel of realistic values whose cost is the real one's).
    pub fn gaussian(sigma: f64, veil: f64) -> Psf {
        let window = 2 * (3.0 * sigma).ceil() as usize + 1;
        let c = (window / 2) as f64;
        let mut cells: Vec<f64> = (0..window * window)
            .map(|i| {
                let (x, y) = ((i % window) as f64 - c, (i / window) as f64 - c);
                (-(x * x + y * y) / (2.0 * sigma * sigma)).exp()
            })
            .collect();
        let sum: f64 = cells.iter().sum();
        cells.iter_mut().for_each(|v| *v *= (1.0 - veil) / sum);
        Psf {
            window,
            cells,
            veil,
        }
    }

    /// The same PSF centred in a `window`-wide window (at least its own).
    pub fn padded(&self, window: usize) -> Psf {
        Psf::weighted_sum([(self, 1.0), (&Psf::zero(window.max(self.window)), 0.0)])
            .unwrap_or_else(|| self.clone())
    }

    /// The smallest centred window (odd) outside which at most `max_lost`
    /// of the light falls, that light added to the veil (which the
    /// simulator spreads uniformly, as it does for light past any window).
    pub fn trimmed(&self, max_lost: f64) -> Psf {
        let n = self.window;
        let c = n / 2;
        // Light in each ring (Chebyshev distance r from the centre cell).
        let mut ring = vec![0.0; c + 1];
        for (i, v) in self.cells.iter().enumerate() {
            let (x, y) = ((i % n).abs_diff(c), (i / n).abs_diff(c));
            ring[x.max(y)] += v;
        }
        let mut outside = 0.0;
        let mut half = c;
        while half > 0 && (outside + ring[half]).abs() <= max_lost {
            outside += ring[half];
            half -= 1;
        }
        let w = 2 * half + 1;
        let off = c - half;
        let cells = (0..w * w)
            .map(|i| self.cells[(i / w + off) * n + i % w + off])
            .collect();
        Psf {
            window: w,
            cells,
            veil: self.veil + outside,
        }
    }

    /// No light in a `window`-wide window.
    fn zero(window: usize) -> Psf {
        Psf {
            window,
            cells: vec![0.0; window * window],
            veil: 0.0,
        }
    }

    /// Σ wᵢ·PSFᵢ, cells and veil alike, each PSF centred in the widest
    /// window: the time-weighted mixture of a display's planes, the mean
    /// over an accommodation sweep, a spectrum's mix of wavelengths. The
    /// one weighted sum of PSFs in nedrt (terms added in order; `None`
    /// without terms).
    pub fn weighted_sum<'a>(
        terms: impl IntoIterator<Item = (&'a Psf, f64)> + Clone,
    ) -> Option<Psf> {
        let window = terms.clone().into_iter().map(|(p, _)| p.window).max()?;
        let mut out = Psf {
            window,
            cells: vec![0.0; window * window],
            veil: 0.0,
        };
        for (p, w) in terms {
            let off = (window - p.window) / 2;
            for y in 0..p.window {
                let row = &mut out.cells[(y + off) * window + off..][..p.window];
                row.iter_mut()
                    .zip(&p.cells[y * p.window..][..p.window])
                    .for_each(|(o, v)| *o += w * v);
            }
            out.veil += w * p.veil;
        }
        Some(out)
    }
}

/// The propagator that computed a request's PSFs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum Propagator {
    /// Hankel transform of a rotationally symmetric pupil profile.
    #[serde(rename = "radial")]
    Radial,
    /// 2-D pupil grid, exact cells over one period.
    #[default]
    #[serde(rename = "2d")]
    TwoD,
}

impl std::fmt::Display for Propagator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Radial => "radial (Hankel)",
            Self::TwoD => "2-D",
        })
    }
}

/// The propagator `calib` uses for a request with `doe`: radial for the
/// lens alone and for radial DOE profiles, 2-D for maps, or 2-D whenever
/// `simulation.propagator = "2d"` or the eye's pupil lies off the axis.
pub fn propagator_for(calib: &Calibration, doe: Option<&HeightMap>) -> Propagator {
    if calib.eye_stop_off_axis() {
        // An eye pupil off the axis breaks the rotational symmetry.
        return Propagator::TwoD;
    }
    match calib.simulation.propagator {
        PropagatorSetting::TwoD => Propagator::TwoD,
        PropagatorSetting::Auto => match doe {
            Some(d) if d.profile == Profile::Map => Propagator::TwoD,
            _ => Propagator::Radial,
        },
    }
}

/// What the model chose for a request, printed with every result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SamplingReport {
    /// Which propagator ran.
    #[serde(default)]
    pub propagator: Propagator,
    /// Radial path: annuli per cell width m_t of its cell rule (extrapolated
    /// from m_t and m_t/2); 0 on the 2-D path.
    #[serde(default)]
    pub annuli_per_cell: usize,
    /// Per channel: the pupil step (Δs, or Δρ on the radial path), its
    /// samples (across the grid, or radial nodes) and the 2-D period that
    /// bounds the window (0 for the radial lens alone, which has none).
    pub channels: Vec<ChannelReport>,
    pub step_rule: StepRule,
    pub window_cells: usize,
    /// Smallest share of the light inside the window over the request's PSFs.
    pub min_window_energy: f64,
    /// Largest veil (light outside the window, spread uniformly) over the PSFs.
    pub max_veil: f64,
    /// True when the period capped the window below the energy target.
    pub window_capped: bool,
    pub refinements: usize,
    pub psf_count: usize,
    pub compute_s: f64,
    pub from_cache: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChannelReport {
    pub name: String,
    pub pupil_step_um: f64,
    pub pupil_samples: usize,
    pub period_cells: usize,
}

impl SamplingReport {
    /// One line for the console.
    pub fn summary(&self) -> String {
        let radial = self.propagator == Propagator::Radial;
        let steps: Vec<String> = self
            .channels
            .iter()
            .map(|c| {
                format!(
                    "{} {:.2} µm ({} {})",
                    c.name,
                    c.pupil_step_um,
                    c.pupil_samples,
                    if radial { "annuli" } else { "samples" }
                )
            })
            .collect();
        let cells = if radial {
            format!(
                "integrated over {} and {} annuli per cell, extrapolated",
                self.annuli_per_cell,
                self.annuli_per_cell / 2
            )
        } else {
            "each integrated exactly".to_string()
        };
        format!(
            "{} PSFs, {} path: pupil step {} set by {}; window {}×{} cells, {cells}; \
             window holds ≥ {:.4}%, veil ≤ {:.4}%{}; {:.2} s{}",
            self.psf_count,
            self.propagator,
            steps.join(", "),
            self.step_rule,
            self.window_cells,
            self.window_cells,
            100.0 * self.min_window_energy,
            100.0 * self.max_veil,
            if self.window_capped {
                " (window capped by the DOE's period: the rest is a uniform veil)"
            } else {
                ""
            },
            self.compute_s,
            if self.from_cache { " (from cache)" } else { "" },
        )
    }
}

/// PSFs of a request with the report of how they were sampled.
#[derive(Debug, Clone)]
pub struct PsfSet {
    pub psfs: Vec<Psf>,
    pub report: SamplingReport,
}

/// Computes the PSFs of `request`, calling `tick` once per finished PSF.
pub fn compute_psfs(
    calib: &Calibration,
    request: &PsfRequest,
    tick: &(dyn Fn() + Sync),
) -> Result<PsfSet, OpticsError> {
    let start = Instant::now();
    if request.specs.is_empty() {
        return Err(OpticsError::EmptyRequest);
    }
    for s in &request.specs {
        if s.channel >= calib.channels.len() || !s.psi_rad.is_finite() {
            return Err(OpticsError::BadSpec(format!("{s:?}")));
        }
    }
    match propagator_for(calib, request.doe) {
        Propagator::Radial => radial_plan::compute(calib, request, tick, start),
        Propagator::TwoD => two_d::compute(calib, request, tick, start),
    }
}

/// The coarsest pupil step rules 1, 2 and 4 allow for the request, or the
/// configured step (an error if a rule forbids it), with the rule that set it.
fn step_cap(calib: &Calibration, request: &PsfRequest) -> Result<(f64, StepRule), OpticsError> {
    let (step_cap, step_rule) = max_pupil_step(calib, &request.specs, request.doe);
    match calib.simulation.pupil_step_m {
        Some(forced) if forced > step_cap * (1.0 + 1e-9) => {
            Err(OpticsError::RuleViolated(format!(
                "simulation.pupil_step_um = {:.3} µm is coarser than {step_rule} allows ({:.3} µm)",
                forced * 1e6,
                step_cap * 1e6
            )))
        }
        Some(forced) => Ok((forced, StepRule::Configured)),
        None => Ok((step_cap, step_rule)),
    }
}

/// The request's channels, sorted, once each.
fn request_channels(request: &PsfRequest) -> Vec<usize> {
    let mut channels: Vec<usize> = request.specs.iter().map(|s| s.channel).collect();
    channels.sort_unstable();
    channels.dedup();
    channels
}

/// The smallest period the 2-D path allows before looking at the PSFs: it
/// must hold the predicted blur (odd, cells).
fn predicted_min_period(calib: &Calibration, request: &PsfRequest) -> usize {
    let predicted = request
        .specs
        .iter()
        .map(|s| predicted_half_width_cells(calib, *s))
        .fold(0.0, f64::max);
    2 * predicted.ceil() as usize + 1
}

/// Largest |a − b| over the common (smaller) window of each pair, as a
/// fraction of `b`'s peak cell, over every PSF of two sets of the same
/// request (how far the radial path is from the 2-D one).
pub fn max_difference_of_peak(a: &PsfSet, b: &PsfSet) -> f64 {
    a.psfs
        .iter()
        .zip(&b.psfs)
        .map(|(a, b)| {
            let w = a.window.min(b.window);
            let (a, b) = (
                crop_centred(&a.cells, a.window, w),
                crop_centred(&b.cells, b.window, w),
            );
            let peak = b.iter().cloned().fold(0.0, f64::max);
            a.iter()
                .zip(&b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max)
                / peak
        })
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod eye_tests;
#[cfg(test)]
mod radial_tests;
#[cfg(test)]
mod tests;
