//! The real-time path (issue 5): frames in, preprocessed frames on the
//! panel. So far the parts that need no device: frame pacing against the
//! panel's refresh ([`pacing`], with a fake clock for tests) and latency
//! accounting ([`latency`]). The stage threads, sources and sinks build on
//! these.

pub mod latency;
pub mod pacing;
