//! One frame's split solve taken a step at a time by a caller that acts
//! between each data step and its clamp: the unrolled preprocessor, whose
//! learned correction sees the relaxed point, the dual and the objective's
//! gradient there. Step for step what the trainer computes
//! (models/nedrt_train/unrolled.py `Unrolled.forward`):
//!
//! ```text
//! x  = (N + ρ_k)⁻¹ (Σ_D A_Dᵀ t_D + ρ_k (z − u))      relax
//! r  = α_k x + (1 − α_k) z
//! z⁺ = clamp(r + u + c_k, 0, 1),  u⁺ = u + r − z⁺    constrain (c_k: the correction)
//! ```
//!
//! from z = the clamped `lsq` image and u = 0. Unlike `admm:K`'s schedule
//! the dual is not rescaled when ρ changes from one step to the next: the
//! trainer does not rescale it, and its learned ρ_k are what they are with
//! that rule. With c_k = 0 and one ρ for every step it is `admm:K`.

use std::sync::Arc;

use num_complex::Complex32 as c32;
use rayon::prelude::*;

use super::DisplayProblem;
use super::operator::Operator;
use super::solver::ProblemPlan;
use crate::sim::SimError;
use nedrt_core::image::Image;

/// Where one frame's step-by-step split solve is (see the module docs).
#[derive(Debug)]
pub struct SplitSteps {
    plan: Arc<ProblemPlan>,
    /// Per channel: the data term's mirrored spectrum.
    data: Vec<Vec<c32>>,
    /// Per channel: Σ_D A_Dᵀ t_D on the frame (the gradient's constant).
    adjoint: Vec<Vec<f32>>,
    z: Vec<Vec<f32>>,
    u: Vec<Vec<f32>>,
    /// The last relaxed point, per channel (empty before the first step).
    r: Vec<Vec<f32>>,
}

impl DisplayProblem {
    /// A split solve of `input` to be taken a step at a time, from the
    /// clamped `lsq` image. An error without the mirrored form
    /// ([`DisplayProblem::has_split`]).
    pub fn split_steps(&self, input: &Image) -> Result<SplitSteps, SimError> {
        let (w, h) = (input.width, input.height);
        let plan = self.plan(w, h);
        let Operator::Mirrored(op) = &plan.operator else {
            return Err(SimError::Invalid(
                "the PSFs are not mirror-symmetric: the split solver has no exact data step".into(),
            ));
        };
        let channels = self.channels();
        let data: Vec<Vec<c32>> = (0..channels)
            .map(|c| op.adjoint_target_spectrum(c, input.plane(c), w, h))
            .collect();
        // The same spectrum back on the frame (not a second forward FFT).
        let adjoint = data
            .iter()
            .map(|b| crate::sim::wiener::first_quadrant(&op.fft.inverse(b.clone()), w, h))
            .collect();
        let z: Vec<Vec<f32>> = self
            .linear_unclamped(input)
            .planes()
            .map(|p| p.iter().map(|v| v.clamp(0.0, 1.0)).collect())
            .collect();
        let u = z.iter().map(|p| vec![0.0; p.len()]).collect();
        Ok(SplitSteps {
            plan,
            data,
            adjoint,
            z,
            u,
            r: Vec::new(),
        })
    }
}

impl SplitSteps {
    fn op(&self) -> &super::operator::MirroredOperator {
        match &self.plan.operator {
            Operator::Mirrored(op) => op,
            // `split_steps` makes a SplitSteps only on the mirrored form.
            Operator::Cropped(_) => unreachable!("a split solve on the cropped form"),
        }
    }

    /// The data step at penalty ρ = `rho_share` · L (L the channel's step
    /// bound) and its relaxation by `relaxation` (α).
    pub fn relax(&mut self, rho_share: f32, relaxation: f32) {
        let (w, h) = (self.plan.width, self.plan.height);
        let op = self.op();
        let r = (0..self.z.len())
            .map(|c| {
                let rho = rho_share * self.plan.lipschitz[c] as f32;
                let v: Vec<f32> = self.z[c]
                    .par_iter()
                    .zip(&self.u[c])
                    .map(|(z, u)| z - u)
                    .collect();
                let x = op.penalised_solve(c, &self.data[c], &v, rho, w, h);
                x.par_iter()
                    .zip(&self.z[c])
                    .map(|(x, z)| relaxation * x + (1.0 - relaxation) * z)
                    .collect()
            })
            .collect();
        self.r = r;
    }

