//! The best display image a preprocessor can put on the panel, and the
//! points between it and a linear filter (docs/optimal.md).
//!
//! For fixed optics the perceived image at depth D is linear in the display
//! image d: A_D d = crop(up2(d) ∗ h_D) + veil_D · mean(d), exactly as the
//! simulator renders it (symmetric extension, no wrap-around). The best
//! display image for a frame is the bounded least-squares solution
//!
//!   d* = argmin_{d ∈ [0, 1]} ½ Σ_D ‖A_D d − t_D‖²,
//!
//! t_D the sharp image up2(I) (sharp objective) or the multifocal target
//! (target objective), over the headline depths. Channels are independent.
//! It is solved by accelerated projected gradient (FISTA with gradient
//! restart, O'Donoghue & Candès 2015). With mirror-symmetric PSFs (every
//! rotationally symmetric system) Σ_D A_Dᵀ A_D is a convolution of the
//! mirrored frame, and a step costs one FFT pair on the Wiener prefilter's
//! grid; otherwise each depth is rendered, cropped and taken back through
//! the exact adjoint, 2 + 2·depths FFTs of the padded retinal grid.
//!
//! Between the linear filter and d*:
//! - `lsq`: the best linear prefilter for the objective on the display grid,
//!   G = Σ_D K_D* T_D / (Σ_D |K_D|² + N_D·K) at unit gain at zero frequency
//!   (K_D the display-grid transfer of h_D, T_D the target's), clamped;
//! - `refine:k`: the `lsq` output improved by k projected-gradient steps;
//! - `admm:k`: the `lsq` output improved by k steps of the split solver
//!   (ADMM, the constraint split off and the quadratic solved exactly).

mod operator;
mod prefilter;
mod solver;
mod split;
mod steps;

pub use prefilter::{DeviceTerms, SolveMode, SolvedPrefilter};
pub use solver::{FistaState, ProblemPlan};
pub use split::{SplitSchedule, SplitState, SplitTerms};
pub use steps::{SplitSteps, StepTerms, UnrolledTerms};

use operator::{Operator, RetinalTerms};

// What the tests (optimal/tests.rs) use through `super::*`.
#[cfg(test)]
use nedrt_core::{image::extend_plane, preprocess::Preprocess};

use std::sync::Arc;

use num_complex::Complex32 as c32;

use super::convolve::{Fft2, SizeCache};
use super::wiener::{WienerPlan, display_kernel};
use crate::Psf;
use nedrt_core::image::Image;

/// What the perceived images are compared with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Objective {
    /// The sharp image up2(I) at every depth.
    Sharp,
    /// The multifocal target: sharp at the main depths, h_b-blurred between.
    Target,
}

impl Objective {
    pub fn name(self) -> &'static str {
        match self {
            Objective::Sharp => "sharp",
            Objective::Target => "target",
        }
    }
}

impl std::str::FromStr for Objective {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "sharp" => Ok(Objective::Sharp),
            "target" => Ok(Objective::Target),
            _ => Err(format!("unknown objective {s:?}; choose sharp or target")),
        }
    }
}

/// When the solver stops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveOptions {
    /// Most projected-gradient steps.
    pub max_steps: usize,
    /// Stop when the objective, as a PSNR, rose by less than this over the
    /// last [`SolveOptions::window`] steps (0 = always take `max_steps`).
    pub tolerance_db: f64,
    pub window: usize,
}

impl SolveOptions {
    /// `optimal`: converged to 0.001 dB (the accuracy the issue's
    /// independent L-BFGS-B reference reached), at most 1000 steps.
    pub const CONVERGED: SolveOptions = SolveOptions {
        max_steps: 1000,
        tolerance_db: 1e-3,
        window: 10,
    };

    /// Exactly `steps` steps (`refine:k`).
    pub fn steps(steps: usize) -> Self {
        SolveOptions {
            max_steps: steps,
            tolerance_db: 0.0,
            window: 1,
        }
    }
}

/// What a solve did, per channel.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SolveReport {
    pub steps: Vec<usize>,
    /// ½ Σ_D ‖A_D d − t_D‖² at the start and at the end, where measured
    /// (empty otherwise).
    pub start_objective: Vec<f64>,
    pub final_objective: Vec<f64>,
}

/// The bounded least-squares problem of one display system and objective.
#[derive(Debug)]
pub struct DisplayProblem {
    pub objective: Objective,
    pub depths_d: Vec<f64>,
    /// System PSFs, [channel][depth].
    psfs: Vec<Vec<Psf>>,
    /// Per depth: whether its target is the h_b-blurred image.
    blurred: Vec<bool>,
    /// h_b per channel, when any depth's target is blurred.
    blur: Option<Vec<Psf>>,
    /// K of the linear prefilter (the starting point).
    pub k_reg: f64,
    plans: SizeCache<ProblemPlan>,
}

