//! nedrt: runtime and simulator for a computational multifocal near-eye
//! display (lens + static DOE + D-CNN preprocessing).
//!
//! The module tree follows the data flow: [`calib`] → [`optics`] → ([`sim`] |
//! [`inference`] → [`pipeline`] → [`present`]).

pub mod app;
pub mod calib;
pub mod charts;
pub mod golden;
pub mod inference;
pub mod optics;
pub mod pipeline;
pub mod present;
pub mod sim;
pub mod util;
