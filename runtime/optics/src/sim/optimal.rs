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
//! - `refine:k`: the `lsq` output improved by k projected-gradient steps.

use std::sync::Arc;

use num_complex::Complex32 as c32;
use rayon::prelude::*;

use super::convolve::{Fft2, SizeCache};
use super::wiener::{WienerPlan, display_kernel, first_quadrant};
use crate::Psf;
use crate::sampling::smooth_size_at_least;
use nedrt_core::image::{Image, extend_plane, symmetric_index, up2_plane};
use nedrt_core::preprocess::{Preprocess, PreprocessError, check_frame};

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
        let plan = self.plan(input.width, input.height);
        let targets =
            (options.tolerance_db > 0.0 || plan.needs_targets()).then(|| self.targets(input));
        let mut report = SolveReport::default();
        let planes = (0..self.channels())
            .map(|c| {
                let objective = plan.channel_objective(c, input.plane(c), targets.as_deref());
                let (plane, steps, f0, f1) = plan.fista(c, &objective, start.plane(c), options);
                report.steps.push(steps);
                if targets.is_some() {
                    report.start_objective.push(f0);
                    report.final_objective.push(f1);
                }
                plane
            })
            .collect();
        (
            Image::from_planes(input.width, input.height, planes),
            report,
        )
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

/// A problem prepared for frames of one size.
#[derive(Debug)]
pub struct ProblemPlan {
    pub width: usize,
    pub height: usize,
    operator: Operator,
    /// Lipschitz constant of the gradient, per channel.
    lipschitz: Vec<f64>,
    /// The linear least-squares prefilter at this size.
    linear: WienerPlan,
}

/// Σ_D A_Dᵀ A_D and Σ_D A_Dᵀ t_D, two ways.
#[derive(Debug)]
enum Operator {
    /// Mirror-symmetric PSFs (every rotationally symmetric system): on the
    /// frame mirrored to 2w×2h, which is exactly periodic, the perceived
    /// image of the mirrored frame is the mirror image of the perceived
    /// image, so the objective is four times the frame's, and both sums are
    /// convolutions on the display grid. A step is one FFT pair of the
    /// Wiener prefilter's size, whatever the PSF window.
    Mirrored(MirroredOperator),
    /// Any PSFs: each depth's perceived image rendered as the simulator
    /// does, cropped, and its residual taken back through the exact
    /// adjoint; 2 + 2·depths FFTs of the padded retinal grid per step.
    Cropped(CroppedOperator),
}

#[derive(Debug)]
struct MirroredOperator {
    /// The mirrored 2w×2h display grid.
    fft: Fft2,
    /// Spectrum of Σ_D A_Dᵀ A_D, per channel (real: the operator is symmetric).
    normal: Vec<Vec<f32>>,
    /// Spectrum of the filter I ↦ Σ_D A_Dᵀ t_D(I), per channel.
    adjoint_target: Vec<Vec<c32>>,
    /// Spectrum of Σ_D T_Dᵀ T_D (the objective's constant ½ Σ_D ‖t_D‖² as
    /// a quadratic form in I), per channel; only the trainer needs it.
    target_gram: Vec<Vec<f32>>,
}

#[derive(Debug)]
struct CroppedOperator {
    /// The retinal grid extended by `half` (the widest PSF's half-window)
    /// on every side, at least.
    fft: Fft2,
    half: usize,
    /// PSF spectra on `fft`'s grid and veils, [channel][depth].
    spectra: Vec<Vec<Vec<c32>>>,
    veils: Vec<Vec<f32>>,
}

/// One channel's objective for one frame: value, and gradient when asked.
type ChannelObjective<'a> = Box<dyn Fn(&[f32], Option<&mut Vec<f32>>) -> f64 + Sync + 'a>;

impl ProblemPlan {
    fn new(problem: &DisplayProblem, width: usize, height: usize) -> Self {
        let symmetric = problem.is_mirror_symmetric();
        let linear = linear_plan(problem, width, height);
        if symmetric {
            let (operator, lipschitz) = MirroredOperator::new(problem, width, height);
            return Self {
                width,
                height,
                operator: Operator::Mirrored(operator),
                lipschitz,
                linear,
            };
        }
        Self::cropped(problem, width, height, linear)
    }

