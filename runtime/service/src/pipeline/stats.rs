//! What the service counts: frames in, rejected (by reason), dropped (by
//! hand-over), presented, and a latency histogram per stage and end to
//! end. Counters are atomics; each histogram has its own lock, taken once
//! per frame by one stage thread (uncontended).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use serde::Serialize;

use super::frame::RejectReason;
use super::latency::Histogram;
use nedrt_core::preprocess::HostTraffic;

/// The pipeline's stages, in order, for latency accounting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Decoding the submitted payload to the network's planar linear input.
    Upload,
    /// The D-CNN (for wgpu: upload to the GPU, dispatches, read-back).
    Dcnn,
    /// The D-CNN's own GPU time (timestamp queries; part of `Dcnn`).
    DcnnGpu,
    /// Clamp and the panel's transfer curve.
    Encode,
    /// Drawing onto the sink (for a window: until the swapchain takes it).
    Present,
    /// Waiting between stages (queues and the wait for a refresh).
    Queued,
    /// Capture (or submission) to present.
    EndToEnd,
}

impl Stage {
    pub const ALL: [Stage; 7] = [
        Stage::Upload,
        Stage::Dcnn,
        Stage::DcnnGpu,
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
            Stage::Dcnn => "dcnn",
            Stage::DcnnGpu => "dcnn-gpu",
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
    /// Presented frames by refreshes between the one they were shown at
    /// and the one predicted when they were submitted (negative: early).
    vs_prediction: Mutex<std::collections::BTreeMap<i64, u64>>,
    /// The same by submitter (a socket client; 0 in process).
    by_client: Mutex<std::collections::BTreeMap<u64, ClientTally>>,
    /// Host↔device traffic of the D-CNN stage's frames.
    pub dcnn_traffic: TrafficCounter,
    /// Host↔device traffic of the sink's presented frames.
    pub present_traffic: TrafficCounter,
    histograms: [Mutex<Histogram>; 7],
    /// Resident set size samples (KiB) taken every `RSS_EVERY` presents.
    rss_kib: Mutex<Vec<u64>>,
    pub backend: Mutex<String>,
    /// Where frames go between the client and the panel.
    pub frame_path: Mutex<String>,
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
        *self
            .vs_prediction
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .entry(late)
            .or_insert(0) += 1;
        let mut clients = self.by_client.lock().unwrap_or_else(|p| p.into_inner());
        let t = clients.entry(f.owner).or_default();
        t.shown += 1;
        match late {
            0 => t.on_time += 1,
            k if k > 0 => t.late += 1,
            _ => t.early += 1,
        }
        t.lead_ns += u128::from(f.predicted_ns.saturating_sub(f.submit_ns));
    }
}

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
        Report {
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
                .map(|&s| {
                    let h = self.histogram(s);
                    StageReport {
                        stage: s.name().to_string(),
                        count: h.count(),
                        mean_ms: h.mean_ns() / 1e6,
                        p50_ms: h.quantile_ns(0.5) as f64 / 1e6,
                        p99_ms: h.quantile_ns(0.99) as f64 / 1e6,
                        max_ms: h.max_ns() as f64 / 1e6,
                    }
                })
                .collect(),
            traffic: vec![
                self.dcnn_traffic.report("dcnn"),
                self.present_traffic.report("present"),
            ],
            rss_kib: self
                .rss_kib
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .clone(),
        }
    }
}

/// This process's resident set size in KiB (Linux `/proc/self/statm`).
pub fn resident_kib() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4)
}

/// Mean host↔device traffic of one frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct HostTrafficMean {
    pub to_device_bytes: f64,
    pub uploads: f64,
    pub to_host_bytes: f64,
    pub read_backs: f64,
}

