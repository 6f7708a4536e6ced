//! The newest frames' timelines: for each frame that left the pipeline at
//! the panel (shown, or replaced by a newer one before a refresh showed
//! it), when it was submitted, the refresh predicted for it, when each
//! stage took and finished it, how long it was held back for a present,
//! and when it was shown or replaced. The counters say how many frames
//! were dropped or late; the timelines say why (docs/service.md, "Frame
//! timelines"). A frame evicted from a queue between the stages never
//! reaches the panel's slot: it has no timeline (its id is missing), and
//! `dropped_queued` counts it.

use std::collections::VecDeque;

use serde::Serialize;

/// Timelines kept: the newest, so a long run shows its latest frames (a
/// benchmark's case, a few hundred frames, is kept whole).
pub const TIMELINE_FRAMES: usize = 4096;

/// The stages a timeline marks, in order.
pub const MARKED_STAGES: [super::Stage; 3] = [
    super::Stage::Upload,
    super::Stage::Preprocess,
    super::Stage::Encode,
];

/// What became of a frame at the panel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Outcome {
    /// On the panel.
    Shown,
    /// Taken by the present loop; the sink could not take it.
    Skipped,
    /// Replaced in the present slot by a newer frame before a refresh
    /// showed it (counted in `dropped_at_present`).
    Replaced,
}

/// A frame's raw times on the service's clock, ns (see [`FrameTiming`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FrameMarks {
    pub id: u64,
    pub owner: u64,
    pub submit_ns: u64,
    pub predicted_ns: u64,
    /// Each marked stage's start and end ([`MARKED_STAGES`]; 0: not run).
    pub stages_ns: [[u64; 2]; 3],
    pub held_ns: u64,
    pub ready_ns: u64,
    /// The device's own time for its preprocessing (timestamps, every
    /// view's summed) and the host's before that work's submission, where
    /// the device path ran it.
    pub gpu_ns: Option<u64>,
    pub record_ns: Option<u64>,
    /// The device path's whole submission on the device (timestamps): the
    /// uploads' copies, unpacks, layers, stages and encodes.
    pub frame_gpu_ns: Option<u64>,
    /// The frame budget's level it ran (the report's `frame_budget`
    /// levels, by index).
    pub level: Option<u8>,
}

/// One frame's timeline, ms from the service's start.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameTiming {
    pub id: u64,
    /// Who submitted it (a socket client; 0 in process).
    pub owner: u64,
    pub outcome: Outcome,
    pub submitted_ms: f64,
    /// The refresh predicted for it at submission (or its client's
    /// display time).
    pub predicted_ms: f64,
    /// When the upload, preprocess and encode stages took it and finished
    /// it ([`MARKED_STAGES`]).
    pub stages_ms: [[f64; 2]; 3],
    /// Of the preprocess stage's time, how long it was held back for a
    /// present (pacing::gate).
    pub held_ms: f64,
    /// In the present slot, ready for a refresh.
    pub ready_ms: f64,
    /// Of the preprocess stage's time, the device's own (timestamps) and
    /// the host's before the submission (the device path).
    pub gpu_ms: Option<f64>,
    pub record_ms: Option<f64>,
    /// The device path's whole submission on the device (timestamps).
    pub frame_gpu_ms: Option<f64>,
    /// The frame budget's level it ran (the report's `frame_budget`
    /// levels, by index; none without a ladder).
    pub level: Option<u8>,
    /// Shown or skipped: when the present loop took it, and the refresh
    /// it was on (shown).
    pub taken_ms: Option<f64>,
    pub shown_ms: Option<f64>,
    /// Replaced: when, and by which frame.
    pub replaced_ms: Option<f64>,
    pub replaced_by: Option<u64>,
}

/// One refresh the present loop worked for, ms from the service's start.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RefreshTiming {
    pub refresh_ms: f64,
    /// When the loop planned to wake for it (the refresh less its lead),
    /// and when it took a frame (none: nothing was due).
    pub wake_ms: f64,
    pub taken_ms: Option<f64>,
    /// When its present ended, and the frame it showed.
    pub presented_ms: Option<f64>,
    pub frame: Option<u64>,
    /// Refreshes passed without a present before this one.
    pub missed: u64,
    /// The pipeline's bound that sources planned with then (submission to
    /// ready), ms.
    pub bound_ms: f64,
}

