//! The in-process API that submits frames to a running service
//! ([`Compositor`]) and the timing every frame carries through the stages.
//! Apart from the service's threads: this is the caller's side.

use std::sync::Arc;

use crate::compose::{LayerError, LayerSet, QuadLayer, ViewGeometry};
use crate::pipeline::channel::NewestSender;
use crate::pipeline::frame::{FrameError, SubmittedFrame, validate};
use crate::pipeline::pacing::{Clock, DisplaySchedule};
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
    /// Who submitted it (a socket client's number; 0 in process).
    pub(super) owner: u64,
    /// When it was submitted, and the refresh predicted for it then.
    pub(super) submit_ns: u64,
    pub(super) predicted_ns: u64,
    /// When the last stage so far finished it (after the encode: ready
    /// for the panel).
    pub(super) ready_ns: u64,
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
    pub(super) layers: Arc<LayerSet>,
    pub(super) schedule: Arc<DisplaySchedule>,
    pub(super) view: ViewGeometry,
    /// Whose layers this handle sets: each client of the socket has its
    /// own; in-process callers share 0 unless they ask for one.
    pub(super) owner: u64,
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
            owner: self.owner,
            submit_ns: now,
            predicted_ns: self.schedule.predicted_display_ns(now),
            ready_ns: now,
        });
        Ok(())
    }

    /// When a frame submitted now is predicted to be on the panel,
    /// CLOCK_MONOTONIC ns (the service's clock): the first refresh after
    /// the pipeline's recent time from submission to ready.
    pub fn predicted_display_ns(&self) -> u64 {
        self.schedule.predicted_display_ns(self.clock.now_ns())
    }

    /// The panel's refresh period, ns.
    pub fn refresh_period_ns(&self) -> u64 {
        self.schedule.period_ns()
    }

    /// The same pipeline, setting layers as `owner` (a client's id).
    pub fn for_owner(&self, owner: u64) -> Compositor {
        Compositor {
            owner,
            ..self.clone()
        }
    }

    /// Checks and places `quad` on the view and makes it this owner's
    /// layer `quad.layer` from the next frame on (replacing an older
    /// submission of it). Refused and counted when it is bad.
    pub fn submit_layer(&self, quad: QuadLayer) -> Result<(), LayerError> {
        use std::sync::atomic::Ordering::Relaxed;
        let placed = quad
            .place(&self.view)
            .and_then(|q| self.layers.set(self.owner, q, self.layer_texel_budget()));
        match placed {
            Ok(()) => {
                self.stats.layers_set.fetch_add(1, Relaxed);
                Ok(())
            }
            Err(e) => {
                self.stats.layers_refused.fetch_add(1, Relaxed);
                tracing::warn!("{e}");
                Err(e)
            }
        }
    }

    /// Counts a layer refused before it could be submitted (a header the
    /// socket source could not turn into a quad).
    pub fn count_layer_refused(&self) {
        self.stats
            .layers_refused
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }

    /// The texels a view's quads may hold in all: twice the view's pixels
    /// (the host keeps them as f32, the device binds them in one buffer).
    pub fn layer_texel_budget(&self) -> usize {
        2 * self.view.width * self.view.height
    }

    /// Removes this owner's layer `layer`; whether it was there.
    pub fn remove_layer(&self, layer: u32) -> bool {
        self.layers.remove(self.owner, layer)
    }

    /// Removes every layer of this owner (a client that left); how many.
    pub fn remove_owner_layers(&self) -> usize {
        self.layers.remove_owner(self.owner)
    }

    /// What quads are placed on.
    pub fn view(&self) -> ViewGeometry {
        self.view
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