    /// The plan on the cropped path whatever the PSFs (tests compare the two).
    fn cropped(problem: &DisplayProblem, width: usize, height: usize, linear: WienerPlan) -> Self {
        let operator = CroppedOperator::new(problem, width, height);
        // The zero-frequency bound of the mirrored path, and above it what
        // power iteration finds: asymmetric PSFs pass a little more at the
        // borders.
        let dc_bound: Vec<f64> = problem
            .psfs
            .iter()
            .map(|ch| {
                ch.iter()
                    .map(|p| 4.0 * (p.cells.iter().sum::<f64>() + p.veil).powi(2))
                    .sum()
            })
            .collect();
        let lipschitz = dc_bound
            .iter()
            .enumerate()
            .map(|(c, bound)| {
                bound.max(POWER_MARGIN * operator.largest_eigenvalue(c, width, height))
            })
            .collect();
        Self {
            width,
            height,
            operator: Operator::Cropped(operator),
            lipschitz,
            linear,
        }
    }

    /// Channel `c`'s objective ½ Σ_D ‖A_D d − t_D‖² for the frame `input`;
    /// `targets` (from [`DisplayProblem::targets`]) are needed for its value
    /// on the mirrored path and for everything on the cropped one; without
    /// them the value is the objective less the constant ½ Σ_D ‖t_D‖².
    fn channel_objective<'a>(
        &'a self,
        c: usize,
        input: &[f32],
        targets: Option<&'a [Arc<Image>]>,
    ) -> ChannelObjective<'a> {
        match &self.operator {
            Operator::Mirrored(op) => {
                let (w, h) = (self.width, self.height);
                let b = op.adjoint_target(c, input, w, h);
                let constant = targets.map_or(0.0, |t| {
                    0.5 * t
                        .iter()
                        .flat_map(|t| t.plane(c))
                        .map(|v| (*v as f64).powi(2))
                        .sum::<f64>()
                });
                Box::new(move |d, gradient| {
                    op.value_and_gradient(c, d, w, h, &b, constant, gradient)
                })
            }
            Operator::Cropped(op) => {
                let (w, h) = (self.width, self.height);
                let targets: Vec<&[f32]> = targets
                    .expect("the cropped path needs the targets")
                    .iter()
                    .map(|t| t.plane(c))
                    .collect();
                Box::new(move |d, gradient| op.value_and_gradient(c, d, w, h, &targets, gradient))
            }
        }
    }

    fn needs_targets(&self) -> bool {
        matches!(self.operator, Operator::Cropped(_))
    }

    /// FISTA with gradient restart from `start` (clamped).
    /// Returns (display plane, steps, objective at start, last objective).
    fn fista(
        &self,
        c: usize,
        objective: &ChannelObjective,
        start: &[f32],
        options: &SolveOptions,
    ) -> (Vec<f32>, usize, f64, f64) {
        let step = (1.0 / self.lipschitz[c]) as f32;
        let mut x: Vec<f32> = start.iter().map(|v| v.clamp(0.0, 1.0)).collect();
        let mut y = x.clone();
        let mut t = 1.0f64;
        let mut gradient = Vec::new();
        let mut history: Vec<f64> = Vec::new();
        let mut steps = 0;
        let mut x_next = vec![0.0f32; x.len()];
        while steps < options.max_steps {
            let f = objective(&y, Some(&mut gradient));
            history.push(f);
            steps += 1;
            x_next
                .par_iter_mut()
                .zip(y.par_iter().zip(&gradient))
                .for_each(|(o, (yv, g))| *o = (yv - step * g).clamp(0.0, 1.0));
            // Restart when the momentum points uphill. A sequential sum:
            // rayon's would split by work stealing, and the same frame
            // must give the same display image every time.
            let uphill: f64 = y
                .iter()
                .zip(&x_next)
                .zip(&x)
                .map(|((yv, xn), xv)| ((yv - xn) * (xn - xv)) as f64)
                .sum();
            let t_next = if uphill > 0.0 {
                1.0
            } else {
                (1.0 + (1.0 + 4.0 * t * t).sqrt()) / 2.0
            };
            let momentum = if uphill > 0.0 {
                0.0
            } else {
                ((t - 1.0) / t_next) as f32
            };
            y.par_iter_mut()
                .zip(x_next.par_iter().zip(&x))
                .for_each(|(yv, (xn, xv))| *yv = xn + momentum * (xn - xv));
            std::mem::swap(&mut x, &mut x_next);
            t = t_next;
            if converged(&history, options) {
                break;
            }
        }
        let last = objective(&x, None);
        let first = history.first().copied().unwrap_or(last);
        (x, steps, first, last)
    }
}