/// A refresh's raw times (see [`RefreshTiming`]), ns.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RefreshMarks {
    pub refresh_ns: u64,
    pub wake_ns: u64,
    pub taken_ns: Option<u64>,
    pub presented_ns: Option<u64>,
    pub frame: Option<u64>,
    pub missed: u64,
    pub bound_ns: u64,
}

/// The rings of the newest timelines.
#[derive(Debug, Default)]
pub(crate) struct Timeline {
    origin_ns: u64,
    frames: VecDeque<FrameTiming>,
    refreshes: VecDeque<RefreshTiming>,
}

impl Timeline {
    pub(crate) fn set_origin(&mut self, origin_ns: u64) {
        self.origin_ns = origin_ns;
    }

    fn ms(&self, ns: u64) -> f64 {
        // Whole microseconds: the clocks' resolution that matters here.
        ((ns as f64 - self.origin_ns as f64) / 1e3).round() / 1e3
    }

    /// A frame left the pipeline: `outcome` at `at_ns` (taken, or
    /// replaced by `by`), on the refresh `shown_ns` where it was shown.
    pub(crate) fn record(
        &mut self,
        m: &FrameMarks,
        outcome: Outcome,
        at_ns: u64,
        shown_ns: Option<u64>,
        by: Option<u64>,
    ) {
        let stage = |[a, b]: [u64; 2]| {
            if a == 0 {
                [0.0; 2]
            } else {
                [self.ms(a), self.ms(b)]
            }
        };
        let replaced = outcome == Outcome::Replaced;
        let timing = FrameTiming {
            id: m.id,
            owner: m.owner,
            outcome,
            submitted_ms: self.ms(m.submit_ns),
            predicted_ms: self.ms(m.predicted_ns),
            stages_ms: m.stages_ns.map(stage),
            held_ms: duration_ms(m.held_ns),
            ready_ms: self.ms(m.ready_ns),
            gpu_ms: m.gpu_ns.map(duration_ms),
            record_ms: m.record_ns.map(duration_ms),
            frame_gpu_ms: m.frame_gpu_ns.map(duration_ms),
            level: m.level,
            taken_ms: (!replaced).then(|| self.ms(at_ns)),
            shown_ms: shown_ns.map(|ns| self.ms(ns)),
            replaced_ms: replaced.then(|| self.ms(at_ns)),
            replaced_by: by.filter(|_| replaced),
        };
        if self.frames.len() >= TIMELINE_FRAMES {
            self.frames.pop_front();
        }
        self.frames.push_back(timing);
    }

    /// The present loop's work for a refresh.
    pub(crate) fn record_refresh(&mut self, r: &RefreshMarks) {
        let timing = RefreshTiming {
            refresh_ms: self.ms(r.refresh_ns),
            wake_ms: self.ms(r.wake_ns),
            taken_ms: r.taken_ns.map(|ns| self.ms(ns)),
            presented_ms: r.presented_ns.map(|ns| self.ms(ns)),
            frame: r.frame,
            missed: r.missed,
            bound_ms: (r.bound_ns as f64 / 1e3).round() / 1e3,
        };
        if self.refreshes.len() >= TIMELINE_FRAMES {
            self.refreshes.pop_front();
        }
        self.refreshes.push_back(timing);
    }

    pub(crate) fn refreshes(&self) -> Vec<RefreshTiming> {
        self.refreshes.iter().cloned().collect()
    }

    /// The timelines by submission.
    pub(crate) fn frames(&self) -> Vec<FrameTiming> {
        let mut v: Vec<FrameTiming> = self.frames.iter().cloned().collect();
        v.sort_by(|a, b| {
            a.submitted_ms
                .total_cmp(&b.submitted_ms)
                .then(a.id.cmp(&b.id))
        });
        v
    }
}

/// What the timelines say about one kind of frame: how many, and the
/// median of each part of their way from submission to the refresh.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TimelineRow {
    /// "on time", "early", "late", "replaced" or "skipped".
    pub frames: &'static str,
    pub count: usize,
    /// Submission to the preprocess stage taking it (the upload and the
    /// queues before it).
    pub to_preprocess_ms: f64,
    /// Held back for a present.
    pub held_ms: f64,
    /// The preprocess stage's own time, less the hold.
    pub preprocess_ms: f64,
    /// Of it, the device's own time and the host's before the submission
    /// (`None`: not measured, off the device path or without timestamps),
    /// and the whole submission's time on the device.
    pub gpu_ms: Option<f64>,
    pub record_ms: Option<f64>,
    pub frame_gpu_ms: Option<f64>,
    /// The preprocess stage's end to ready (the queue and the encode).
    pub to_ready_ms: f64,
    /// The present loop's wake for the frame's predicted refresh less the
    /// frame's ready time: how long before its take it was ready
    /// (negative: it missed it; `None`: no refresh record for any).
    pub ready_before_take_ms: Option<f64>,
    /// The present of those shown: from the take to the present's end.
    pub present_ms: Option<f64>,
    /// When the first and the last of them were submitted, s from the
    /// first frame's submission.
    pub first_s: f64,
    pub last_s: f64,
}

