//! nedrt-stages, layer 2 of nedrt: what runs on every frame, whichever
//! command asks. The preprocessing registry ([`preprocess`]: which
//! "input frame → display frame" each display system runs, and the
//! least-squares family), the prefilters on the device
//! ([`device_prefilter`]: nedrt-gpu's stages fed by nedrt-optics, and
//! [`device_prefilter::OnDevice`] to run one as a host preprocessor), the
//! stage combinator ([`Chain`], the twin of [`nedrt_gpu::Chain`]), the
//! unrolled preprocessor on the host ([`unrolled`]: split-solver steps with
//! learned corrections) and the fault injection ([`FailsAfter`], for either
//! kind of stage).
//!
//! Rule: depends on nedrt-core, nedrt-gpu, nedrt-optics and nedrt-infer
//! only; it knows neither the service nor the commands, so `nedrt run`,
//! `nedrt sim`, `nedrt eval` and the studies build the same stages.

pub mod device_prefilter;
mod faults;
pub mod network;
pub mod preprocess;
pub mod unrolled;

pub use faults::FailsAfter;
pub use network::Network;
pub use preprocess::Chain;

/// Why an engine could not be built.
#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    /// A part the engine needs was not loaded (a method's D-CNN).
    #[error("{0}")]
    Unavailable(String),
    /// An input the engine reads is unusable (a model card); `path` names it.
    #[error("{path}: {reason}")]
    Input { path: String, reason: String },
    #[error(transparent)]
    Optics(#[from] nedrt_optics::OpticsError),
    #[error(transparent)]
    Sim(#[from] nedrt_optics::sim::SimError),
    #[error(transparent)]
    Fft(#[from] nedrt_gpu::fft::FftError),
    #[error(transparent)]
    Gpu(#[from] nedrt_gpu::GpuError),
    #[error(transparent)]
    Inference(#[from] nedrt_infer::InferenceError),
}

impl EngineError {
    pub fn input(path: impl std::fmt::Display, reason: impl std::fmt::Display) -> Self {
        Self::Input {
            path: path.to_string(),
            reason: reason.to_string(),
        }
    }
}