    /// What the step's correction sees, after [`SplitSteps::relax`]: the
    /// planes r + u, then u, then ∇f(r) / L = (N r − Σ_D A_Dᵀ t_D) / L,
    /// each per channel (9 planes for three channels).
    pub fn correction_inputs(&self) -> Image {
        let (w, h) = (self.plan.width, self.plan.height);
        let op = self.op();
        let mut planes: Vec<Vec<f32>> = Vec::new();
        for (r, u) in self.r.iter().zip(&self.u) {
            planes.push(r.iter().zip(u).map(|(r, u)| r + u).collect());
        }
        planes.extend(self.u.iter().cloned());
        for (c, r) in self.r.iter().enumerate() {
            let mut g = Vec::new();
            op.value_and_gradient(c, r, w, h, &self.adjoint[c], 0.0, Some(&mut g));
            let l = self.plan.lipschitz[c] as f32;
            planes.push(g.into_iter().map(|v| v / l).collect());
        }
        Image::from_planes(w, h, planes)
    }

    /// The constraint step: z = clamp(r + u + `correction`) (no correction:
    /// the classical step), u = u + r − z. An error before
    /// [`SplitSteps::relax`] or for a correction of the wrong shape.
    pub fn constrain(&mut self, correction: Option<&Image>) -> Result<(), SimError> {
        let (w, h) = (self.plan.width, self.plan.height);
        if self.r.len() != self.z.len() {
            return Err(SimError::Invalid(
                "a constraint step before its data step".into(),
            ));
        }
        if let Some(c) = correction
            && (c.width, c.height, c.channels()) != (w, h, self.z.len())
        {
            return Err(SimError::Invalid(format!(
                "a {}×{} correction of {} channels for a {w}×{h} display image of {}",
                c.width,
                c.height,
                c.channels(),
                self.z.len()
            )));
        }
        for (ch, ((z, u), r)) in self
            .z
            .iter_mut()
            .zip(self.u.iter_mut())
            .zip(std::mem::take(&mut self.r))
            .enumerate()
        {
            let extra = correction.map(|c| c.plane(ch));
            z.par_iter_mut()
                .zip(u.par_iter_mut())
                .zip(r.par_iter())
                .enumerate()
                .for_each(|(i, ((z, u), r))| {
                    let point = r + *u + extra.map_or(0.0, |e| e[i]);
                    let next = point.clamp(0.0, 1.0);
                    *u = *u + r - next;
                    *z = next;
                });
        }
        Ok(())
    }

    /// The display image so far (z, in [0, 1]).
    pub fn display(&self) -> Image {
        Image::from_planes(self.plan.width, self.plan.height, self.z.clone())
    }
}

/// The unrolled model's terms at one frame size, as the device takes them
/// (per channel, the DCT filter's layout, [`crate::sim::wiener::dct_plane`]):
/// the `lsq` start's gains; b = Σ_D A_Dᵀ t_D / L and N / L, the gradient's
/// constant and operator; and per step the solve's gains L / (N + ρ_k), so
/// that the data step (N + ρ_k)⁻¹ (Σ_D A_Dᵀ t_D + ρ_k (z − u)), as
/// [`SplitSteps::relax`] computes it, is one filter of b + (ρ_k / L)(z − u).
#[derive(Debug, Clone)]
pub struct UnrolledTerms {
    pub linear: Vec<Vec<f32>>,
    pub adjoint: Vec<Vec<f32>>,
    pub normal: Vec<Vec<f32>>,
    pub steps: Vec<StepTerms>,
}

/// One step's gains per channel: the solve's, L / (N + ρ_k).
#[derive(Debug, Clone, Default)]
pub struct StepTerms {
    pub solve: Vec<Vec<f32>>,
}

