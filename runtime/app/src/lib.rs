//! nedrt-app, layer 4 of nedrt: what the `nedrt` commands other than `nedrt
//! run` do, as library functions with typed options and printable reports
//! (the binary only parses arguments, reads the environment into
//! [`CommonOptions`] and calls these): the simulation, the viewer, the
//! designs' prefilter batches, tuning, the photographs and the charts. What
//! every command shares ([`CommonOptions`], [`AppError`], the named designs)
//! is nedrt-command's, re-exported here; `nedrt run` is nedrt-run; the
//! studies built on these are the crate above, nedrt-studies.
//!
//! Rule: no clap, no indicatif, no environment (settings arrive as values,
//! progress through [`nedrt_core::Progress`]).

pub mod calib_capture;
pub mod calib_fit;
pub mod calib_loop;
pub mod calib_patterns;
pub mod calib_psfs;
pub mod calib_register;
pub mod calib_show;
pub mod calib_synth;
pub mod calib_truth;
pub mod charts;
pub mod frames;
pub mod images;
pub mod prefilter_batch;
pub mod sim;
pub mod tolerance;
pub mod tune;
pub mod viewer;

pub use nedrt_command::design;
pub use nedrt_command::{
    AppError, CommonOptions, DcnnOptions, MAX_ACCOMMODATION_D, MeasuredPsfs, Phase,
    check_accommodation, check_accommodation_as, check_output_folder, create_dir, gpu_for,
    write_text,
};

/// Deadlines for the unit tests (shared with the integration tests).
#[cfg(test)]
#[path = "../../../tests/common/deadline.rs"]
mod deadline;
