//! The simulator: what the eye perceives through each display system, the
//! targets it is judged against, and the scores (optics.md §6–§7,
//! evaluation.md).

pub mod convolve;
pub mod image;
pub mod image_io;
pub mod metrics;
