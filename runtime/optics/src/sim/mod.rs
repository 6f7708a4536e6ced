//! The simulator: what the eye perceives through each display system, the
//! targets it is judged against, and the scores (docs/model.md §9–§13,
//! §16–§17).

pub mod convolve;
pub mod economy;
pub mod focus;
pub mod methods;
pub mod metrics;
pub mod optimal;
pub mod simulator;
pub mod wiener;
pub mod zones;

pub use methods::{Method, Optics};
pub use nedrt_core::Image;
pub use optimal::{DisplayProblem, Objective, SolveMode, SolveOptions, SolvedPrefilter};
pub use simulator::{Prepared, Simulator, objective_depths_d, perceive};
pub use zones::{ZoneRequest, Zoned};

/// Upper end of the headline depth range (docs/model.md §17: 0–2.5 D), the
/// depths the optimal display image is solved over.
pub const HEADLINE_MAX_D: f64 = 2.5;

/// A simulation that cannot run, naming the input at fault.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error(transparent)]
    Optics(#[from] crate::OpticsError),
    #[error(transparent)]
    Doe(#[from] crate::doe_file::DoeError),
    #[error(transparent)]
    Bundle(#[from] crate::bundle::BundleError),
    #[error(transparent)]
    Image(#[from] nedrt_core::image_io::ImageError),
    #[error("{0}")]
    Invalid(String),
}
