//! Frame sources, each run on its own thread and feeding the service
//! through a [`Compositor`]: a folder of images ([`dir`]), a synthetic
//! moving test pattern ([`pattern`]) and applications over the socket
//! protocol ([`socket`]).

pub mod dir;
pub mod pattern;
pub mod socket;

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::thread::JoinHandle;

use super::service::Compositor;

/// Errors of the frame sources (start-up problems; bad frames are
/// rejections, not errors).
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    #[error("{path}: {reason}")]
    Input { path: PathBuf, reason: String },
    #[error(transparent)]
    Image(#[from] nedrt_core::image_io::ImageError),
    #[error("socket {path}: {reason}")]
    Socket { path: PathBuf, reason: String },
}

/// Something that submits frames until it ends or is stopped.
pub trait Source: Send + std::fmt::Debug {
    fn describe(&self) -> String;
    /// Submits frames; returns how many it submitted.
    fn run(&mut self, compositor: Compositor, stop: &AtomicBool) -> Result<u64, SourceError>;
}

/// Runs `source` on a thread of its own; its compositor handle is dropped
/// when it ends, which lets the pipeline drain.
pub fn spawn(
    mut source: Box<dyn Source>,
    compositor: Compositor,
    stop: Arc<AtomicBool>,
) -> std::io::Result<JoinHandle<Result<u64, SourceError>>> {
    std::thread::Builder::new()
        .name("source".into())
        .spawn(move || source.run(compositor, &stop))
}

/// Submission pacing: frames at `rate_hz` (0: as fast as they are made).
#[derive(Debug)]
pub(crate) struct Rate {
    pacer: Option<super::pacing::Pacer>,
    clock: Arc<dyn super::pacing::Clock>,
}

impl Rate {
    pub(crate) fn new(rate_hz: f64, clock: Arc<dyn super::pacing::Clock>) -> Self {
        let pacer = (rate_hz > 0.0).then(|| super::pacing::Pacer::new(rate_hz, clock.now_ns()));
        Self { pacer, clock }
    }

    /// Waits for the next slot; returns the capture time to stamp.
    pub(crate) fn wait(&mut self) -> u64 {
        if let Some(p) = &mut self.pacer {
            let tick = p.next(self.clock.now_ns());
            self.clock.sleep_until_ns(tick.vsync_ns);
        }
        self.clock.now_ns()
    }
}
