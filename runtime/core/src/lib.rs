//! nedrt-core, layer 0 of nedrt: what every other layer shares and nothing
//! it depends on. The calibration ([`calib`]), the one image type
//! ([`Image`]: planar linear intensity, the simulator's input and the
//! runtime's frame) with its validated file I/O ([`image_io`]) and the one
//! padding rule for networks that need a multiple ([`Image::pad_reflect`]),
//! the "input frame → display frame" interface ([`preprocess`]), the progress
//! reporter the binary supplies ([`progress`]), and small file utilities.
//!
//! Rule: depends on no other nedrt crate, reads no environment variable and
//! prints nothing; the binary passes settings in as values.

pub mod calib;
pub mod image;
pub mod image_io;
pub mod named;
pub mod preprocess;
pub mod progress;
pub mod util;

pub use image::Image;
pub use named::Named;
pub use preprocess::{Preprocess, PreprocessError};
pub use progress::Progress;