/// Frame sizes whose plans a problem keeps (a 1080p plan holds the PSF
/// spectra of every depth and channel, about 0.7 GB).
const PLANS_KEPT: usize = 2;

impl DisplayProblem {
    /// `psfs[channel][depth]` at `depths_d`; `blurred[depth]` when that
    /// depth's target is up2(I) ∗ h_b (then `blur` holds h_b per channel).
    pub fn new(
        objective: Objective,
        depths_d: Vec<f64>,
        psfs: Vec<Vec<Psf>>,
        blurred: Vec<bool>,
        blur: Option<Vec<Psf>>,
        k_reg: f64,
    ) -> Result<Self, super::SimError> {
        if depths_d.is_empty() || psfs.is_empty() {
            return Err(super::SimError::Invalid(
                "a display problem needs at least one depth and channel".into(),
            ));
        }
        if psfs.iter().any(|p| p.len() != depths_d.len()) || blurred.len() != depths_d.len() {
            return Err(super::SimError::Invalid(
                "one PSF per channel and depth, one target per depth".into(),
            ));
        }
        if blurred.iter().any(|&b| b) && blur.as_ref().is_none_or(|b| b.len() != psfs.len()) {
            return Err(super::SimError::Invalid(
                "blurred targets need h_b for every channel".into(),
            ));
        }
        if !(k_reg.is_finite() && k_reg >= 0.0) {
            return Err(super::SimError::Invalid(format!(
                "K = {k_reg} is not a finite value ≥ 0"
            )));
        }
        Ok(Self {
            objective,
            depths_d,
            psfs,
            blurred,
            blur,
            k_reg,
            plans: SizeCache::new(PLANS_KEPT),
        })
    }

    pub fn channels(&self) -> usize {
        self.psfs.len()
    }

    /// The plan for `width`×`height` frames (kept for the sizes used last).
    pub fn plan(&self, width: usize, height: usize) -> Arc<ProblemPlan> {
        self.plans
            .get_or_make(width, height, || ProblemPlan::new(self, width, height))
    }

    /// The targets t_D of `input`, [depth] (retinal grid), exactly as the
    /// simulator's `Prepared::target` makes them.
    pub fn targets(&self, input: &Image) -> Vec<Arc<Image>> {
        let sharp = Arc::new(input.up2());
        let blurred = match (&self.blur, self.blurred.iter().any(|&b| b)) {
            (Some(blur), true) => Some(Arc::new(super::perceive(input, blur))),
            _ => None,
        };
        self.blurred
            .iter()
            .map(|&b| match (&blurred, b) {
                (Some(t), true) => t.clone(),
                _ => sharp.clone(),
            })
            .collect()
    }

    /// What the device's refinement needs at `width`×`height`: the gains
    /// of the linear prefilter, of Σ_D A_Dᵀ t_D and of Σ_D A_Dᵀ A_D in the
    /// DCT filter's layout ([`super::wiener::dct_plane`]) and the step
    /// 1/L, per channel. Only the mirrored path has them (mirror-symmetric
    /// PSFs); the cropped path is refused.
    pub fn device_terms(
        &self,
        width: usize,
        height: usize,
    ) -> Result<DeviceTerms, super::SimError> {
        let plan = self.plan(width, height);
        let Operator::Mirrored(op) = &plan.operator else {
            return Err(super::SimError::Invalid(
                "the PSFs are not mirror-symmetric: the objective has no DCT form for the device"
                    .into(),
            ));
        };
        let planes = |spectra: Vec<Vec<c32>>| -> Result<Vec<Vec<f32>>, super::SimError> {
            spectra
                .iter()
                .enumerate()
                .map(|(c, g)| super::wiener::dct_plane(g, width, height, c))
                .collect()
        };
        let real = |v: &Vec<f32>| v.iter().map(|r| c32::new(*r, 0.0)).collect::<Vec<c32>>();
        Ok(DeviceTerms {
            linear: plan.linear.dct_gains()?,
            adjoint_target: planes(op.adjoint_target.clone())?,
            normal: planes(op.normal.iter().map(real).collect())?,
            // The CPU's step, in the same precision.
            step: plan.lipschitz.iter().map(|l| (1.0 / l) as f32).collect(),
        })
    }

    /// The `lsq` prefilter's gains for `width`×`height` frames as the
    /// device's DCT filter takes them ([`WienerPlan::dct_gains`]).
    pub fn linear_dct_gains(
        &self,
        width: usize,
        height: usize,
    ) -> Result<Vec<Vec<f32>>, super::SimError> {
        self.plan(width, height).linear.dct_gains()
    }