impl DisplayProblem {
    /// [`UnrolledTerms`] at `width`×`height` for steps of penalties
    /// `rho_shares` (ρ_k / L). The PSFs must be mirror-symmetric.
    pub fn device_unrolled_terms(
        &self,
        width: usize,
        height: usize,
        rho_shares: &[f32],
    ) -> Result<UnrolledTerms, SimError> {
        use crate::sim::wiener::dct_plane;
        let plan = self.plan(width, height);
        let Operator::Mirrored(op) = &plan.operator else {
            return Err(SimError::Invalid(
                "the PSFs are not mirror-symmetric: the split solver has no exact data step".into(),
            ));
        };
        let real = |v: f32| c32::new(v, 0.0);
        let mut adjoint = Vec::new();
        let mut normal = Vec::new();
        let mut steps = vec![StepTerms::default(); rho_shares.len()];
        for c in 0..self.channels() {
            let l = plan.lipschitz[c] as f32;
            let a: Vec<c32> = op.adjoint_target[c].iter().map(|v| v / l).collect();
            adjoint.push(dct_plane(&a, width, height, c)?);
            let n: Vec<c32> = op.normal[c].iter().map(|m| real(m / l)).collect();
            normal.push(dct_plane(&n, width, height, c)?);
            for (k, share) in rho_shares.iter().enumerate() {
                let rho = share * l;
                let solve: Vec<c32> = op.normal[c].iter().map(|m| real(l / (m + rho))).collect();
                steps[k].solve.push(dct_plane(&solve, width, height, c)?);
            }
        }
        Ok(UnrolledTerms {
            linear: plan.linear.dct_gains()?,
            adjoint,
            normal,
            steps,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{frame, problem, symmetric_problem};
    use super::super::{Objective, SplitSchedule};
    use nedrt_core::image::Image;

    #[test]
    fn uncorrected_steps_at_one_penalty_are_admm() {
        let p = symmetric_problem(Objective::Target);
        let input = frame(16, 12, 1);
        let schedule = SplitSchedule::SHIPPED;
        let mut steps = p.split_steps(&input).expect("mirrored");
        assert_eq!(
            steps.display().data(),
            p.linear_unclamped(&input).clamped().data()
        );
        for _ in 0..5 {
            steps.relax(schedule.rho as f32, schedule.relaxation as f32);
            steps.constrain(None).expect("after relax");
        }
        let (admm, _) = p
            .solve_split(&input, p.split_start(&input), 5, &schedule)
            .expect("mirrored");
        // The same arithmetic but for ρ's rounding (f32 here, f64 there).
        let d = steps
            .display()
            .data()
            .iter()
            .zip(admm.data())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(d <= 1e-5, "{d}");
    }

    #[test]
    fn the_correction_sees_the_point_the_dual_and_the_objectives_gradient() {
        let p = symmetric_problem(Objective::Target);
        let input = frame(12, 10, 1);
        let mut steps = p.split_steps(&input).expect("mirrored");
        steps.relax(0.05, 1.8);
        steps.constrain(None).expect("after relax");
        steps.relax(0.2, 1.5);
        let seen = steps.correction_inputs();
        assert_eq!(seen.channels(), 3);
        let (point, dual, gradient) = (seen.plane(0), seen.plane(1), seen.plane(2));
        // r = point − dual; the gradient plane is ∂f/∂r / L.
        let r: Vec<f32> = point.iter().zip(dual).map(|(p, u)| p - u).collect();
        let f =
            |d: &[f32]| p.objective_value(&input, &Image::from_planes(12, 10, vec![d.to_vec()]))[0];
        let lipschitz = p.plan(12, 10).lipschitz[0];
        // A quadratic: the central difference along a direction is exact
        // but for rounding, which a whole-frame direction keeps small.
        let direction: Vec<f32> = (0..r.len())
            .map(|i| ((i * 7919) % 13) as f32 / 6.0 - 1.0)
            .collect();
        let eps = 0.1f32;
        let along =
            |s: f32| -> Vec<f32> { r.iter().zip(&direction).map(|(r, v)| r + s * v).collect() };
        let slope = (f(&along(eps)) - f(&along(-eps))) / (2.0 * eps as f64);
        let got: f64 = gradient
            .iter()
            .zip(&direction)
            .map(|(g, v)| *g as f64 * lipschitz * *v as f64)
            .sum();
        assert!(
            (slope - got).abs() <= 1e-3 * slope.abs(),
            "{slope} against {got}"
        );
    }

    #[test]
    fn a_correction_moves_the_point_before_the_clamp_and_bad_ones_are_refused() {
        let p = symmetric_problem(Objective::Sharp);
        let input = frame(8, 6, 1);
        let mut steps = p.split_steps(&input).expect("mirrored");
        assert!(steps.constrain(None).is_err(), "constrain before relax");
        steps.relax(0.05, 1.8);
        let seen = steps.correction_inputs();
        let shift = Image::from_planes(8, 6, vec![vec![0.25; 48]]);
        let e = steps
            .constrain(Some(&Image::from_planes(4, 6, vec![vec![0.0; 24]])))
            .expect_err("wrong size");
        assert!(e.to_string().contains("4×6"), "{e}");
        steps.constrain(Some(&shift)).expect("right size");
        let want: Vec<f32> = seen
            .plane(0)
            .iter()
            .map(|v| (v + 0.25).clamp(0.0, 1.0))
            .collect();
        assert_eq!(steps.display().plane(0), want.as_slice());
        let q = problem(Objective::Sharp);
        assert!(
            q.split_steps(&input)
                .unwrap_err()
                .to_string()
                .contains("mirror-symmetric")
        );
    }
}
