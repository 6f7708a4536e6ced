//! The pacing on a fake clock: a source that renders for the refresh it
//! will be shown at, a stage of a given cost behind a newest-wins hand-over,
//! the present slot, and the present loop on the real [`PresentPacer`] and
//! [`DisplaySchedule`], run as one event loop in time order
//! ([`super::super::fake_loop`]).

use super::super::fake_loop::{Outcome, run, run_with};
use super::*;
use crate::pipeline::pacing::{Clock, DisplaySchedule, FakeClock};
use crate::pipeline::stats::Stats;

const PERIOD: u64 = 11_111_111;
/// The estimates settle within this many frames.
const WARM_UP: usize = 24;

fn assert_on_time(out: &Outcome, what: &str) {
    assert!(out.shown.len() > 300, "{what}: {} shown", out.shown.len());
    for (i, &(f, shown)) in out.shown.iter().enumerate().skip(WARM_UP) {
        assert_eq!(
            shown, f.predicted_ns,
            "{what}: frame {} (shown #{i}) predicted {} shown {}",
            f.id, f.predicted_ns, shown
        );
    }
    for &(vsync, done, margin) in out.presents.iter().skip(WARM_UP) {
        assert!(
            done <= vsync,
            "{what}: a present ended {} ns late",
            done - vsync
        );
        assert!(
            vsync - done <= margin,
            "{what}: woke {} ns before its work needed, margin {margin}",
            vsync - done
        );
    }
    // Every frame's end-to-end time is its stage, the present and the
    // margins: no wait for a refresh's grid.
    for &(f, shown) in out.shown.iter().skip(WARM_UP) {
        assert!(
            shown - f.submit_ns < 2 * PERIOD,
            "{what}: {} ns",
            shown - f.submit_ns
        );
    }
}

#[test]
fn a_fixed_cost_stage_is_shown_on_its_predicted_refresh_just_after_the_wake() {
    let stats = Stats::default();
    let out = run(400, |_| 4 * PERIOD / 10, 700_000, &stats);
    assert_on_time(&out, "fixed");
    assert_eq!(out.dropped_before_stage, 0);
    // A frame is made for its refresh: submission to display is the stage,
    // the present and the margins, well under two periods.
    let (f, shown) = out.shown[300];
    let e2e = shown - f.submit_ns;
    assert!(e2e < PERIOD, "{e2e} ns from submission to display");
    let late = out
        .shown
        .iter()
        .filter(|(f, s)| *s > f.predicted_ns)
        .count();
    assert_eq!(stats.snapshot().late.count as usize, late);
}

#[test]
fn a_jittering_stage_below_a_period_is_shown_on_its_predicted_refresh() {
    let stats = Stats::default();
    // 0.3–0.8 of a period, in a scrambled order.
    let jitter =
        |id: u64| 3 * PERIOD / 10 + (id.wrapping_mul(2_654_435_761) % 1000) * PERIOD / 2000;
    let out = run(400, jitter, 700_000, &stats);
    assert_on_time(&out, "jitter");
}

#[test]
fn a_stage_longer_than_a_period_drops_newest_wins_and_counts_the_late() {
    let stats = Stats::default();
    let out = run(400, |_| 3 * PERIOD / 2, 700_000, &stats);
    // Frames are dropped, never queued: at most one waits for the stage.
    assert!(
        out.dropped_before_stage > 50,
        "{} dropped",
        out.dropped_before_stage
    );
    assert!(out.most_waiting <= 1);
    assert!(out.shown.len() > 150, "{} shown", out.shown.len());
    for &(f, shown) in out.shown.iter().skip(WARM_UP) {
        assert!(
            shown - f.submit_ns < 5 * PERIOD,
            "frame {}: {} ns from submission to display",
            f.id,
            shown - f.submit_ns
        );
    }
    let r = stats.snapshot();
    let late: u64 = r
        .shown_vs_predicted
        .iter()
        .filter(|(k, _)| *k > 0)
        .map(|(_, n)| n)
        .sum();
    assert!(late > 0, "{:?}", r.shown_vs_predicted);
    assert_eq!(r.late.count, late);
    assert!(r.late.max_ms >= PERIOD as f64 / 1e6 * 0.99, "{:?}", r.late);
}

