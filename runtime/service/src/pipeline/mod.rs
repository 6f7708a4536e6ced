//! The real-time path: frames in, preprocessed frames on the panel.
//!
//! Sources ([`source`]: a folder, a test pattern, applications over the
//! socket [`protocol`]) submit [`frame`]s through a
//! [`service::Compositor`]; the [`service`] runs upload → D-CNN → encode on
//! threads joined by newest-wins [`channel`]s and presents on the panel's
//! refresh ([`pacing`]) to a `present::Sink`, counting everything
//! ([`stats`], [`latency`]).

pub mod channel;
pub mod device_frames;
pub mod frame;
pub mod ladder;
pub mod latency;
pub mod pacing;
/// The wire format, from nedrt-protocol (the path the service's users know).
pub use nedrt_protocol as protocol;
pub mod service;
pub mod source;
pub mod stats;
#[cfg(test)]
pub(crate) mod test_stage;