    /// The `lsq` display image of `input` before the panel's clamp.
    pub fn linear_unclamped(&self, input: &Image) -> Image {
        self.plan(input.width, input.height)
            .linear
            .apply_unclamped(input)
    }

    /// Improves `start` (clamped to [0, 1] first) towards the bounded
    /// least-squares optimum for `input`. The objective values of the
    /// report are measured only when the stopping rule needs them (or the
    /// cropped path runs): otherwise they are `None`.
    pub fn solve(
        &self,
        input: &Image,
        start: &Image,
        options: &SolveOptions,
    ) -> (Image, SolveReport) {
        let states = start.planes().map(FistaState::at).collect();
        let (display, report, _) = self.solve_from(input, states, options);
        (display, report)
    }

    /// As [`DisplayProblem::solve`], from where an earlier solve of a
    /// frame of this size stopped, per channel (its iterate and momentum:
    /// K steps from a solve of K steps are a solve of 2K); and where this
    /// one stops.
    pub fn solve_from(
        &self,
        input: &Image,
        states: Vec<FistaState>,
        options: &SolveOptions,
    ) -> (Image, SolveReport, Vec<FistaState>) {
        let plan = self.plan(input.width, input.height);
        let targets =
            (options.tolerance_db > 0.0 || plan.needs_targets()).then(|| self.targets(input));
        let mut report = SolveReport::default();
        let mut planes = Vec::new();
        let mut out = Vec::new();
        for (c, state) in states.into_iter().enumerate().take(self.channels()) {
            let objective = plan.channel_objective(c, input.plane(c), targets.as_deref());
            let (state, steps, f0, f1) = plan.fista_from(c, &objective, state, options);
            report.steps.push(steps);
            if targets.is_some() {
                report.start_objective.push(f0);
                report.final_objective.push(f1);
            }
            planes.push(state.x().to_vec());
            out.push(state);
        }
        (
            Image::from_planes(input.width, input.height, planes),
            report,
            out,
        )
    }

    /// Whether the split solver (`admm:K`) runs: the objective must be
    /// diagonal on the mirrored grid (mirror-symmetric PSFs).
    pub fn has_split(&self) -> bool {
        self.is_mirror_symmetric()
    }

    /// `steps` split-solver steps per channel from `states` (a start:
    /// [`SplitState::at`] of the clamped `lsq` image, or where an earlier
    /// solve of this frame size stopped), on `schedule`; the display image
    /// and where each channel stopped. An error without the mirrored form
    /// ([`DisplayProblem::has_split`]).
    pub fn solve_split(
        &self,
        input: &Image,
        states: Vec<SplitState>,
        steps: usize,
        schedule: &SplitSchedule,
    ) -> Result<(Image, Vec<SplitState>), super::SimError> {
        let plan = self.plan(input.width, input.height);
        let mut out = Vec::new();
        for (c, state) in states.into_iter().enumerate().take(self.channels()) {
            let state = plan
                .split_from(c, input.plane(c), state, steps, schedule)
                .ok_or_else(|| {
                    super::SimError::Invalid(
                        "the PSFs are not mirror-symmetric: the split solver (admm:K) has no \
                         exact data step; use refine:K"
                            .into(),
                    )
                })?;
            out.push(state);
        }
        let planes = out.iter().map(|s| s.z.clone()).collect();
        Ok((Image::from_planes(input.width, input.height, planes), out))
    }

    /// The split solver's start for `input`: the clamped `lsq` image.
    pub fn split_start(&self, input: &Image) -> Vec<SplitState> {
        self.linear_unclamped(input)
            .planes()
            .map(SplitState::at)
            .collect()
    }

    /// The objective as convolution kernels on the mirrored 2w×2h display
    /// grid, for the trainer (`nedrt prefilter --operator`): per channel
    /// (κ_M, κ_C, κ_T), row-major 2h×2w, periodic, origin at [0, 0], such
    /// that with d̃, Ĩ the mirrored display image and input,
    /// ½ Σ_D ‖A_D d − t_D‖² = ¼ (½ d̃·(κ_M ⊛ d̃) − d̃·(κ_C ⊛ Ĩ) + ½ Ĩ·(κ_T ⊛ Ĩ)).
    /// `None` when the PSFs are not mirror-symmetric (no such form exists).
    pub fn mirrored_kernels(&self, width: usize, height: usize) -> Option<Vec<[Vec<f32>; 3]>> {
        let plan = self.plan(width, height);
        let Operator::Mirrored(op) = &plan.operator else {
            return None;
        };
        let real = |s: &[f32]| s.iter().map(|v| c32::new(*v, 0.0)).collect::<Vec<_>>();
        Some(
            (0..self.channels())
                .map(|c| {
                    [
                        op.fft.inverse(real(&op.normal[c])),
                        op.fft.inverse(op.adjoint_target[c].clone()),
                        op.fft.inverse(real(&op.target_gram[c])),
                    ]
                })
                .collect(),
        )
    }