/// The kernel on the w×h display grid of I ↦ up2ᵀ(k ⊛ up2(I)), k given by
/// its spectrum on the 2w×2h retinal grid (both periodic):
/// κ[n, m] = Σ_{a,b ∈ {−1,0,1}} w_a w_b k[2n + a, 2m + b], w = (1, 2, 1).
fn fold_to_display(retinal: &Fft2, spectrum: Vec<c32>, display: &Fft2) -> Vec<c32> {
    let k = retinal.inverse(spectrum);
    let (rw, rh) = (retinal.width, retinal.height);
    let (dw, dh) = (display.width, display.height);
    let weight = |a: isize| if a == 0 { 2.0f32 } else { 1.0 };
    let mut out = vec![0.0f32; dw * dh];
    out.par_chunks_mut(dw).enumerate().for_each(|(n, row)| {
        for (m, o) in row.iter_mut().enumerate() {
            let mut acc = 0.0f32;
            for a in -1isize..=1 {
                let y = (2 * n as isize + a).rem_euclid(rh as isize) as usize;
                for b in -1isize..=1 {
                    let x = (2 * m as isize + b).rem_euclid(rw as isize) as usize;
                    acc += weight(a) * weight(b) * k[y * rw + x];
                }
            }
            *o = acc;
        }
    });
    display.forward(&out)
}

/// One depth's terms of the mirrored objective on the retinal grid:
/// |H_D|², H_D* T_D and |T_D|² (T_D = 1 for the sharp image, h_b's spectrum
/// for a blurred target), the veils at zero frequency.
struct RetinalTerms<'a> {
    problem: &'a DisplayProblem,
    retinal: Fft2,
    /// h_b's spectrum per channel, when a target is blurred.
    blur: Option<Vec<Vec<c32>>>,
}

impl<'a> RetinalTerms<'a> {
    fn new(problem: &'a DisplayProblem, width: usize, height: usize) -> Self {
        let retinal = Fft2::new(4 * width, 4 * height);
        let blur = problem
            .blur
            .as_ref()
            .filter(|_| problem.blurred.iter().any(|&b| b))
            .map(|b| b.iter().map(|p| Self::spectrum(&retinal, p)).collect());
        Self {
            problem,
            retinal,
            blur,
        }
    }

    /// The veil is uniform light: on the periodic grid a constant kernel,
    /// i.e. its weight at zero frequency.
    fn spectrum(retinal: &Fft2, p: &Psf) -> Vec<c32> {
        let mut s = retinal.kernel_spectrum(&p.cells, p.window);
        s[0] += c32::new(p.veil as f32, 0.0);
        s
    }

    fn depth(&self, c: usize, depth: usize) -> [Vec<c32>; 3] {
        let h = Self::spectrum(&self.retinal, &self.problem.psfs[c][depth]);
        let gram = h.par_iter().map(|v| c32::new(v.norm_sqr(), 0.0)).collect();
        match (&self.blur, self.problem.blurred[depth]) {
            (Some(b), true) => [
                gram,
                h.par_iter()
                    .zip(&b[c])
                    .map(|(hv, bv)| hv.conj() * bv)
                    .collect(),
                b[c].par_iter()
                    .map(|v| c32::new(v.norm_sqr(), 0.0))
                    .collect(),
            ],
            _ => [
                gram,
                h.par_iter().map(|v| v.conj()).collect(),
                vec![c32::new(1.0, 0.0); h.len()],
            ],
        }
    }

