//! The solved display image as a display system's preprocessing
//! (`lsq`, `refine:k`, `optimal`) and the refinement's terms for the device.
//! Apart from the problem: the adapters other crates hold.

use super::{DisplayProblem, FistaState, SolveOptions, SolveReport, SplitSchedule, SplitState};
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
    /// The linear output and `k` steps of the split solver
    /// ([`SplitSchedule::SHIPPED`]).
    Admm(usize),
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

/// Where the last frame's solve stopped, per channel.
#[derive(Debug, Clone)]
enum Stopped {
    Fista(Vec<FistaState>),
    Split(Vec<SplitState>),
}

/// `lsq`, `refine:k`, `admm:k` and `optimal` as the preprocessing of a display system.
#[derive(Debug, Clone)]
pub struct SolvedPrefilter {
    /// The display system whose optics the problem holds ("doe+wiener").
    pub method: String,
    pub problem: Arc<DisplayProblem>,
    pub mode: SolveMode,
    /// The last frame's solve, for reports.
    pub last: Option<SolveReport>,
    /// `refine:K` and `admm:K` only: on a frame unchanged since the last
    /// (RMS change at most [`SolvedPrefilter::STILL_RMS`]), go on from
    /// where the last frame's solve stopped instead of the linear
    /// prefilter, so that a still scene converges over frames at K steps
    /// a frame.
    pub warm_start: bool,
    /// The last frame and where its solve stopped, per channel.
    still: Option<(Image, Stopped)>,
    /// Frames in a row the last solve went on from the one before.
    warm_frames: u64,
}

impl SolvedPrefilter {
    /// A frame whose RMS change from the last is at most this (a quarter
    /// of an 8-bit code, in linear intensity) is the same scene still: a
    /// renderer's noise, not a change the eye would see.
    pub const STILL_RMS: f64 = 1.0 / 1024.0;

    pub fn new(method: impl Into<String>, problem: Arc<DisplayProblem>, mode: SolveMode) -> Self {
        Self {
            method: method.into(),
            problem,
            mode,
            last: None,
            warm_start: false,
            still: None,
            warm_frames: 0,
        }
    }

    /// The same, warm-started on still frames (`refine:K`, `admm:K`).
    pub fn warm_started(mut self) -> Self {
        self.warm_start = true;
        self
    }

    /// Frames in a row the last solve went on from the one before (0: it
    /// started from the linear prefilter).
    pub fn warm_frames(&self) -> u64 {
        self.warm_frames
    }

    /// `k` split-solver steps from `states`.
    fn split_from(
        &self,
        input: &Image,
        states: Vec<SplitState>,
        k: usize,
    ) -> Result<(Image, Vec<SplitState>), PreprocessError> {
        self.problem
            .solve_split(input, states, k, &SplitSchedule::SHIPPED)
            .map_err(|e| PreprocessError::Engine {
                engine: self.describe(),
                reason: e.to_string(),
            })
    }

    /// Where a still frame's solve goes on from, if `input` is one.
    fn still_states(&mut self, input: &Image) -> Option<Stopped> {
        let (last, states) = self.still.take()?;
        let same_size = (last.width, last.height, last.channels())
            == (input.width, input.height, input.channels());
        if !same_size {
            return None;
        }
        let n = input.data().len().max(1) as f64;
        let change = (last
            .data()
            .iter()
            .zip(input.data())
            .map(|(a, b)| ((a - b) as f64).powi(2))
            .sum::<f64>()
            / n)
            .sqrt();
        (change <= Self::STILL_RMS).then_some(states)
    }
}

impl Preprocess for SolvedPrefilter {
    fn describe(&self) -> String {
        let p = &self.problem;
        let what = match self.mode {
            SolveMode::Linear => "linear least-squares prefilter".to_string(),
            SolveMode::Refine(k) if self.warm_start => format!(
                "least-squares prefilter + {k} projected-gradient steps, going on from the last \
                 frame's on a still one"
            ),
            SolveMode::Refine(k) => {
                format!("least-squares prefilter + {k} projected-gradient steps")
            }
            SolveMode::Admm(k) if self.warm_start => format!(
                "least-squares prefilter + {k} split-solver (ADMM) steps, going on from the last \
                 frame's on a still one"
            ),
            SolveMode::Admm(k) => {
                format!("least-squares prefilter + {k} split-solver (ADMM) steps")
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
        if self.warm_start {
            let still = self.still_states(input);
            self.warm_frames = if still.is_some() {
                self.warm_frames + 1
            } else {
                0
            };
            match self.mode {
                SolveMode::Refine(k) => {
                    let states = match still {
                        Some(Stopped::Fista(states)) => states,
                        _ => {
                            let linear = self.problem.linear_unclamped(input).clamped();
                            linear.planes().map(FistaState::at).collect()
                        }
                    };
                    let options = SolveOptions::steps(k);
                    let (display, report, states) =
                        self.problem.solve_from(input, states, &options);
                    self.still = Some((input.clone(), Stopped::Fista(states)));
                    self.last = Some(report);
                    return Ok(display);
                }
                SolveMode::Admm(k) => {
                    let states = match still {
                        Some(Stopped::Split(states)) => states,
                        _ => self.problem.split_start(input),
                    };
                    let (display, states) = self.split_from(input, states, k)?;
                    self.still = Some((input.clone(), Stopped::Split(states)));
                    return Ok(display);
                }
                SolveMode::Linear | SolveMode::Optimal => {}
            }
        }
        let options = match self.mode {
            SolveMode::Linear => return Ok(self.problem.linear_unclamped(input).clamped()),
            SolveMode::Admm(k) => {
                let start = self.problem.split_start(input);
                return self.split_from(input, start, k).map(|(display, _)| display);
            }
            SolveMode::Refine(k) => SolveOptions::steps(k),
            SolveMode::Optimal => SolveOptions::CONVERGED,
        };
        let linear = self.problem.linear_unclamped(input).clamped();
        let (display, report) = self.problem.solve(input, &linear, &options);
        self.last = Some(report);
        Ok(display)
    }
}
