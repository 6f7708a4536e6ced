//! The service's report: the counts, each stage's latency, the traffic,
//! the predictions, as a table and as JSON (`--report-json`).

use serde::Serialize;

use nedrt_core::preprocess::HostTraffic;

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

impl StageReport {
    /// The report of histogram `h` under `stage`.
    pub fn of(stage: String, h: &crate::pipeline::latency::Histogram) -> Self {
        Self {
            stage,
            count: h.count(),
            mean_ms: h.mean_ns() / 1e6,
            p50_ms: h.quantile_ns(0.5) as f64 / 1e6,
            p99_ms: h.quantile_ns(0.99) as f64 / 1e6,
            max_ms: h.max_ns() as f64 / 1e6,
        }
    }
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
    /// The frame budget's levels: frames, time and switches per level,
    /// and the quality delivered (a run with a ladder).
    pub frame_budget: Option<crate::pipeline::ladder::BudgetReport>,
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
    /// Two views: a view shown from its last frame (its layer late).
    pub view_frames_reused: u64,
    /// (refreshes late against the prediction at submission, frames);
    /// 0 is on the predicted refresh, negative early.
    pub shown_vs_predicted: Vec<(i64, u64)>,
    /// Each submitter's shown frames against their predictions.
    pub clients: Vec<ClientReport>,
    pub stages: Vec<StageReport>,
    /// Frames shown after the refresh predicted at their submission, and
    /// by how much.
    pub late: StageReport,
    /// What `end-to-end` is measured between.
    pub end_to_end_from: String,
    /// Each view's engine (two views on the panel; empty for one).
    pub view_stages: Vec<StageReport>,
    /// Host↔device traffic per frame, by stage (the decode and encode
    /// stages run on the host and move nothing).
    pub traffic: Vec<TrafficReport>,
    pub rss_kib: Vec<u64>,
    /// The newest frames' timelines (stats::timeline), by submission.
    pub frames: Vec<super::FrameTiming>,
    /// The present loop's newest refreshes: its wake, its take, its
    /// present's end and the frame shown.
    pub refreshes: Vec<super::RefreshTiming>,
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
        if self.late.count > 0 {
            s += &format!(
                "late: {} frames shown after their predicted refresh, by p50 {:.3} ms, max \
                 {:.3} ms\n",
                self.late.count, self.late.p50_ms, self.late.max_ms
            );
        }
        for c in self.clients.iter().filter(|c| c.client != 0) {
            s += &format!(
                "client {}: {} shown, {} on the predicted refresh, {} late, {} early; submitted \
                 {:.1} ms before the predicted display time on average\n",
                c.client, c.shown, c.on_time, c.late, c.early, c.mean_lead_ms
            );
        }
        if !self.view_stages.is_empty() {
            s += &format!(
                "views: {} times a view was shown from its last frame (its frame not \
                 waited for)\n",
                self.view_frames_reused
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
        if let Some(b) = &self.frame_budget {
            s += &b.table();
        }
        s += &self.traffic_line();
        s += "stage            count     p50 ms     p99 ms     max ms   share of end-to-end\n";
        for r in &self.stages {
            // The GPU's and the record's times are inside preprocess;
            // end-to-end is the whole.
            let inside = ["end-to-end", "preprocess-gpu", "preprocess-record"];
            let share = if inside.contains(&r.stage.as_str()) || e2e <= 0.0 {
                String::new()
            } else {
                format!("{:>5.1} %", 100.0 * r.mean_ms / e2e)
            };
            s += &format!(
                "{:<14} {:>7} {:>10.3} {:>10.3} {:>10.3}   {share}\n",
                r.stage, r.count, r.p50_ms, r.p99_ms, r.max_ms
            );
        }
        // Inside dcnn, each view's engine where it ran.
        for r in &self.view_stages {
            s += &format!(
                "  {:<16} {:>5} {:>10.3} {:>10.3} {:>10.3}\n",
                r.stage, r.count, r.p50_ms, r.p99_ms, r.max_ms
            );
        }
        s += &format!("end-to-end: {}\n", self.end_to_end_from);
        s
    }
}