    fn fold(&self, spectrum: Vec<c32>, display: &Fft2) -> Vec<c32> {
        fold_to_display(&self.retinal, spectrum, display)
    }
}

impl MirroredOperator {
    fn new(problem: &DisplayProblem, width: usize, height: usize) -> (Self, Vec<f64>) {
        let terms = RetinalTerms::new(problem, width, height);
        let fft = Fft2::new(2 * width, 2 * height);
        let mut normal = Vec::new();
        let mut adjoint_target = Vec::new();
        let mut target_gram = Vec::new();
        let mut lipschitz = Vec::new();
        for c in 0..problem.channels() {
            // Summed over the depths on the retinal grid, folded once.
            let n = terms.retinal.bins() * terms.retinal.height;
            let mut sums = [(); 3].map(|_| vec![c32::new(0.0, 0.0); n]);
            for depth in 0..problem.depths_d.len() {
                for (sum, term) in sums.iter_mut().zip(terms.depth(c, depth)) {
                    sum.par_iter_mut().zip(&term).for_each(|(o, v)| *o += v);
                }
            }
            let [gram, cross, targets] = sums;
            let m: Vec<f32> = terms.fold(gram, &fft).into_iter().map(|v| v.re).collect();
            lipschitz.push(m.iter().fold(0.0f32, |a, v| a.max(*v)) as f64);
            normal.push(m);
            adjoint_target.push(terms.fold(cross, &fft));
            target_gram.push(
                terms
                    .fold(targets, &fft)
                    .into_iter()
                    .map(|v| v.re)
                    .collect(),
            );
        }
        (
            Self {
                fft,
                normal,
                adjoint_target,
                target_gram,
            },
            lipschitz,
        )
    }

    fn mirror(plane: &[f32], w: usize, h: usize) -> Vec<f32> {
        extend_plane(plane, w, h, 0, 0, 2 * w, 2 * h)
    }

    /// Σ_D A_Dᵀ t_D(I) on the frame (the mirrored result's first quadrant).
    fn adjoint_target(&self, c: usize, input: &[f32], w: usize, h: usize) -> Vec<f32> {
        let mut s = self.fft.forward(&Self::mirror(input, w, h));
        s.par_iter_mut()
            .zip(&self.adjoint_target[c])
            .for_each(|(x, k)| *x *= k);
        first_quadrant(&self.fft.inverse(s), w, h)
    }

    #[allow(clippy::too_many_arguments)]
    fn value_and_gradient(
        &self,
        c: usize,
        display: &[f32],
        w: usize,
        h: usize,
        adjoint_target: &[f32],
        constant: f64,
        gradient: Option<&mut Vec<f32>>,
    ) -> f64 {
        let mut s = self.fft.forward(&Self::mirror(display, w, h));
        s.par_iter_mut()
            .zip(&self.normal[c])
            .for_each(|(x, m)| *x *= *m);
        let normal = first_quadrant(&self.fft.inverse(s), w, h);
        let value: f64 = display
            .iter()
            .zip(&normal)
            .zip(adjoint_target)
            .map(|((d, m), b)| (*d as f64) * (0.5 * *m as f64 - *b as f64))
            .sum();
        if let Some(g) = gradient {
            g.clear();
            g.extend(normal.iter().zip(adjoint_target).map(|(m, b)| m - b));
        }
        value + constant
    }
}

impl CroppedOperator {
    fn new(problem: &DisplayProblem, width: usize, height: usize) -> Self {
        let half = problem
            .psfs
            .iter()
            .flatten()
            .map(|p| p.window / 2)
            .max()
            .unwrap_or(0);
        let fw = smooth_size_at_least((2 * width + 2 * half) as f64);
        let fh = smooth_size_at_least((2 * height + 2 * half) as f64);
        let fft = Fft2::new(fw, fh);
        let spectra = problem
            .psfs
            .iter()
            .map(|ch| {
                ch.iter()
                    .map(|p| fft.kernel_spectrum(&p.cells, p.window))
                    .collect()
            })
            .collect();
        let veils = problem
            .psfs
            .iter()
            .map(|ch| ch.iter().map(|p| p.veil as f32).collect())
            .collect();
        Self {
            fft,
            half,
            spectra,
            veils,
        }
    }