/// A cold start, as on the H200 (2026-11-28): the stage's first frame
/// takes 120 periods (the half network's first frame, 1343 ms, compiling
/// its shaders) and the first present three. A few frames on, every frame
/// is shown on the refresh it was predicted for, one a refresh, and none
/// is replaced in the present slot: the slow samples leave the estimates
/// with the warm-up, and the source does not wait for the refreshes it
/// planned while they counted.
#[test]
fn a_slow_first_frame_does_not_hold_the_pacing_back() {
    let stats = Stats::default();
    let cold = |id: u64| {
        if id == 0 {
            120 * PERIOD
        } else {
            4 * PERIOD / 10
        }
    };
    let present = |n: u64| if n == 0 { 3 * PERIOD } else { 700_000 };
    let out = run_with(400, cold, present, &stats);
    // The first frame is on the panel after about 121 refreshes; the rest
    // of the run has room for 270 more.
    assert!(out.shown.len() > 260, "{} shown", out.shown.len());
    const SETTLE: usize = Estimate::WARM_UP + 2;
    let settled = &out.shown[SETTLE..];
    for (i, &(f, shown)) in settled.iter().enumerate() {
        assert_eq!(
            shown,
            f.predicted_ns,
            "frame {} (shown #{}) predicted {} shown {}",
            f.id,
            i + SETTLE,
            f.predicted_ns,
            shown
        );
    }
    for w in settled.windows(2) {
        assert_eq!(
            w[1].1 - w[0].1,
            PERIOD,
            "frames {} and {}: a refresh without a new frame",
            w[0].0.id,
            w[1].0.id
        );
    }
    let first_settled = settled[0].0.id;
    let late: Vec<u64> = out
        .replaced
        .iter()
        .filter(|f| f.id >= first_settled)
        .map(|f| f.id)
        .collect();
    assert!(
        late.is_empty(),
        "replaced in the slot after the warm-up: {late:?}"
    );
}

/// A source that planned a frame with an estimate a slow first frame
/// inflated does not wait for that plan's refresh once the estimate has
/// shrunk: the frame is shown when ready, and the next is planned from
/// there. With an estimate that holds, the plan stands (two frames are
/// never made for one refresh).
#[test]
fn a_plan_made_with_an_inflated_estimate_is_not_waited_for() {
    let clock = FakeClock::default();
    let schedule = DisplaySchedule::new(PERIOD, 0);
    let mut pipeline = Estimate::default();
    pipeline.observe(120 * PERIOD);
    schedule.publish_pipeline(&pipeline);
    let now = clock.now_ns();
    let inflated = schedule.plan_submission(now, 0, 0);
    assert!(inflated.refresh_ns > 300 * PERIOD, "{inflated:?}");
    // The next frames take 0.4 of a period: the estimate forgets the first.
    pipeline.observe(4 * PERIOD / 10);
    schedule.publish_pipeline(&pipeline);
    clock.sleep_until_ns(now + PERIOD / 10);
    let after = schedule.replan_after(inflated.refresh_ns, now, 0);
    assert!(after <= 3 * PERIOD, "{after}");
    let next = schedule.plan_submission(clock.now_ns(), after, 0);
    assert!(next.refresh_ns > after, "{next:?} after {after}");
    assert!(next.start_ns <= clock.now_ns() + 3 * PERIOD, "{next:?}");
    // An estimate that holds keeps the plan.
    let now = clock.now_ns();
    let held = schedule.plan_submission(now, next.refresh_ns, 0);
    clock.sleep_until_ns(held.start_ns);
    assert_eq!(
        schedule.replan_after(held.refresh_ns, held.start_ns, 0),
        held.refresh_ns
    );
}

