//! A problem prepared for one frame size and its accelerated projected
//! gradient (FISTA with restart): the per-channel objective, the step
//! bound, the stopping rule. Apart from the operators it applies.

use super::operator::{CroppedOperator, MirroredOperator, Operator, POWER_MARGIN};
use super::{DisplayProblem, SolveOptions, linear_plan};
use crate::sim::wiener::WienerPlan;
use nedrt_core::image::Image;
use rayon::prelude::*;
use std::sync::Arc;

/// A problem prepared for frames of one size.
#[derive(Debug)]
pub struct ProblemPlan {
    pub width: usize,
    pub height: usize,
    pub(super) operator: Operator,
    /// Lipschitz constant of the gradient, per channel.
    pub(super) lipschitz: Vec<f64>,
    /// The linear least-squares prefilter at this size.
    pub(super) linear: WienerPlan,
}

/// One channel's objective for one frame: value, and gradient when asked.
pub(super) type ChannelObjective<'a> =
    Box<dyn Fn(&[f32], Option<&mut Vec<f32>>) -> f64 + Sync + 'a>;

impl ProblemPlan {
    pub(super) fn new(problem: &DisplayProblem, width: usize, height: usize) -> Self {
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
    pub(super) fn cropped(
        problem: &DisplayProblem,
        width: usize,
        height: usize,
        linear: WienerPlan,
    ) -> Self {
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
    pub(super) fn channel_objective<'a>(
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

    pub(super) fn needs_targets(&self) -> bool {
        matches!(self.operator, Operator::Cropped(_))
    }

    /// FISTA with gradient restart from `state` (a start, or where an
    /// earlier solve stopped: its iterate, its extrapolated point and its
    /// momentum, so that K steps and then K more are 2K steps).
    /// Returns (where it stopped, steps, objective at start, last objective).
    pub(super) fn fista_from(
        &self,
        c: usize,
        objective: &ChannelObjective,
        state: FistaState,
        options: &SolveOptions,
    ) -> (FistaState, usize, f64, f64) {
        let step = (1.0 / self.lipschitz[c]) as f32;
        let FistaState {
            mut x,
            mut y,
            mut t,
        } = state;
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
        (FistaState { x, y, t }, steps, first, last)
    }
}

/// Where a channel's FISTA stopped: its iterate, its extrapolated point
/// and its momentum ([`ProblemPlan::fista_from`] goes on from it).
#[derive(Debug, Clone, PartialEq)]
pub struct FistaState {
    x: Vec<f32>,
    y: Vec<f32>,
    t: f64,
}

impl FistaState {
    /// A fresh start at `start` (clamped), no momentum.
    pub fn at(start: &[f32]) -> Self {
        let x: Vec<f32> = start.iter().map(|v| v.clamp(0.0, 1.0)).collect();
        Self {
            y: x.clone(),
            x,
            t: 1.0,
        }
    }

    /// The iterate: the display plane so far.
    pub fn x(&self) -> &[f32] {
        &self.x
    }
}

/// Whether the objective rose by less than the tolerance (as a PSNR) over
/// the last `window` steps.
pub(super) fn converged(history: &[f64], options: &SolveOptions) -> bool {
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