    /// Power iteration on Σ_D A_Dᵀ A_D for channel `c`.
    fn largest_eigenvalue(&self, c: usize, w: usize, h: usize) -> f64 {
        let n = w * h;
        let zero = vec![0.0f32; 4 * n];
        let targets: Vec<&[f32]> = vec![&zero; self.spectra[c].len()];
        let norm = |x: &[f32]| x.iter().map(|a| (*a as f64).powi(2)).sum::<f64>().sqrt();
        // A pattern with every frequency, so no eigenvector is missed.
        let mut v: Vec<f32> = (0..n)
            .map(|i| 1.0 + ((i * 7919) % 101) as f32 / 101.0)
            .collect();
        let mut g = Vec::new();
        let mut eig = 0.0;
        for _ in 0..POWER_STEPS {
            self.value_and_gradient(c, &v, w, h, &targets, Some(&mut g));
            let (ng, nv) = (norm(&g), norm(&v));
            if ng == 0.0 || nv == 0.0 {
                break;
            }
            eig = ng / nv;
            v = g.iter().map(|a| (*a as f64 / ng) as f32).collect();
        }
        eig
    }

    /// ½ Σ_D ‖A_D d − t_D‖² for channel `c`, and its gradient Σ_D A_Dᵀ r_D
    /// into `gradient` when given.
    fn value_and_gradient(
        &self,
        c: usize,
        display: &[f32],
        w: usize,
        h: usize,
        targets: &[&[f32]],
        gradient: Option<&mut Vec<f32>>,
    ) -> f64 {
        let a = self.half;
        let (w2, h2) = (2 * w, 2 * h);
        let (fw, fh) = (self.fft.width, self.fft.height);
        let up = up2_plane(display, w, h);
        let u = self.fft.forward(&extend_plane(&up, w2, h2, a, a, fw, fh));
        let mean = display.iter().map(|&v| v as f64).sum::<f64>() / (w * h) as f64;
        let want_gradient = gradient.is_some();
        let mut acc = want_gradient.then(|| vec![c32::new(0.0, 0.0); u.len()]);
        let mut veil_adjoint = 0.0f64;
        let mut value = 0.0f64;
        for (d, (spectrum, &veil)) in self.spectra[c].iter().zip(&self.veils[c]).enumerate() {
            let mut s = u.clone();
            s.par_iter_mut().zip(spectrum).for_each(|(x, k)| *x *= k);
            let full = self.fft.inverse(s);
            let lift = (veil as f64 * mean) as f32;
            let mut placed = want_gradient.then(|| vec![0.0f32; fw * fh]);
            let mut residual_sum = 0.0f64;
            for y in 0..h2 {
                let row = &full[(y + a) * fw + a..(y + a) * fw + a + w2];
                let target = &targets[d][y * w2..(y + 1) * w2];
                for x in 0..w2 {
                    let r = row[x] + lift - target[x];
                    value += (r as f64) * (r as f64);
                    residual_sum += r as f64;
                    if let Some(p) = placed.as_mut() {
                        p[(y + a) * fw + a + x] = r;
                    }
                }
            }
            if let (Some(p), Some(acc)) = (placed, acc.as_mut()) {
                let rs = self.fft.forward(&p);
                acc.par_iter_mut()
                    .zip(rs.par_iter().zip(spectrum))
                    .for_each(|(o, (r, k))| *o += k.conj() * r);
                veil_adjoint += veil as f64 * residual_sum;
            }
        }
        if let (Some(g), Some(acc)) = (gradient, acc) {
            let full = self.fft.inverse(acc);
            // Adjoint of the symmetric extension: fold the padded grid back.
            let xs: Vec<usize> = (0..w2 + 2 * a)
                .map(|x| symmetric_index(x as isize - a as isize, w2))
                .collect();
            let mut retinal = vec![0.0f32; w2 * h2];
            for y in 0..h2 + 2 * a {
                let sy = symmetric_index(y as isize - a as isize, h2);
                let dst = &mut retinal[sy * w2..(sy + 1) * w2];
                for (x, &sx) in xs.iter().enumerate() {
                    dst[sx] += full[y * fw + x];
                }
            }
            // Adjoint of up2 (sum of each 2×2 block) and of the veil's mean.
            let lift = (veil_adjoint / (w * h) as f64) as f32;
            g.clear();
            g.resize(w * h, 0.0);
            for y in 0..h {
                for x in 0..w {
                    let i = 2 * y * w2 + 2 * x;
                    g[y * w + x] =
                        retinal[i] + retinal[i + 1] + retinal[i + w2] + retinal[i + w2 + 1] + lift;
                }
            }
        }
        0.5 * value
    }
}