impl HostTrafficMean {
    /// `total` over `frames` (nothing when there were none).
    pub fn of(total: HostTraffic, frames: u64) -> Self {
        if frames == 0 {
            return Self::default();
        }
        let n = frames as f64;
        Self {
            to_device_bytes: total.to_device_bytes as f64 / n,
            uploads: total.uploads as f64 / n,
            to_host_bytes: total.to_host_bytes as f64 / n,
            read_backs: total.read_backs as f64 / n,
        }
    }
}

/// Latency of one stage, milliseconds.
#[derive(Debug, Clone, Serialize)]
pub struct StageReport {
    pub stage: String,
    pub count: u64,
    pub mean_ms: f64,
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
}

/// Host↔device traffic of one stage, per frame it handled.
#[derive(Debug, Clone, Serialize)]
pub struct TrafficReport {
    pub stage: String,
    /// Frames the stage handled (a frame dropped later still counts here).
    pub frames: u64,
    pub total: HostTraffic,
}

/// Everything the service counted.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub backend: String,
    /// "device: …" when frames stay on the GPU from upload to panel, else
    /// "host: …" and why.
    pub frame_path: String,
    pub submitted: u64,
    pub rejected: Vec<(String, u64)>,
    pub dropped_queued: u64,
    pub dropped_at_present: u64,
    pub presented: u64,
    pub skipped: u64,
    pub missed_refreshes: u64,
    pub dcnn_failures: u64,
    pub disconnects_mid_frame: u64,
    pub clients_dropped: u64,
    pub in_flight_at_stop: u64,
    pub failed: u64,
    pub lost_by_sink: u64,
    pub layers_set: u64,
    pub layers_refused: u64,
    pub frames_with_layers: u64,
    /// (refreshes late against the prediction at submission, frames);
    /// 0 is on the predicted refresh, negative early.
    pub shown_vs_predicted: Vec<(i64, u64)>,
    /// Each submitter's shown frames against their predictions.
    pub clients: Vec<ClientReport>,
    pub stages: Vec<StageReport>,
    /// Host↔device traffic per frame, by stage (the decode and encode
    /// stages run on the host and move nothing).
    pub traffic: Vec<TrafficReport>,
    pub rss_kib: Vec<u64>,
}

/// One submitter's frames against the display-time predictions (client
/// 0: in-process submissions).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ClientReport {
    pub client: u64,
    pub shown: u64,
    pub on_time: u64,
    pub late: u64,
    pub early: u64,
    /// Mean of (predicted display time − submission), ms: how far ahead of
    /// the refresh it was predicted for the client submitted.
    pub mean_lead_ms: f64,
}

impl Report {
    /// Host↔device traffic per presented frame: every stage's total over
    /// the frames presented, so the work on frames dropped on the way is
    /// charged to the ones shown.
    pub fn traffic_per_frame(&self) -> HostTrafficMean {
        let mut total = HostTraffic::default();
        for t in &self.traffic {
            total.add(t.total);
        }
        HostTrafficMean::of(total, self.presented)
    }

    fn traffic_line(&self) -> String {
        let m = self.traffic_per_frame();
        let parts: Vec<String> = self
            .traffic
            .iter()
            .filter(|t| t.frames > 0)
            .map(|t| {
                let m = HostTrafficMean::of(t.total, t.frames);
                format!(
                    "{} {:.1} MB up in {:.2} uploads, {:.1} MB down, {:.2} read-backs over {} frames",
                    t.stage,
                    m.to_device_bytes / 1e6,
                    m.uploads,
                    m.to_host_bytes / 1e6,
                    m.read_backs,
                    t.frames
                )
            })
            .collect();
        format!(
            "host traffic per presented frame: {:.1} MB to the device in {:.2} uploads, {:.1} MB \
             back, {:.2} read-backs (per frame each stage handled: {})\n",
            m.to_device_bytes / 1e6,
            m.uploads,
            m.to_host_bytes / 1e6,
            m.read_backs,
            if parts.is_empty() {
                "no device stage".to_string()
            } else {
                parts.join("; ")
            }
        )
    }

