//! The split solver (`admm:K`): the panel's box constraint split off the
//! least-squares objective (ADMM, as Le-ADMM and USRNet unroll it). The
//! data step (N + ρ) x = b + ρ (z − u) is exact, one FFT pair: Σ_D A_Dᵀ A_D
//! is diagonal in the mirrored grid's basis. The constraint step is a clamp.
//! So a step costs what a projected-gradient step costs, but it solves
//! the quadratic part rather than descending it by 1/L.

use super::operator::Operator;
use super::solver::ProblemPlan;
use rayon::prelude::*;

/// The penalty of each step and the relaxation: ρ_k = `rho` · L ·
/// `growth`^k (L the channel's largest eigenvalue of Σ_D A_Dᵀ A_D), so
/// that the early steps move far from the start and the later ones settle
/// on the constraint (the continuation of half-quadratic splitting).
/// `relaxation` α mixes the data step with the last constraint step
/// (α x + (1 − α) z; 1 is plain ADMM, 1.5–1.8 is the usual over-relaxation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SplitSchedule {
    pub rho: f64,
    pub growth: f64,
    pub relaxation: f64,
}

impl SplitSchedule {
    /// The schedule `admm:K` runs (docs/optimal.md: chosen on crops of
    /// data/images/train by `cargo run --release --example split_schedule`).
    pub const SHIPPED: SplitSchedule = SplitSchedule {
        rho: 0.05,
        growth: 1.0,
        relaxation: 1.8,
    };

    /// The penalty of step `k` (from 0) for a channel whose step bound is `lipschitz`.
    pub fn rho_at(&self, k: usize, lipschitz: f64) -> f32 {
        (self.rho * lipschitz * self.growth.powi(k as i32)) as f32
    }
}

/// Where a channel's split solve stopped: the constraint's copy z (the
/// display plane, in [0, 1]), the scaled dual u and the steps taken (the
/// schedule goes on from there: K steps and K more are 2K steps).
#[derive(Debug, Clone, PartialEq)]
pub struct SplitState {
    pub(super) z: Vec<f32>,
    pub(super) u: Vec<f32>,
    pub(super) steps: usize,
}

impl SplitState {
    /// A start at `start` (clamped), no dual.
    pub(super) fn at(start: &[f32]) -> Self {
        Self {
            z: start.iter().map(|v| v.clamp(0.0, 1.0)).collect(),
            u: vec![0.0; start.len()],
            steps: 0,
        }
    }
}

impl ProblemPlan {
    /// `steps` split steps of channel `c` for the frame plane `input`,
    /// from `state`, on `schedule`. `None` on the cropped path (no exact
    /// data step there).
    pub(super) fn split_from(
        &self,
        c: usize,
        input: &[f32],
        mut state: SplitState,
        steps: usize,
        schedule: &SplitSchedule,
    ) -> Option<SplitState> {
        let Operator::Mirrored(op) = &self.operator else {
            return None;
        };
        let (w, h) = (self.width, self.height);
        let b = op.adjoint_target_spectrum(c, input, w, h);
        let alpha = schedule.relaxation as f32;
        let mut v = vec![0.0f32; w * h];
        for k in state.steps..state.steps + steps {
            let rho = schedule.rho_at(k, self.lipschitz[c]);
            v.par_iter_mut()
                .zip(state.z.par_iter().zip(&state.u))
                .for_each(|(o, (z, u))| *o = z - u);
            let x = op.penalised_solve(c, &b, &v, rho, w, h);
            // With a penalty that grows, the scaled dual shrinks with it
            // (u = y/ρ for the same unscaled multiplier y).
            let next_rho = schedule.rho_at(k + 1, self.lipschitz[c]);
            let rescale = rho / next_rho;
            state
                .z
                .par_iter_mut()
                .zip(state.u.par_iter_mut().zip(&x))
                .for_each(|(z, (u, x))| {
                    let relaxed = alpha * x + (1.0 - alpha) * *z;
                    let z_next = (relaxed + *u).clamp(0.0, 1.0);
                    *u = (*u + relaxed - z_next) * rescale;
                    *z = z_next;
                });
        }
        state.steps += steps;
        Some(state)
    }
}

/// The split solver's terms at one frame size, as the device takes them:
/// per channel the gains (the DCT filter's layout,
/// [`crate::sim::wiener::dct_plane`]) of the `lsq` start, of the data term
/// Σ_D A_Dᵀ t_D / (N + ρ) and of the penalty's share ρ / (N + ρ), so that
/// the data step is x = data(I) + penalty(z − u); and the relaxation.
#[derive(Debug, Clone)]
pub struct SplitTerms {
    pub linear: Vec<Vec<f32>>,
    pub data: Vec<Vec<f32>>,
    pub penalty: Vec<Vec<f32>>,
    pub relaxation: f32,
}

impl super::DisplayProblem {
    /// [`SplitTerms`] at `width`×`height` for `schedule`. The device keeps
    /// one gain set per operator, so its penalty is constant (growth 1);
    /// the PSFs must be mirror-symmetric.
    pub fn device_split_terms(
        &self,
        width: usize,
        height: usize,
        schedule: &SplitSchedule,
    ) -> Result<SplitTerms, crate::sim::SimError> {
        if schedule.growth != 1.0 {
            return Err(crate::sim::SimError::Invalid(format!(
                "the device's split solver keeps its penalty constant; this schedule grows it \
                 ×{} a step",
                schedule.growth
            )));
        }
        let plan = self.plan(width, height);
        let Operator::Mirrored(op) = &plan.operator else {
            return Err(crate::sim::SimError::Invalid(
                "the PSFs are not mirror-symmetric: the split solver has no exact data step".into(),
            ));
        };
        let mut data = Vec::new();
        let mut penalty = Vec::new();
        for c in 0..self.channels() {
            let rho = schedule.rho_at(0, plan.lipschitz[c]);
            let spectrum: Vec<num_complex::Complex32> = op.adjoint_target[c]
                .iter()
                .zip(&op.normal[c])
                .map(|(a, m)| a / (m + rho))
                .collect();
            data.push(crate::sim::wiener::dct_plane(&spectrum, width, height, c)?);
            let share: Vec<num_complex::Complex32> = op.normal[c]
                .iter()
                .map(|m| num_complex::Complex32::new(rho / (m + rho), 0.0))
                .collect();
            penalty.push(crate::sim::wiener::dct_plane(&share, width, height, c)?);
        }
        Ok(SplitTerms {
            linear: plan.linear.dct_gains()?,
            data,
            penalty,
            relaxation: schedule.relaxation as f32,
        })
    }
}