/// Power-iteration steps and the margin on what they find (power iteration
/// approaches the largest eigenvalue from below).
const POWER_STEPS: usize = 30;
const POWER_MARGIN: f64 = 1.05;

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

/// Whether the objective rose by less than the tolerance (as a PSNR) over
/// the last `window` steps.
fn converged(history: &[f64], options: &SolveOptions) -> bool {
    if options.tolerance_db <= 0.0 || history.len() <= options.window {
        return false;
    }
    let best = |s: &[f64]| s.iter().copied().fold(f64::INFINITY, f64::min);
    let before = best(&history[..history.len() - options.window]);
    let now = best(history);
    if now <= 0.0 {
        return true;
    }
    10.0 * (before / now).log10() < options.tolerance_db
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

/// How a [`SolvedPrefilter`] makes the display image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SolveMode {
    /// The linear least-squares prefilter, clamped.
    Linear,
    /// The linear output and `k` projected-gradient steps.
    Refine(usize),
    /// Solved to convergence.
    Optimal,
}

/// The refinement's terms at one frame size for the device
/// ([`DisplayProblem::device_terms`]).
#[derive(Debug, Clone)]
pub struct DeviceTerms {
    pub linear: Vec<Vec<f32>>,
    pub adjoint_target: Vec<Vec<f32>>,
    pub normal: Vec<Vec<f32>>,
    pub step: Vec<f32>,
}

/// `lsq`, `refine:k` and `optimal` as the preprocessing of a display system.
#[derive(Debug, Clone)]
pub struct SolvedPrefilter {
    /// The display system whose optics the problem holds ("doe+wiener").
    pub method: String,
    pub problem: Arc<DisplayProblem>,
    pub mode: SolveMode,
    /// The last frame's solve, for reports.
    pub last: Option<SolveReport>,
}

impl SolvedPrefilter {
    pub fn new(method: impl Into<String>, problem: Arc<DisplayProblem>, mode: SolveMode) -> Self {
        Self {
            method: method.into(),
            problem,
            mode,
            last: None,
        }
    }
}

impl Preprocess for SolvedPrefilter {
    fn describe(&self) -> String {
        let p = &self.problem;
        let what = match self.mode {
            SolveMode::Linear => "linear least-squares prefilter".to_string(),
            SolveMode::Refine(k) => {
                format!("least-squares prefilter + {k} projected-gradient steps")
            }
            SolveMode::Optimal => "bounded least-squares optimum".to_string(),
        };
        let mut s = format!(
            "{what} of {} ({} objective over {} depths, K = {:e})",
            self.method,
            p.objective.name(),
            p.depths_d.len(),
            p.k_reg
        );
        if let Some(r) = self
            .last
            .as_ref()
            .filter(|_| self.mode == SolveMode::Optimal)
        {
            let steps: Vec<String> = r.steps.iter().map(|n| n.to_string()).collect();
            s.push_str(&format!(
                "; last frame {} steps per channel",
                steps.join("/")
            ));
        }
        s
    }

    fn run(&mut self, input: &Image) -> Result<Image, PreprocessError> {
        check_frame(input, self.problem.channels())?;
        let linear = self.problem.linear_unclamped(input).clamped();
        let options = match self.mode {
            SolveMode::Linear => return Ok(linear),
            SolveMode::Refine(k) => SolveOptions::steps(k),
            SolveMode::Optimal => SolveOptions::CONVERGED,
        };
        let (display, report) = self.problem.solve(input, &linear, &options);
        self.last = Some(report);
        Ok(display)
    }
}

#[cfg(test)]
mod tests;