/// A duration in ms, to the µs.
fn duration_ms(ns: u64) -> f64 {
    (ns as f64 / 1e3).round() / 1e3
}

/// The timelines' frames by what became of them against their predicted
/// refresh (shown on it, before or after it; replaced; skipped), each
/// kind's medians, with the present loop's `refreshes`. A refresh is
/// `period_ms`: "on time" is within half of one of the prediction.
pub fn summarize(
    frames: &[FrameTiming],
    refreshes: &[RefreshTiming],
    period_ms: f64,
) -> Vec<TimelineRow> {
    let wake_for = |predicted_ms: f64| {
        refreshes
            .iter()
            .find(|r| (r.refresh_ms - predicted_ms).abs() < period_ms / 2.0)
            .map(|r| r.wake_ms)
    };
    let presented = |f: &FrameTiming| {
        let taken = f.taken_ms?;
        refreshes
            .iter()
            .find(|r| r.frame == Some(f.id) && r.taken_ms == Some(taken))
            .and_then(|r| Some(r.presented_ms? - taken))
    };
    let t0 = frames
        .iter()
        .map(|f| f.submitted_ms)
        .fold(f64::INFINITY, f64::min);
    let kind = |f: &FrameTiming| match (f.outcome, f.shown_ms) {
        (Outcome::Replaced, _) => "replaced",
        (Outcome::Skipped, _) => "skipped",
        (Outcome::Shown, Some(s)) if s > f.predicted_ms + period_ms / 2.0 => "late",
        (Outcome::Shown, Some(s)) if s < f.predicted_ms - period_ms / 2.0 => "early",
        (Outcome::Shown, _) => "on time",
    };
    ["on time", "early", "late", "replaced", "skipped"]
        .into_iter()
        .filter_map(|name| {
            let of: Vec<&FrameTiming> = frames.iter().filter(|f| kind(f) == name).collect();
            if of.is_empty() {
                return None;
            }
            let median_of = |g: &dyn Fn(&FrameTiming) -> Option<f64>| {
                let mut v: Vec<f64> = of.iter().filter_map(|f| g(f)).collect();
                v.sort_by(f64::total_cmp);
                let m = v.len() / 2;
                match v.len() {
                    0 => None,
                    n if n % 2 == 1 => Some(v[m]),
                    _ => Some((v[m - 1] + v[m]) / 2.0),
                }
            };
            let median =
                |g: &dyn Fn(&FrameTiming) -> f64| median_of(&|f| Some(g(f))).unwrap_or(0.0);
            let submitted: Vec<f64> = of.iter().map(|f| f.submitted_ms).collect();
            Some(TimelineRow {
                frames: name,
                count: of.len(),
                to_preprocess_ms: median(&|f| f.stages_ms[1][0] - f.submitted_ms),
                held_ms: median(&|f| f.held_ms),
                preprocess_ms: median(&|f| f.stages_ms[1][1] - f.stages_ms[1][0] - f.held_ms),
                gpu_ms: median_of(&|f| f.gpu_ms),
                record_ms: median_of(&|f| f.record_ms),
                frame_gpu_ms: median_of(&|f| f.frame_gpu_ms),
                to_ready_ms: median(&|f| f.ready_ms - f.stages_ms[1][1]),
                ready_before_take_ms: median_of(&|f| Some(wake_for(f.predicted_ms)? - f.ready_ms)),
                present_ms: median_of(&presented),
                first_s: (submitted.iter().copied().fold(f64::INFINITY, f64::min) - t0) / 1e3,
                last_s: (submitted.iter().copied().fold(f64::NEG_INFINITY, f64::max) - t0) / 1e3,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn marks(id: u64, submit_ns: u64, predicted_ns: u64) -> FrameMarks {
        let ms = 1_000_000;
        FrameMarks {
            id,
            owner: 0,
            submit_ns,
            predicted_ns,
            stages_ns: [
                [submit_ns + ms, submit_ns + 2 * ms],
                [submit_ns + 2 * ms, submit_ns + 6 * ms],
                [submit_ns + 6 * ms, submit_ns + 7 * ms],
            ],
            held_ns: ms,
            ready_ns: submit_ns + 7 * ms,
            gpu_ns: Some(2 * ms + 1234),
            record_ns: None,
            frame_gpu_ns: None,
            level: None,
        }
    }

    #[test]
    fn a_timeline_is_in_ms_from_the_origin_and_keeps_the_newest() {
        let mut t = Timeline::default();
        t.set_origin(5_000_000);
        let m = marks(3, 6_000_000, 16_000_000);
        t.record(&m, Outcome::Shown, 14_000_000, Some(16_000_000), None);
        let f = &t.frames()[0];
        assert_eq!(
            (f.submitted_ms, f.predicted_ms, f.stages_ms[1], f.held_ms),
            (1.0, 11.0, [3.0, 7.0], 1.0)
        );
        // Durations to the µs; a time not measured stays unknown.
        assert_eq!((f.gpu_ms, f.record_ms), (Some(2.001), None));
        assert_eq!(
            (f.taken_ms, f.shown_ms, f.replaced_ms),
            (Some(9.0), Some(11.0), None)
        );
        t.record(&m, Outcome::Replaced, 8_000_000, None, Some(4));
        let f = &t.frames()[1];
        assert_eq!(
            (f.taken_ms, f.replaced_ms, f.replaced_by),
            (None, Some(3.0), Some(4))
        );
        for i in 0..TIMELINE_FRAMES as u64 {
            t.record(
                &marks(100 + i, 7_000_000 + i, 0),
                Outcome::Shown,
                0,
                None,
                None,
            );
        }
        let frames = t.frames();
        assert_eq!(frames.len(), TIMELINE_FRAMES);
        assert_eq!(frames[0].id, 100, "the oldest went first");
    }

    #[test]
    fn the_summary_sorts_frames_by_their_refresh_and_gives_medians() {
        let mut t = Timeline::default();
        let ms = 1_000_000;
        let period = 10 * ms;
        // Submitted 10 ms apart, each predicted a period after submission.
        for i in 0..6u64 {
            let submit = 100 * ms + i * period;
            let m = marks(i, submit, submit + period);
            match i {
                // Shown a refresh after its prediction.
                4 => t.record(
                    &m,
                    Outcome::Shown,
                    submit + period,
                    Some(submit + 2 * period),
                    None,
                ),
                5 => t.record(&m, Outcome::Replaced, submit + 9 * ms, None, Some(6)),
                _ => t.record(
                    &m,
                    Outcome::Shown,
                    submit + 8 * ms,
                    Some(submit + period),
                    None,
                ),
            }
        }
        // The loop wakes 2 ms before each refresh; its present takes 0.5 ms.
        for k in 0..8u64 {
            let refresh = 100 * ms + k * period;
            let shown = (0..6u64).find(|&i| i != 5 && 100 * ms + i * period + period == refresh);
            t.record_refresh(&RefreshMarks {
                refresh_ns: refresh,
                wake_ns: refresh - 2 * ms,
                taken_ns: Some(refresh - 2 * ms),
                presented_ns: Some(refresh - 2 * ms + ms / 2),
                frame: shown,
                missed: 0,
                bound_ns: 7 * ms,
            });
        }
        let rows = summarize(&t.frames(), &t.refreshes(), 10.0);
        let names: Vec<(&str, usize)> = rows.iter().map(|r| (r.frames, r.count)).collect();
        assert_eq!(names, [("on time", 4), ("late", 1), ("replaced", 1)]);
        let on_time = &rows[0];
        // marks(): the preprocess stage from 2 to 6 ms, 1 of it held; ready at 7.
        assert_eq!(
            (
                on_time.to_preprocess_ms,
                on_time.held_ms,
                on_time.preprocess_ms
            ),
            (2.0, 1.0, 3.0)
        );
        // Ready at 7 ms, predicted at 10, taken at 8.
        assert_eq!(
            (
                on_time.to_ready_ms,
                on_time.ready_before_take_ms,
                on_time.present_ms
            ),
            (1.0, Some(1.0), Some(0.5))
        );
        // Frame 4 was taken at 18 ms (a refresh late): no present of it on record.
        assert_eq!(rows[1].present_ms, None);
        assert_eq!((on_time.first_s, on_time.last_s), (0.0, 0.03));
        assert_eq!((rows[2].first_s, rows[2].last_s), (0.05, 0.05));
    }
}
