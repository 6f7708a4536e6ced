//! Optics: dispersion and defocus (via [`crate::calib`]), the pupil with its
//! DOE, propagation to the retina, the sampling rules of optics.md §5, PSFs,
//! MTFs and the PSF cache.

pub mod doe;
pub mod doe_file;
pub mod propagate;
pub mod pupil;
