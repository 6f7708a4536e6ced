//! The service's pacing as one event loop on a fake clock, for tests: a
//! source that renders for the refresh it will be shown at, a stage of a
//! given cost behind a newest-wins hand-over, the present slot, and the
//! present loop on the real [`PresentPacer`] and [`DisplaySchedule`], run
//! in time order. The pacing's tests and the frame budget's share it.

use super::{Clock, DisplaySchedule, Estimate, FakeClock, NewestSlot, PresentPacer};
use crate::pipeline::stats::{ShownFrame, Stats};

#[derive(Debug, Clone, Copy)]
pub(crate) struct Frame {
    pub(crate) id: u64,
    pub(crate) submit_ns: u64,
    pub(crate) predicted_ns: u64,
    pub(crate) ready_ns: u64,
}

/// What a run showed.
#[derive(Debug, Default)]
pub(crate) struct Outcome {
    pub(crate) shown: Vec<(Frame, u64)>,
    /// (refresh, end of the present work, margin when woken) per present.
    pub(crate) presents: Vec<(u64, u64, u64)>,
    /// Frames replaced in the stage's input before it took them.
    pub(crate) dropped_before_stage: u64,
    /// Those frames.
    pub(crate) dropped: Vec<Frame>,
    /// Frames replaced in the present slot before the loop took them.
    pub(crate) replaced: Vec<Frame>,
    pub(crate) most_waiting: usize,
}

/// `refreshes` refreshes at 90 Hz; the stage's cost for frame `id` is
/// `stage_ns(id)`, the present's work `present_ns`.
pub(crate) fn run(
    refreshes: u64,
    stage_ns: impl Fn(u64) -> u64,
    present_ns: u64,
    stats: &Stats,
) -> Outcome {
    run_with(refreshes, stage_ns, |_| present_ns, stats)
}

/// As [`run`], the `n`-th present's work `present_ns(n)`.
pub(crate) fn run_with(
    refreshes: u64,
    stage_ns: impl Fn(u64) -> u64,
    present_ns: impl Fn(u64) -> u64,
    stats: &Stats,
) -> Outcome {
    run_staged(refreshes, |c| stage_ns(c.id), present_ns, stats)
}

/// A frame the stage starts: what its cost may depend on.
#[derive(Debug, Clone, Copy)]
pub(crate) struct StageCall {
    pub(crate) id: u64,
    /// When the stage starts it.
    pub(crate) start_ns: u64,
    /// The present loop's lead as the schedule has it then.
    pub(crate) latch_ns: u64,
    pub(crate) period_ns: u64,
}

/// As [`run_with`], the stage's cost for each frame it starts
/// `stage(call)`, called in time order.
pub(crate) fn run_staged(
    refreshes: u64,
    mut stage_ns: impl FnMut(StageCall) -> u64,
    present_ns: impl Fn(u64) -> u64,
    stats: &Stats,
) -> Outcome {
    let clock = FakeClock::default();
    let mut pacer = PresentPacer::new(90.0, clock.now_ns());
    let period = pacer.period_ns();
    let schedule = DisplaySchedule::new(period, clock.now_ns());
    let mut pipeline = Estimate::default();
    let slot = NewestSlot::<Frame>::new();
    let mut out = Outcome::default();
    // The stage: one frame in work, one waiting (newest wins).
    let mut in_stage: Option<Frame> = None;
    let mut waiting: Option<Frame> = None;
    let mut next_id = 0;
    let mut plan = schedule.plan_submission(0, 0, 0);
    let mut last_target = 0;
    // Runs the source and the stage up to `t`, in time order.
    let mut advance = |t: u64,
                       in_stage: &mut Option<Frame>,
                       waiting: &mut Option<Frame>,
                       out: &mut Outcome| loop {
        let stage_done = in_stage.map(|f| f.ready_ns);
        let source_due = plan.start_ns;
        let next = stage_done.map_or(source_due, |d| d.min(source_due));
        if next > t {
            break;
        }
        clock.sleep_until_ns(next);
        if stage_done == Some(next) {
            let f = in_stage.take().expect("in stage");
            out.replaced.extend(slot.put_keeping_dropping(f, |_| false));
            if let Some(mut w) = waiting.take() {
                let call = StageCall {
                    id: w.id,
                    start_ns: next,
                    latch_ns: schedule.latch_ns(),
                    period_ns: period,
                };
                w.ready_ns = next + stage_ns(call);
                *in_stage = Some(w);
            }
            continue;
        }
        // The source submits the frame it made for the planned refresh
        // (making it takes no time here).
        let now = clock.now_ns();
        let f = Frame {
            id: next_id,
            submit_ns: now,
            predicted_ns: plan.refresh_ns,
            ready_ns: 0,
        };
        next_id += 1;
        if in_stage.is_none() {
            let call = StageCall {
                id: f.id,
                start_ns: now,
                latch_ns: schedule.latch_ns(),
                period_ns: period,
            };
            *in_stage = Some(Frame {
                ready_ns: now + stage_ns(call),
                ..f
            });
        } else if let Some(old) = waiting.replace(f) {
            out.dropped_before_stage += 1;
            out.dropped.push(old);
        }
        out.most_waiting = out.most_waiting.max(usize::from(waiting.is_some()));
        last_target = last_target.max(plan.refresh_ns);
        // As the pattern source plans (`source::Rate::wait`).
        let after = schedule.replan_after(last_target, now, 0);
        plan = schedule.plan_submission(now, after, 0);
    };
    for _ in 0..refreshes {
        let wake = pacer.next(clock.now_ns());
        schedule.observe_refresh(wake.vsync_ns);
        schedule.set_latch_ns(pacer.lead_ns());
        let margin = pacer.margin_ns();
        advance(wake.wake_ns, &mut in_stage, &mut waiting, &mut out);
        clock.sleep_until_ns(wake.wake_ns);
        let Some(f) = slot.take() else {
            continue;
        };
        let done = wake.wake_ns + present_ns(out.presents.len() as u64);
        advance(done, &mut in_stage, &mut waiting, &mut out);
        clock.sleep_until_ns(done);
        let finished = pacer.finished(&wake, done);
        // As the present loop (no stage holds a frame back here).
        pipeline.observe(f.ready_ns - f.submit_ns);
        schedule.publish_pipeline(&pipeline);
        stats.record_vs_prediction(ShownFrame {
            owner: 0,
            submit_ns: f.submit_ns,
            predicted_ns: f.predicted_ns,
            shown_ns: finished.shown_ns,
            period_ns: period,
        });
        out.shown.push((f, finished.shown_ns));
        out.presents.push((wake.vsync_ns, done, margin));
    }
    out
}
