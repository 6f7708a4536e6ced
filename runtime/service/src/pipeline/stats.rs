//! What the service counts: frames in, rejected (by reason), dropped (by
//! hand-over), presented, and a latency histogram per stage and end to
//! end. Counters are atomics; each histogram has its own lock, taken once
//! per frame by one stage thread (uncontended).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use super::frame::RejectReason;
use super::latency::Histogram;
use nedrt_core::preprocess::HostTraffic;

mod report;
mod timeline;
pub use report::{ClientReport, HostTrafficMean, Report, StageReport, TrafficReport};
pub use timeline::{
    FrameMarks, FrameTiming, MARKED_STAGES, Outcome, RefreshMarks, RefreshTiming, TIMELINE_FRAMES,
    TimelineRow, summarize,
};

/// The pipeline's stages, in order, for latency accounting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Decoding the submitted payload to the network's planar linear input.
    Upload,
    /// The D-CNN (for wgpu: upload to the GPU, dispatches, read-back).
    Preprocess,
    /// The preprocessing's own GPU time (timestamp queries; part of
    /// `Preprocess`).
    PreprocessGpu,
    /// The device path's host time before its submission: the upload's
    /// copy to the device's staging memory and the recording of the
    /// frame's passes (part of `Preprocess`).
    PreprocessRecord,
    /// The device path's whole submission on the device (timestamps): the
    /// uploads' copies, unpacks, layers, stages and encodes (part of
    /// `Preprocess`; less `PreprocessGpu` it is the device's share of the
    /// frame's overhead).
    PreprocessFrameGpu,
    /// Device work held back until a present was submitted, so that the
    /// present does not queue behind it (`pacing::PresentGate`; part of
    /// `Preprocess`).
    YieldToPresent,
    /// Clamp and the panel's transfer curve.
    Encode,
    /// Drawing onto the sink (for a window: until the swapchain takes it).
    Present,
    /// Waiting between stages (queues and the wait for a refresh).
    Queued,
    /// Capture to the refresh the frame is on ([`END_TO_END_FROM`]).
    EndToEnd,
}

impl Stage {
    pub const ALL: [Stage; 10] = [
        Stage::Upload,
        Stage::Preprocess,
        Stage::PreprocessGpu,
        Stage::PreprocessRecord,
        Stage::PreprocessFrameGpu,
        Stage::YieldToPresent,
        Stage::Encode,
        Stage::Present,
        Stage::Queued,
        Stage::EndToEnd,
    ];

    fn index(self) -> usize {
        Stage::ALL.iter().position(|&s| s == self).unwrap_or(0)
    }

    pub fn name(self) -> &'static str {
        match self {
            Stage::Upload => "upload",
            Stage::Preprocess => "preprocess",
            Stage::PreprocessGpu => "preprocess-gpu",
            Stage::PreprocessRecord => "preprocess-record",
            Stage::PreprocessFrameGpu => "preprocess-frame-gpu",
            Stage::YieldToPresent => "yield-to-present",
            Stage::Encode => "encode",
            Stage::Present => "present",
            Stage::Queued => "queued",
            Stage::EndToEnd => "end-to-end",
        }
    }
}

