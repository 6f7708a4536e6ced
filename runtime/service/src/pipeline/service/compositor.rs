//! The in-process API that submits frames to a running service
//! ([`Compositor`]) and the timing every frame carries through the stages.
//! Apart from the service's threads: this is the caller's side.

use std::sync::Arc;

use crate::pipeline::channel::NewestSender;
use crate::pipeline::frame::{FrameError, SubmittedFrame, validate};
use crate::pipeline::pacing::Clock;
use crate::pipeline::stats::Stats;

/// A frame in flight with its timing.
#[derive(Debug)]
pub(super) struct Timed<T> {
    pub(super) item: T,
    pub(super) id: u64,
    /// Capture time if the client gave a usable one, else submission.
    pub(super) start_ns: u64,
    /// Time spent in the stages' own work so far.
    pub(super) work_ns: u64,
}

/// The in-process API: submit frames to a running service. Cheap to clone;
/// the pipeline runs until every clone is dropped (or the service stops).
#[derive(Debug, Clone)]
pub struct Compositor {
    pub(super) tx: NewestSender<Timed<SubmittedFrame>>,
    pub(super) stats: Arc<Stats>,
    pub(super) clock: Arc<dyn Clock>,
    pub(super) width: usize,
    pub(super) height: usize,
}

impl Compositor {
    /// Checks `frame` and queues it; a bad frame is refused (and counted)
    /// here, on the caller's thread, so the caller learns why at once.
    /// Never blocks on the pipeline: a full queue drops its oldest frame.
    pub fn submit(&self, frame: SubmittedFrame) -> Result<(), FrameError> {
        use std::sync::atomic::Ordering::Relaxed;
        self.stats.submitted.fetch_add(1, Relaxed);
        if let Err(e) = validate(&frame, self.width, self.height) {
            self.stats.reject(e.reason);
            tracing::warn!("{e}");
            return Err(e);
        }
        let now = self.clock.now_ns();
        let start_ns = if frame.capture_ns > 0 && frame.capture_ns <= now {
            frame.capture_ns
        } else {
            now
        };
        self.tx.send(Timed {
            id: frame.id,
            item: frame,
            start_ns,
            work_ns: 0,
        });
        Ok(())
    }

    /// The panel's resolution, which every frame must have.
    pub fn panel_size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Counts a frame refused before it could be submitted (a header the
    /// socket source could not turn into a frame).
    pub fn reject_before_submit(
        &self,
        reason: crate::pipeline::frame::RejectReason,
        id: u64,
        detail: &str,
    ) {
        self.stats
            .submitted
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.stats.reject(reason);
        tracing::warn!("frame {id} rejected ({}): {detail}", reason.name());
    }

    /// Counts a client dropped for not reading its replies.
    pub fn count_client_dropped(&self) {
        self.stats
            .clients_dropped
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }

    /// Counts a client that vanished with a frame half sent.
    pub fn count_disconnect_mid_frame(&self) {
        self.stats
            .disconnects_mid_frame
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }
}
