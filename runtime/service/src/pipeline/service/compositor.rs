//! The in-process API that submits frames to a running service
//! ([`Compositor`]) and the timing every frame carries through the stages.
//! Apart from the service's threads: this is the caller's side.

use std::sync::Arc;

use crate::compose::{LayerError, LayerSet, QuadLayer, ViewGeometry, ViewRegion};
use crate::pipeline::channel::NewestSender;
use crate::pipeline::frame::{FrameError, SubmittedFrame, validate};
use crate::pipeline::pacing::{Clock, DisplaySchedule, SubmitPlan};
use crate::pipeline::stats::{FrameMarks, Stats};

/// A frame in flight with its timing.
#[derive(Debug)]
pub(super) struct Timed<T> {
    pub(super) item: T,
    pub(super) id: u64,
    /// Capture time if the client gave a usable one, else submission.
    pub(super) start_ns: u64,
    /// Time spent in the stages' own work so far.
    pub(super) work_ns: u64,
    /// Of that, time a stage held the frame back for other work (the
    /// device's yield to a present, pacing::gate): a wait the pacing
    /// chose, which the pipeline's estimate leaves out.
    pub(super) waited_ns: u64,
    /// Time it queued behind a frame a stage held back, as far as that
    /// hold made the wait longer: the same wait passed on, which the
    /// estimate leaves out too.
    pub(super) behind_hold_ns: u64,
    /// The device's own time for its preprocessing, the host's before
    /// that work's submission and the whole submission's on the device
    /// (the device path; StageNotes).
    pub(super) gpu_ns: Option<u64>,
    pub(super) record_ns: Option<u64>,
    pub(super) frame_gpu_ns: Option<u64>,
    /// The frame budget's level it ran (its index in the report's
    /// levels; none without a ladder).
    pub(super) level: Option<u8>,
    /// Who submitted it (a socket client's number; 0 in process).
    pub(super) owner: u64,
    /// When it was submitted, and the refresh predicted for it then.
    pub(super) submit_ns: u64,
    pub(super) predicted_ns: u64,
    /// The client gave the refresh it rendered the frame for (an OpenXR
    /// frame's display time): it is not shown before it.
    pub(super) hold: bool,
    /// When the last stage so far finished it (after the encode: ready
    /// for the panel).
    pub(super) ready_ns: u64,
    /// When each stage took it and finished it (stats::MARKED_STAGES).
    pub(super) stages_ns: [[u64; 2]; 3],
}

impl<T> Timed<T> {
    /// Its times, for its timeline (stats::timeline).
    pub(super) fn marks(&self) -> FrameMarks {
        FrameMarks {
            id: self.id,
            owner: self.owner,
            submit_ns: self.submit_ns,
            predicted_ns: self.predicted_ns,
            stages_ns: self.stages_ns,
            held_ns: self.waited_ns,
            ready_ns: self.ready_ns,
            gpu_ns: self.gpu_ns,
            record_ns: self.record_ns,
            frame_gpu_ns: self.frame_gpu_ns,
            level: self.level,
        }
    }
}

/// A submission: a frame for one view, or (`None`) a panel-sized frame.
pub(super) type Submission = (Option<u8>, SubmittedFrame);

/// A view of the panel as submitters see it: where it lies, how quads are
/// placed on it, and its quads.
#[derive(Debug)]
pub(super) struct ViewSlot {
    pub(super) region: ViewRegion,
    pub(super) geometry: ViewGeometry,
    pub(super) layers: Arc<LayerSet>,
}

/// The in-process API: submit frames to a running service. Cheap to clone;
/// the pipeline runs until every clone is dropped (or the service stops).
#[derive(Debug, Clone)]
pub struct Compositor {
    pub(super) tx: NewestSender<Timed<Submission>>,
    pub(super) stats: Arc<Stats>,
    pub(super) clock: Arc<dyn Clock>,
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) schedule: Arc<DisplaySchedule>,
    /// One view (the whole panel), or a headset's two eyes.
    pub(super) views: Arc<[ViewSlot]>,
    /// Whose layers this handle sets: each client of the socket has its
    /// own; in-process callers share 0 unless they ask for one.
    pub(super) owner: u64,
}