/// Shared counters and histograms of a running service.
#[derive(Debug, Default)]
pub struct Stats {
    pub submitted: AtomicU64,
    pub rejected: [AtomicU64; 7],
    /// Evicted from the ingest → upload, upload → D-CNN and D-CNN → encode queues.
    pub dropped_queued: Arc<AtomicU64>,
    /// Replaced in the present slot before a refresh showed them.
    pub dropped_at_present: AtomicU64,
    pub presented: AtomicU64,
    /// Frames a sink could not take (occluded window, outdated surface).
    pub skipped: AtomicU64,
    pub missed_refreshes: AtomicU64,
    /// Frames the D-CNN backend failed on (each also switches to the fallback).
    pub dcnn_failures: AtomicU64,
    /// Clients that disconnected with a frame half sent.
    pub disconnects_mid_frame: AtomicU64,
    /// Clients dropped for not reading their replies within the deadline.
    pub clients_dropped: AtomicU64,
    /// Accepted frames still inside the pipeline (a queue, a stage, the
    /// present slot) when it stopped: never shown, and never processed
    /// further once the stop was seen.
    pub in_flight_at_stop: AtomicU64,
    /// Accepted frames a stage could not process (the D-CNN refusing a
    /// validated frame, a sink failing on it).
    pub failed: AtomicU64,
    /// Presented frames the sink then lost (a recorder's writes after its
    /// disk filled); these are also in `presented`.
    pub lost_by_sink: AtomicU64,
    /// Quad layers set (a submission, or a newer one of the same layer).
    pub layers_set: AtomicU64,
    /// Quad layers refused (outside the view, non-finite, wrong size, …).
    pub layers_refused: AtomicU64,
    /// Frames blended with at least one quad layer.
    pub frames_with_layers: AtomicU64,
    /// Two views: a view shown from its last frame in a composition made
    /// for the other view's (its projection layer was not waited for).
    pub view_frames_reused: AtomicU64,
    /// Presented frames by refreshes between the one they were shown at
    /// and the one predicted when they were submitted (negative: early).
    vs_prediction: Mutex<std::collections::BTreeMap<i64, u64>>,
    /// The same by submitter (a socket client; 0 in process).
    by_client: Mutex<std::collections::BTreeMap<u64, ClientTally>>,
    /// Host↔device traffic of the D-CNN stage's frames.
    pub dcnn_traffic: TrafficCounter,
    /// Host↔device traffic of the sink's presented frames.
    pub present_traffic: TrafficCounter,
    histograms: [Mutex<Histogram>; Stage::ALL.len()],
    /// Frames shown after the refresh predicted at their submission: by
    /// how much (a whole number of periods).
    late: Mutex<Histogram>,
    /// Each view's engine time, where the panel has two views (a view's
    /// share of `dcnn`; a view whose image did not change is not run).
    view_dcnn: [Mutex<Histogram>; 2],
    /// Resident set size samples (KiB) taken every `RSS_EVERY` presents.
    rss_kib: Mutex<Vec<u64>>,
    /// The newest frames' timelines (shown or replaced at the panel).
    timeline: Mutex<timeline::Timeline>,
    pub backend: Mutex<String>,
    /// Where frames go between the client and the panel.
    pub frame_path: Mutex<String>,
    /// The frame budget's levels and counts, where the run has a ladder
    /// (updated after each frame).
    pub frame_budget: Mutex<Option<crate::pipeline::ladder::BudgetReport>>,
}

/// Host↔device traffic summed over the frames one stage handled.
#[derive(Debug, Default)]
pub struct TrafficCounter {
    totals: Mutex<(HostTraffic, u64)>,
}

impl TrafficCounter {
    /// One frame's traffic.
    pub fn record(&self, traffic: HostTraffic) {
        let mut t = self.totals.lock().unwrap_or_else(|p| p.into_inner());
        t.0.add(traffic);
        t.1 += 1;
    }

    fn report(&self, stage: &str) -> TrafficReport {
        let (total, frames) = *self.totals.lock().unwrap_or_else(|p| p.into_inner());
        TrafficReport {
            stage: stage.to_string(),
            frames,
            total,
        }
    }
}

/// Clients the report names one by one; later ones are counted together
/// as client `u64::MAX`.
pub const MAX_CLIENTS_REPORTED: usize = 1024;

/// One submitter's shown frames against their predictions.
#[derive(Debug, Default, Clone, Copy)]
struct ClientTally {
    shown: u64,
    on_time: u64,
    late: u64,
    early: u64,
    /// Sum of (predicted display time − submission), ns.
    lead_ns: u128,
}

/// A presented frame against its prediction: when it was submitted, the
/// refresh predicted for it then, and the refresh it was shown at.
#[derive(Debug, Clone, Copy)]
pub struct ShownFrame {
    pub owner: u64,
    pub submit_ns: u64,
    pub predicted_ns: u64,
    pub shown_ns: u64,
    pub period_ns: u64,
}

impl Stats {
    /// A frame shown at the refresh `shown_ns`, predicted at `predicted_ns`.
    pub fn record_vs_prediction(&self, f: ShownFrame) {
        let late = (f.shown_ns as f64 - f.predicted_ns as f64) / f.period_ns.max(1) as f64;
        let late = late.round() as i64;
        if f.shown_ns > f.predicted_ns {
            self.late
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .record_ns(f.shown_ns - f.predicted_ns);
        }
        *self
            .vs_prediction
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .entry(late)
            .or_insert(0) += 1;
        let mut clients = self.by_client.lock().unwrap_or_else(|p| p.into_inner());
        // Bounded however many clients come and go: past the first
        // MAX_CLIENTS_REPORTED, the rest are one entry.
        let owner = if clients.len() >= MAX_CLIENTS_REPORTED && !clients.contains_key(&f.owner) {
            u64::MAX
        } else {
            f.owner
        };
        let t = clients.entry(owner).or_default();
        t.shown += 1;
        match late {
            0 => t.on_time += 1,
            k if k > 0 => t.late += 1,
            _ => t.early += 1,
        }
        t.lead_ns += u128::from(f.predicted_ns.saturating_sub(f.submit_ns));
    }
}

/// What the end-to-end latency is measured between (the report says it).
pub const END_TO_END_FROM: &str = "from the frame's capture time (a socket client's \
    stamp; the pattern and folder sources stamp a frame once it is made) to the refresh \
    it is on (for a sink paced by the display, to the end of its present)";

/// Presents between resident-memory samples.
pub const RSS_EVERY: u64 = 100;

