//! [`Control`]: how the caller runs and ends the present loop (stop,
//! report now, keep open, progress). Apart as the one type every caller
//! of the service builds, whatever its pipeline.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use nedrt_core::progress::{Progress, Silent};

/// How the present loop runs and ends.
#[derive(Debug, Clone)]
pub struct Control {
    /// Set by a signal (or a test) to stop.
    pub stop: Arc<AtomicBool>,
    /// Set by SIGUSR1: print the latency table now.
    pub report: Arc<AtomicBool>,
    /// Keep showing the last frame after the sources end, until stopped.
    pub keep_open: bool,
    /// Where the live status line and the requested tables go.
    pub progress: Arc<dyn Progress>,
    /// Set once, when the pipeline is prepared and takes its first frame:
    /// a caller that bounds the run's time (a benchmark) counts from here,
    /// not from the preparation.
    pub serving: Arc<std::sync::OnceLock<std::time::Instant>>,
}

impl Default for Control {
    fn default() -> Self {
        Self {
            stop: Arc::default(),
            report: Arc::default(),
            keep_open: false,
            progress: Arc::new(Silent),
            serving: Arc::default(),
        }
    }
}