    pub fn rejected_total(&self) -> u64 {
        self.rejected.iter().map(|(_, n)| n).sum()
    }

    /// Every frame in exactly one bucket: the sum of the buckets. Once the
    /// service has shut down this equals `submitted`; while it runs the
    /// difference is the frames in flight.
    pub fn accounted(&self) -> u64 {
        self.presented
            + self.rejected_total()
            + self.dropped_queued
            + self.dropped_at_present
            + self.skipped
            + self.in_flight_at_stop
            + self.failed
    }

    /// The human-readable table printed at exit and on SIGUSR1.
    pub fn table(&self) -> String {
        let mut s = format!(
            "frames: {} submitted, {} presented, {} rejected, {} dropped in queues, \
             {} replaced before a refresh, {} skipped by the sink, {} in flight at stop, \
             {} failed; {} refreshes missed; preprocess: {} ({} failures)\n",
            self.submitted,
            self.presented,
            self.rejected_total(),
            self.dropped_queued,
            self.dropped_at_present,
            self.skipped,
            self.in_flight_at_stop,
            self.failed,
            self.missed_refreshes,
            self.backend,
            self.dcnn_failures
        );
        let pending = self.submitted.saturating_sub(self.accounted());
        if pending > 0 {
            s += &format!("{pending} frames in the pipeline now\n");
        }
        if self.lost_by_sink > 0 {
            s += &format!(
                "{} presented frames lost by the sink (not recorded)\n",
                self.lost_by_sink
            );
        }
        let shown: u64 = self.shown_vs_predicted.iter().map(|&(_, n)| n).sum();
        if shown > 0 {
            let parts: Vec<String> = self
                .shown_vs_predicted
                .iter()
                .map(|&(k, n)| {
                    let at = match k {
                        0 => "on the predicted refresh".to_string(),
                        k if k > 0 => format!("{k} late"),
                        k => format!("{} early", -k),
                    };
                    format!("{at} {:.1} %", 100.0 * n as f64 / shown as f64)
                })
                .collect();
            s += &format!("shown vs predicted (refreshes): {}\n", parts.join(", "));
        }
        for c in self.clients.iter().filter(|c| c.client != 0) {
            s += &format!(
                "client {}: {} shown, {} on the predicted refresh, {} late, {} early; submitted \
                 {:.1} ms before the predicted display time on average\n",
                c.client, c.shown, c.on_time, c.late, c.early, c.mean_lead_ms
            );
        }
        if self.layers_set + self.layers_refused > 0 {
            s += &format!(
                "layers: {} set, {} refused; {} frames blended with quad layers\n",
                self.layers_set, self.layers_refused, self.frames_with_layers
            );
        }
        let rejected: Vec<String> = self
            .rejected
            .iter()
            .filter(|(_, n)| *n > 0)
            .map(|(r, n)| format!("{r} {n}"))
            .collect();
        if !rejected.is_empty() {
            s += &format!("rejected: {}\n", rejected.join(", "));
        }
        let e2e = self
            .stages
            .iter()
            .find(|r| r.stage == "end-to-end")
            .map_or(0.0, |r| r.mean_ms);
        s += &format!("frame path: {}\n", self.frame_path);
        s += &self.traffic_line();
        s += "stage        count     p50 ms     p99 ms     max ms   share of end-to-end\n";
        for r in &self.stages {
            // dcnn-gpu is inside dcnn; end-to-end is the whole.
            let share = if r.stage == "end-to-end" || r.stage == "dcnn-gpu" || e2e <= 0.0 {
                String::new()
            } else {
                format!("{:>5.1} %", 100.0 * r.mean_ms / e2e)
            };
            s += &format!(
                "{:<10} {:>7} {:>10.3} {:>10.3} {:>10.3}   {share}\n",
                r.stage, r.count, r.p50_ms, r.p99_ms, r.max_ms
            );
        }
        s
    }
}