impl Compositor {
    /// Checks `frame` and queues it; a bad frame is refused (and counted)
    /// here, on the caller's thread, so the caller learns why at once.
    /// Never blocks on the pipeline: a full queue drops its oldest frame.
    pub fn submit(&self, frame: SubmittedFrame) -> Result<(), FrameError> {
        self.submit_to(None, frame, None, false)
    }

    /// As [`Compositor::submit`], for a frame made for the refresh at
    /// `refresh_ns` ([`Compositor::submit_view_for`]).
    pub fn submit_for(
        &self,
        frame: SubmittedFrame,
        refresh_ns: Option<u64>,
    ) -> Result<(), FrameError> {
        self.submit_to(None, frame, refresh_ns, false)
    }

    /// As [`Compositor::submit`], a frame of view `view`'s size for that
    /// view alone (on a one-view panel, view 0 is the panel).
    pub fn submit_view(&self, view: u8, frame: SubmittedFrame) -> Result<(), FrameError> {
        self.submit_view_for(view, frame, None)
    }

    /// As [`Compositor::submit_view`], for a frame made for the refresh at
    /// `refresh_ns` (from [`Compositor::plan_submission`]): that refresh is
    /// its prediction (`None`: predicted at submission). It is shown when
    /// ready, early if so: held, frames planned seconds ahead by an
    /// estimate a slow first frame inflated waited for those refreshes
    /// (the H200, 2026-11-28: 30 of 200 shown; docs/benchmarks.md).
    pub fn submit_view_for(
        &self,
        view: u8,
        frame: SubmittedFrame,
        refresh_ns: Option<u64>,
    ) -> Result<(), FrameError> {
        self.submit_view_timed(view, frame, refresh_ns, false)
    }

    /// As [`Compositor::submit_view_for`], for a client's frame with the
    /// display time it was rendered for (`None`: none given): that time is
    /// its prediction, and the frame is not shown before it (an OpenXR
    /// frame belongs to its display time: shown early, it would show the
    /// scene of a later moment). `view` `None`: a panel-sized frame.
    pub fn submit_at(
        &self,
        view: Option<u8>,
        frame: SubmittedFrame,
        display_ns: Option<u64>,
    ) -> Result<(), FrameError> {
        match view {
            Some(v) => self.submit_view_timed(v, frame, display_ns, display_ns.is_some()),
            None => self.submit_to(None, frame, display_ns, display_ns.is_some()),
        }
    }

    fn submit_view_timed(
        &self,
        view: u8,
        frame: SubmittedFrame,
        refresh_ns: Option<u64>,
        hold: bool,
    ) -> Result<(), FrameError> {
        let whole = self.views.len() == 1
            && (self.views[0].region.width, self.views[0].region.height)
                == (self.width, self.height);
        if whole && view == 0 {
            return self.submit_to(None, frame, refresh_ns, hold);
        }
        self.submit_to(Some(view), frame, refresh_ns, hold)
    }

    fn submit_to(
        &self,
        view: Option<u8>,
        frame: SubmittedFrame,
        refresh_ns: Option<u64>,
        hold: bool,
    ) -> Result<(), FrameError> {
        use std::sync::atomic::Ordering::Relaxed;
        self.stats.submitted.fetch_add(1, Relaxed);
        let size = match view {
            None => Some((self.width, self.height)),
            Some(v) => self
                .views
                .get(usize::from(v))
                .map(|s| (s.region.width, s.region.height)),
        };
        let checked = match size {
            Some((w, h)) => validate(&frame, w, h),
            None => Err(FrameError {
                id: frame.id,
                reason: crate::pipeline::frame::RejectReason::UnknownView,
                detail: format!(
                    "view {} (this service runs {} views)",
                    view.unwrap_or(0),
                    self.views.len()
                ),
            }),
        };
        if let Err(e) = checked {
            self.stats.reject(e.reason);
            tracing::warn!("{e}");
            return Err(e);
        }
        let now = self.clock.now_ns();
        let given = refresh_ns.filter(|r| r.abs_diff(now) < 1_000_000_000);
        let start_ns = if frame.capture_ns > 0 && frame.capture_ns <= now {
            frame.capture_ns
        } else {
            now
        };
        self.tx.send(Timed {
            id: frame.id,
            item: (view, frame),
            start_ns,
            work_ns: 0,
            waited_ns: 0,
            behind_hold_ns: 0,
            gpu_ns: None,
            record_ns: None,
            frame_gpu_ns: None,
            level: None,
            owner: self.owner,
            submit_ns: now,
            // A client's display time more than a second from now is no
            // prediction (a hostile or broken clock): the service's own.
            predicted_ns: given.unwrap_or_else(|| self.schedule.predicted_display_ns(now)),
            hold: hold && given.is_some(),
            ready_ns: now,
            stages_ns: [[0; 2]; 3],
        });
        Ok(())
    }

