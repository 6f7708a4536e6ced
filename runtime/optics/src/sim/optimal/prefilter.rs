//! The solved display image as a display system's preprocessing
//! (`lsq`, `refine:k`, `optimal`) and the refinement's terms for the device.
//! Apart from the problem: the adapters other crates hold.

use super::{DisplayProblem, SolveOptions, SolveReport};
use nedrt_core::image::Image;
use nedrt_core::preprocess::{Preprocess, PreprocessError, check_frame};
use std::sync::Arc;

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
