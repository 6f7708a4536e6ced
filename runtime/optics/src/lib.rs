//! nedrt-optics, layer 1 of nedrt: the physical model (docs/model.md).
//! Dispersion and defocus (via [`nedrt_core::calib`]), the pupil with its
//! DOE, propagation to the retina, the sampling rules of docs/model.md §8,
//! PSFs, MTFs and the PSF cache; the simulator ([`sim`]: perceived images,
//! targets, the Wiener prefilter, scores) and the golden vectors.
//!
//! Rule: depends on nedrt-core only; no GPU, no network, no console.

pub mod golden;
pub mod sim;

pub mod bundle;
pub mod cache;
pub mod doe;
pub mod doe_file;
pub mod mtf;
pub mod perturb;
pub mod pixel;
pub mod propagate;
pub mod psf;
pub mod pupil;
pub mod radial;
pub mod radial_golden;
pub mod sampling;
pub mod spectrum;

pub use doe::{HeightMap, Profile};
pub use psf::{Propagator, Psf, PsfRequest, PsfSet, SamplingReport, compute_psfs, propagator_for};
pub use sampling::PsfSpec;

/// Why a PSF request cannot be met. Never a silent alias: each names the rule.
#[derive(Debug, thiserror::Error)]
pub enum OpticsError {
    #[error("empty PSF request")]
    EmptyRequest,
    #[error("invalid PSF specification {0}")]
    BadSpec(String),
    #[error("sampling rule cannot be met: {0}")]
    RuleViolated(String),
    #[error(
        "channel {channel}: the sampling rules need {samples} pupil samples across the aperture \
         ({step_um:.3} µm step), more than simulation.max_pupil_samples = {limit}"
    )]
    GridTooLarge {
        channel: String,
        samples: usize,
        step_um: f64,
        limit: usize,
    },
    #[error(transparent)]
    Doe(#[from] doe_file::DoeError),
}

#[cfg(test)]
mod golden_tests;