    /// The `lsq` prefilter (before the clamp) as convolution kernels on the
    /// mirrored 2w×2h display grid, per channel, laid out as
    /// [`DisplayProblem::mirrored_kernels`]: the split solver's start, for
    /// the trainer's unrolled model.
    pub fn mirrored_linear_kernels(&self, width: usize, height: usize) -> Vec<Vec<f32>> {
        self.plan(width, height).linear.mirrored_kernels()
    }

    /// [`DisplayProblem::mirrored_kernels`] for each depth on its own,
    /// [depth][channel] (the trainer's per-depth PSNR loss); their sum over
    /// the depths is `mirrored_kernels`.
    pub fn mirrored_depth_kernels(
        &self,
        width: usize,
        height: usize,
    ) -> Option<Vec<Vec<[Vec<f32>; 3]>>> {
        if !self.is_mirror_symmetric() {
            return None;
        }
        let terms = RetinalTerms::new(self, width, height);
        let fft = Fft2::new(2 * width, 2 * height);
        Some(
            (0..self.depths_d.len())
                .map(|depth| {
                    (0..self.channels())
                        .map(|c| {
                            terms
                                .depth(c, depth)
                                .map(|t| fft.inverse(terms.fold(t, &fft)))
                        })
                        .collect()
                })
                .collect(),
        )
    }

    fn is_mirror_symmetric(&self) -> bool {
        self.psfs.iter().flatten().all(mirror_symmetric)
            && self.blur.iter().flatten().all(mirror_symmetric)
    }

    /// ½ Σ_D ‖A_D d − t_D‖² per channel (for reports and tests).
    pub fn objective_value(&self, input: &Image, display: &Image) -> Vec<f64> {
        let plan = self.plan(input.width, input.height);
        let targets = self.targets(input);
        (0..self.channels())
            .map(|c| {
                plan.channel_objective(c, input.plane(c), Some(&targets))(display.plane(c), None)
            })
            .collect()
    }
}

/// Whether a PSF is its own mirror image in x and in y (to round-off).
fn mirror_symmetric(p: &Psf) -> bool {
    let w = p.window;
    let peak = p.cells.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let tol = 1e-9 * peak.max(f64::MIN_POSITIVE);
    (0..w).all(|y| {
        (0..w).all(|x| {
            let v = p.cells[y * w + x];
            (v - p.cells[y * w + (w - 1 - x)]).abs() <= tol
                && (v - p.cells[(w - 1 - y) * w + x]).abs() <= tol
        })
    })
}

/// The display-grid least-squares gains G = Σ_D K_D* T_D / (Σ_D |K_D|² + N_D K)
/// of each channel, scaled to unit gain at zero frequency, on the mirrored
/// 2w×2h grid of the Wiener prefilter.
fn linear_plan(problem: &DisplayProblem, width: usize, height: usize) -> WienerPlan {
    let fft = Fft2::new(2 * width, 2 * height);
    let spectrum = |p: &Psf| {
        let (k, side) = display_kernel(p);
        let mut s = fft.kernel_spectrum(&k, side);
        s[0] += c32::new(p.veil as f32, 0.0);
        s
    };
    let n_depths = problem.depths_d.len() as f32;
    let gains = (0..problem.channels())
        .map(|c| {
            let blur = problem
                .blur
                .as_ref()
                .filter(|_| problem.blurred.iter().any(|&b| b))
                .map(|b| spectrum(&b[c]));
            let mut num = vec![c32::new(0.0, 0.0); fft.bins() * fft.height];
            let mut den = vec![n_depths * problem.k_reg as f32; num.len()];
            for (p, &blurred) in problem.psfs[c].iter().zip(&problem.blurred) {
                let k = spectrum(p);
                for (i, kv) in k.iter().enumerate() {
                    let t = match (&blur, blurred) {
                        (Some(b), true) => b[i],
                        _ => c32::new(1.0, 0.0),
                    };
                    num[i] += kv.conj() * t;
                    den[i] += kv.norm_sqr();
                }
            }
            let g0 = num[0].re / den[0];
            num.iter()
                .zip(&den)
                .map(|(n, d)| n / (d * g0))
                .collect::<Vec<_>>()
        })
        .collect();
    WienerPlan::from_gains(fft, width, height, gains)
}

#[cfg(test)]
mod tests;
