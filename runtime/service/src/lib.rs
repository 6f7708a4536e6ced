//! nedrt-service, layer 2 of nedrt: the real-time path. Frames come in
//! ([`pipeline`]: sources, the socket protocol (nedrt-protocol's wire
//! format, re-exported as `pipeline::protocol`), validation, the threaded
//! service, pacing and accounting), are preprocessed by any
//! [`nedrt_core::Preprocess`], and go out to the panel ([`present`]: the
//! transfer curve and the sinks). Applications' quad layers are blended
//! over each view's projection layer first ([`compose`]).
//!
//! Rule: depends on nedrt-core, nedrt-gpu and nedrt-protocol only: it runs whatever
//! preprocessing it is handed and knows neither optics nor networks; no
//! console output (the live status line goes through a
//! [`nedrt_core::Progress`] the binary supplies).

pub mod compose;
pub mod pipeline;
pub mod present;

/// Deadlines for the unit tests (shared with the integration tests).
#[cfg(test)]
#[path = "../../../tests/common/deadline.rs"]
mod deadline;