/// Presents late in the warm-up (the H200, 2026-11-28: five of the first
/// ten 6–17 ms behind the first frames' compiles, then 0.7–1.1 ms) leave
/// no margin behind: the wake comes back to the work and the margin's
/// floor.
#[test]
fn presents_late_in_the_warm_up_are_not_learnt() {
    let mut pacer = PresentPacer::new(90.0, 0);
    let period = pacer.period_ns();
    let mut now = 0;
    for i in 0..2 * Estimate::WARM_UP as u64 {
        let w = pacer.next(now);
        let work = if i == 0 { 3 * period / 2 } else { 900_000 };
        let done = w.wake_ns + work;
        pacer.finished(&w, done);
        now = done.max(w.vsync_ns);
    }
    let floor = period / PresentPacer::MIN_MARGIN_DIV;
    assert!(
        pacer.lead_ns() <= 900_000 + floor + 200_000,
        "lead {} ns, margin {} ns",
        pacer.lead_ns(),
        pacer.margin_ns()
    );
}

#[test]
fn a_late_present_raises_the_margin_and_the_wake_moves_earlier() {
    let mut pacer = PresentPacer::new(90.0, 0);
    let period = pacer.period_ns();
    let mut work = 1_000_000;
    let mut now = 0;
    for i in 0..60u64 {
        let w = pacer.next(now);
        assert!(
            w.vsync_ns - w.wake_ns <= period,
            "the lead is at most a period"
        );
        // The work doubles at frame 30.
        if i == 30 {
            work *= 2;
        }
        let done = w.wake_ns + work;
        let f = pacer.finished(&w, done);
        if i == 30 {
            assert!(f.late_ns > 0, "the jump is late once");
            assert_eq!(f.shown_ns, w.vsync_ns + period);
        }
        if i > 33 {
            assert_eq!(f.late_ns, 0, "frame {i} late after the margin grew");
        }
        now = done.max(w.vsync_ns);
    }
}

#[test]
fn estimates_follow_the_mean_and_the_deviation() {
    let mut e = Estimate::default();
    e.observe(1000);
    assert_eq!((e.mean_ns(), e.dev_ns()), (1000, 500));
    for _ in 0..200 {
        e.observe(2000);
    }
    assert!(e.mean_ns().abs_diff(2000) < 10, "{e:?}");
    assert!(e.dev_ns() < 10, "{e:?}");
    for i in 0..400 {
        e.observe(if i % 2 == 0 { 1000 } else { 3000 });
    }
    assert!(e.mean_ns().abs_diff(2000) < 200, "{e:?}");
    assert!(e.bound_ns() >= 3000, "{e:?}");
}

/// When nothing is due at the wake, a frame may still be taken until the
/// work's mean and two deviations before the refresh: inside the wake's
/// lead (which keeps four deviations and the floor), never past it.
#[test]
fn the_latest_take_lies_between_the_work_and_the_wake() {
    let mut pacer = PresentPacer::new(90.0, 0);
    let period = pacer.period_ns();
    for i in 0..64u64 {
        let wake = pacer.next(i * period);
        // Work of 1 ms ± 0.2 ms.
        let work = 1_000_000 + (i % 3) * 200_000;
        pacer.finished(&wake, wake.wake_ns + work);
    }
    let (latest, lead) = (pacer.latest_take_ns(), pacer.lead_ns());
    assert!(latest >= 1_000_000 && latest < lead, "{latest} {lead}");
    assert_eq!(latest, pacer.work.mean_ns() + 2 * pacer.work.dev_ns());
    // Before any work is known, the latest take is the wake itself at most.
    let fresh = PresentPacer::new(90.0, 0);
    assert!(fresh.latest_take_ns() <= fresh.lead_ns());
}