    /// When a frame submitted now is predicted to be on the panel,
    /// CLOCK_MONOTONIC ns (the service's clock): the first refresh after
    /// the pipeline's recent time from submission to ready.
    pub fn predicted_display_ns(&self) -> u64 {
        self.schedule.predicted_display_ns(self.clock.now_ns())
    }

    /// When to start making the next frame, and for which refresh: the
    /// first after `after_ns` that a frame taking `make_ns` to make can
    /// reach ([`DisplaySchedule::plan_submission`]).
    pub fn plan_submission(&self, after_ns: u64, make_ns: u64) -> SubmitPlan {
        self.schedule
            .plan_submission(self.clock.now_ns(), after_ns, make_ns)
    }

    /// The refresh a frame made for `planned_ns` and submitted at
    /// `submitted_ns` will be on, as the pipeline's estimate now sees it
    /// ([`DisplaySchedule::replan_after`]).
    pub fn replan_after(&self, planned_ns: u64, submitted_ns: u64, make_ns: u64) -> u64 {
        self.schedule
            .replan_after(planned_ns, submitted_ns, make_ns)
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

    /// Checks and places `quad` on view 0 and makes it this owner's layer
    /// `quad.layer` from the next frame on (replacing an older submission
    /// of it). Refused and counted when it is bad.
    pub fn submit_layer(&self, quad: QuadLayer) -> Result<(), LayerError> {
        self.submit_layer_on(0, quad)
    }

    /// As [`Compositor::submit_layer`], on view `view`.
    pub fn submit_layer_on(&self, view: u8, quad: QuadLayer) -> Result<(), LayerError> {
        use std::sync::atomic::Ordering::Relaxed;
        let placed = match self.views.get(usize::from(view)) {
            Some(slot) => quad.place(&slot.geometry).and_then(|q| {
                let budget = 2 * slot.region.width * slot.region.height;
                slot.layers.set(self.owner, q, budget)
            }),
            None => Err(LayerError::UnknownView {
                layer: quad.layer,
                view,
                views: self.views.len(),
            }),
        };
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

    /// Removes this owner's layer `layer` of view 0; whether it was there.
    pub fn remove_layer(&self, layer: u32) -> bool {
        self.remove_layer_on(0, layer)
    }

    /// Removes this owner's layer `layer` of view `view`.
    pub fn remove_layer_on(&self, view: u8, layer: u32) -> bool {
        self.views
            .get(usize::from(view))
            .is_some_and(|v| v.layers.remove(self.owner, layer))
    }

    /// Removes every layer of this owner on every view (a client that
    /// left); how many.
    pub fn remove_owner_layers(&self) -> usize {
        self.views
            .iter()
            .map(|v| v.layers.remove_owner(self.owner))
            .sum()
    }

    /// What quads are placed on: view 0.
    pub fn view(&self) -> ViewGeometry {
        self.views[0].geometry
    }

    /// The views the service runs: 1, or 2 (a headset's eyes).
    pub fn view_count(&self) -> usize {
        self.views.len()
    }

    /// Where view `view` lies on the panel: x, y, width, height.
    pub fn view_region(&self, view: u8) -> Option<[usize; 4]> {
        self.views
            .get(usize::from(view))
            .map(|v| [v.region.x, v.region.y, v.region.width, v.region.height])
    }

    /// View `view`'s size, if there is one.
    pub fn view_size(&self, view: u8) -> Option<(usize, usize)> {
        self.views
            .get(usize::from(view))
            .map(|v| (v.region.width, v.region.height))
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