impl Stats {
    pub fn reject(&self, reason: RejectReason) {
        self.rejected[reason.index()].fetch_add(1, Ordering::Relaxed);
    }

    pub fn rejected_total(&self) -> u64 {
        self.rejected
            .iter()
            .map(|a| a.load(Ordering::Relaxed))
            .sum()
    }

    /// View `view`'s engine took `ns`.
    pub fn record_view(&self, view: usize, ns: u64) {
        if let Some(h) = self.view_dcnn.get(view) {
            h.lock().unwrap_or_else(|p| p.into_inner()).record_ns(ns);
        }
    }

    pub fn record(&self, stage: Stage, ns: u64) {
        self.histograms[stage.index()]
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .record_ns(ns);
    }

    pub fn histogram(&self, stage: Stage) -> Histogram {
        self.histograms[stage.index()]
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Timelines are in ms from `origin_ns` (the service's start).
    pub fn set_timeline_origin(&self, origin_ns: u64) {
        self.timeline
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .set_origin(origin_ns);
    }

    /// A frame left the pipeline at the panel: `outcome` at `at_ns` (taken
    /// by the present loop, or replaced by frame `by`), shown on the
    /// refresh `shown_ns`.
    pub fn record_timeline(
        &self,
        marks: &FrameMarks,
        outcome: Outcome,
        at_ns: u64,
        shown_ns: Option<u64>,
        by: Option<u64>,
    ) {
        self.timeline
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .record(marks, outcome, at_ns, shown_ns, by);
    }

    /// The present loop's work for a refresh (stats::timeline).
    pub fn record_refresh(&self, marks: &RefreshMarks) {
        self.timeline
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .record_refresh(marks);
    }

    pub fn sample_rss(&self) {
        if let Some(kib) = resident_kib() {
            self.rss_kib
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .push(kib);
        }
    }

    /// A snapshot for reports.
    pub fn snapshot(&self) -> Report {
        let load = |a: &AtomicU64| a.load(Ordering::Relaxed);
        // One lock for both (a guard in the literal below would live to
        // its end).
        let (frames, refreshes) = {
            let t = self.timeline.lock().unwrap_or_else(|p| p.into_inner());
            (t.frames(), t.refreshes())
        };
        Report {
            frame_budget: self
                .frame_budget
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clone(),
            backend: self
                .backend
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clone(),
            frame_path: self
                .frame_path
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clone(),
            submitted: load(&self.submitted),
            rejected: RejectReason::ALL
                .iter()
                .map(|r| (r.name().to_string(), load(&self.rejected[r.index()])))
                .collect(),
            dropped_queued: load(&self.dropped_queued),
            dropped_at_present: load(&self.dropped_at_present),
            presented: load(&self.presented),
            skipped: load(&self.skipped),
            missed_refreshes: load(&self.missed_refreshes),
            dcnn_failures: load(&self.dcnn_failures),
            disconnects_mid_frame: load(&self.disconnects_mid_frame),
            clients_dropped: load(&self.clients_dropped),
            in_flight_at_stop: load(&self.in_flight_at_stop),
            failed: load(&self.failed),
            lost_by_sink: load(&self.lost_by_sink),
            layers_set: load(&self.layers_set),
            layers_refused: load(&self.layers_refused),
            frames_with_layers: load(&self.frames_with_layers),
            view_frames_reused: load(&self.view_frames_reused),
            shown_vs_predicted: self
                .vs_prediction
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .iter()
                .map(|(&k, &n)| (k, n))
                .collect(),
            clients: self
                .by_client
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .iter()
                .map(|(&client, t)| ClientReport {
                    client,
                    shown: t.shown,
                    on_time: t.on_time,
                    late: t.late,
                    early: t.early,
                    mean_lead_ms: if t.shown == 0 {
                        0.0
                    } else {
                        t.lead_ns as f64 / t.shown as f64 / 1e6
                    },
                })
                .collect(),
            stages: Stage::ALL
                .iter()
                .map(|&s| StageReport::of(s.name().to_string(), &self.histogram(s)))
                .collect(),
            late: StageReport::of(
                "late".into(),
                &self.late.lock().unwrap_or_else(|p| p.into_inner()),
            ),
            end_to_end_from: END_TO_END_FROM.into(),
            view_stages: self
                .view_dcnn
                .iter()
                .enumerate()
                .filter_map(|(v, h)| {
                    let h = h.lock().unwrap_or_else(|p| p.into_inner());
                    (h.count() > 0).then(|| StageReport::of(format!("preprocess view {v}"), &h))
                })
                .collect(),
            traffic: vec![
                self.dcnn_traffic.report("preprocess"),
                self.present_traffic.report("present"),
            ],
            rss_kib: self
                .rss_kib
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clone(),
            frames,
            refreshes,
        }
    }
}

/// This process's resident set size in KiB (Linux `/proc/self/statm`).
pub fn resident_kib() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4)
}
