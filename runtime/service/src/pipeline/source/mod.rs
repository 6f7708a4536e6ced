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

/// When a pattern or folder source submits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SourceRate {
    /// Each frame made for a refresh of the panel, just in time for it
    /// ([`DisplaySchedule::plan_submission`](super::pacing::DisplaySchedule::plan_submission)),
    /// on the present loop's clock.
    Display,
    /// At a rate of its own, Hz, on its own timer (0: as fast as frames
    /// are made).
    Hz(f64),
}

/// Submission pacing of a source that makes its frames.
#[derive(Debug)]
pub(crate) struct Rate {
    rate: SourceRate,
    pacer: Option<super::pacing::Pacer>,
    clock: Arc<dyn super::pacing::Clock>,
    /// How long making a frame takes, to start it in time.
    make: super::pacing::Estimate,
    started_ns: u64,
    /// The refresh the last frame was made for, and when it was made.
    last_refresh_ns: u64,
    last_made_ns: u64,
}

impl Rate {
    pub(crate) fn new(rate: SourceRate, clock: Arc<dyn super::pacing::Clock>) -> Self {
        let pacer = match rate {
            SourceRate::Hz(hz) if hz > 0.0 => Some(super::pacing::Pacer::new(hz, clock.now_ns())),
            _ => None,
        };
        Self {
            rate,
            pacer,
            clock,
            make: Default::default(),
            started_ns: 0,
            last_refresh_ns: 0,
            last_made_ns: 0,
        }
    }

    pub(crate) fn rate(&self) -> SourceRate {
        self.rate
    }

    /// Frames a second, for a source whose content moves with time.
    pub(crate) fn frames_per_second(&self, compositor: &Compositor) -> f64 {
        match self.rate {
            SourceRate::Hz(hz) => hz,
            SourceRate::Display => 1e9 / compositor.refresh_period_ns().max(1) as f64,
        }
    }

    /// Waits until the next frame is to be made; returns the refresh it is
    /// made for, when the source follows the display.
    pub(crate) fn wait(&mut self, compositor: &Compositor) -> Option<u64> {
        let mut made_for = None;
        if let Some(p) = &mut self.pacer {
            let tick = p.next(self.clock.now_ns());
            self.clock.sleep_until_ns(tick.vsync_ns);
        } else if self.rate == SourceRate::Display {
            let make = self.make.bound_ns();
            let after = compositor.replan_after(self.last_refresh_ns, self.last_made_ns, make);
            let plan = compositor.plan_submission(after, make);
            self.last_refresh_ns = plan.refresh_ns;
            self.clock.sleep_until_ns(plan.start_ns);
            made_for = Some(plan.refresh_ns);
        }
        self.started_ns = self.clock.now_ns();
        made_for
    }

    /// The frame is made: the capture time to stamp (now), and how long
    /// making it took is learnt.
    pub(crate) fn made(&mut self) -> u64 {
        let now = self.clock.now_ns();
        self.make.observe(now.saturating_sub(self.started_ns));
        self.last_made_ns = now;
        now
    }
}
