//! The whole loop of the device path on a fake clock: a source that plans
//! its frames with the real [`DisplaySchedule`], a device stage behind the
//! real [`PresentGate`] on one in-order queue with the present's work, and
//! the present loop on the real [`PresentPacer`], with the pipeline's
//! estimate fed as the present loop feeds it.
//!
//! What it pins (the H200, 2026-11-27, docs/benchmarks.md): a frame the
//! gate holds back for a present was planned too early; if that wait went
//! into the pipeline's estimate, the next frames were planned earlier
//! still, held back again, and shown a refresh before their prediction,
//! for good. Left out of the estimate, a start that overestimates settles
//! on frames made for the next refresh, never held back.

use super::{DisplaySchedule, Estimate, FakeClock, NewestSlot, PresentGate, PresentPacer, Slot};
use crate::pipeline::pacing::Clock;

const PERIOD: u64 = 11_111_111;

#[derive(Debug, Clone, Copy)]
struct Frame {
    id: u64,
    submit_ns: u64,
    predicted_ns: u64,
    ready_ns: u64,
    waited_ns: u64,
    /// Its wait in the engine's queue, as far as the last frame's hold
    /// made it longer.
    behind_hold_ns: u64,
}

/// A frame in the device stage: held back until the present for a refresh
/// is done (since when), or on the device until a time.
#[derive(Debug, Clone, Copy)]
enum InStage {
    Held {
        frame: Frame,
        vsync_ns: u64,
        since_ns: u64,
    },
    Running {
        frame: Frame,
        end_ns: u64,
    },
}

#[derive(Debug, Default)]
struct Outcome {
    /// Each frame shown, and the refresh it was on.
    shown: Vec<(Frame, u64)>,
}

/// The device stage and its queue.
struct Device<'a> {
    gate: &'a PresentGate,
    /// The gate's estimate of the stage's device work (submission to fence).
    work: Estimate,
    /// When the device's queue is next free.
    free_ns: u64,
    /// How long the last frame was held back.
    last_hold_ns: u64,
    cost_ns: &'a dyn Fn(u64) -> u64,
}

impl Device<'_> {
    /// The engine takes `frame` at `now`: asks the gate, then submits and
    /// waits for its fence (as `Engine::run`).
    fn take(&mut self, mut frame: Frame, now: u64) -> InStage {
        frame.behind_hold_ns = (now - frame.submit_ns).min(self.last_hold_ns);
        match self
            .gate
            .slot(now, self.work.bound_ns(), frame.predicted_ns)
        {
            Slot::Now => {
                self.last_hold_ns = 0;
                self.submit(frame, now)
            }
            Slot::AfterPresent(vsync_ns) => InStage::Held {
                frame,
                vsync_ns,
                since_ns: now,
            },
        }
    }

    fn submit(&mut self, frame: Frame, now: u64) -> InStage {
        let end_ns = now.max(self.free_ns) + (self.cost_ns)(frame.id);
        self.free_ns = end_ns;
        self.work.observe(end_ns - now);
        InStage::Running { frame, end_ns }
    }
}

/// What the pipeline's estimate learns from a frame shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Feed {
    /// Submission to ready less the gate's wait and the queueing behind a
    /// frame held back (as the present loop feeds it).
    LessHolds,
    /// Submission to ready, the gate's waits left in.
    WithWaits,
}

/// `refreshes` refreshes at 90 Hz; frame `id`'s device work takes
/// `cost_ns(id)`, the present's `present_ns`; `feed` is what the
/// pipeline's estimate learns.
fn run(refreshes: u64, cost_ns: &dyn Fn(u64) -> u64, present_ns: u64, feed: Feed) -> Outcome {
    let clock = FakeClock::default();
    let mut pacer = PresentPacer::new(90.0, clock.now_ns());
    let schedule = DisplaySchedule::new(pacer.period_ns(), clock.now_ns());
    let gate = PresentGate::new(pacer.period_ns());
    let mut device = Device {
        gate: &gate,
        work: Estimate::default(),
        free_ns: 0,
        last_hold_ns: 0,
        cost_ns,
    };
    let mut pipeline = Estimate::default();
    let slot = NewestSlot::<Frame>::new();
    let mut stage: Option<InStage> = None;
    let mut input: Option<Frame> = None;
    let mut plan = schedule.plan_submission(0, 0, 0);
    let mut last_target = 0;
    let mut next_id = 0;
    let mut out = Outcome::default();
    // The source and the stage up to `t`, in time order.
    let mut advance = |t: u64,
                       stage: &mut Option<InStage>,
                       input: &mut Option<Frame>,
                       device: &mut Device<'_>| loop {
        let stage_end = match stage {
            Some(InStage::Running { end_ns, .. }) => Some(*end_ns),
            _ => None,
        };
        let next = stage_end.map_or(plan.start_ns, |e| e.min(plan.start_ns));
        if next > t {
            break;
        }
        clock.sleep_until_ns(next);
        if stage_end == Some(next) {
            if let Some(InStage::Running { mut frame, .. }) = stage.take() {
                frame.ready_ns = next;
                slot.put(frame);
            }
            *stage = input.take().map(|f| device.take(f, next));
            continue;
        }
        // The source submits a frame (made in no time), predicted as the
        // compositor predicts it, and plans the next.
        let frame = Frame {
            id: next_id,
            submit_ns: next,
            predicted_ns: schedule.predicted_display_ns(next),
            ready_ns: 0,
            waited_ns: 0,
            behind_hold_ns: 0,
        };
        next_id += 1;
        if stage.is_none() {
            *stage = Some(device.take(frame, next));
        } else {
            *input = Some(frame);
        }
        last_target = last_target.max(plan.refresh_ns);
        plan = schedule.plan_submission(next, last_target, 0);
    };
    for _ in 0..refreshes {
        let wake = pacer.next(clock.now_ns());
        schedule.observe_refresh(wake.vsync_ns);
        schedule.set_latch_ns(pacer.lead_ns());
        gate.announce(wake.wake_ns, wake.vsync_ns);
        advance(wake.wake_ns, &mut stage, &mut input, &mut device);
        clock.sleep_until_ns(wake.wake_ns);
        let taken = slot.take();
        // The present's work queues behind what the device already has.
        let done = if taken.is_some() {
            let done = wake.wake_ns.max(device.free_ns) + present_ns;
            device.free_ns = done;
            advance(done, &mut stage, &mut input, &mut device);
            clock.sleep_until_ns(done);
            done
        } else {
            wake.wake_ns
        };
        gate.done(wake.vsync_ns);
        // A frame held back for this present goes now.
        if let Some(InStage::Held {
            mut frame,
            vsync_ns,
            since_ns,
        }) = stage
            && vsync_ns <= wake.vsync_ns
        {
            frame.waited_ns = done - since_ns;
            device.last_hold_ns = frame.waited_ns;
            stage = Some(device.submit(frame, done));
        }
        let Some(f) = taken else {
            continue;
        };
        let finished = pacer.finished(&wake, done);
        pipeline.observe(match feed {
            Feed::LessHolds => f.ready_ns - f.submit_ns - f.waited_ns - f.behind_hold_ns,
            Feed::WithWaits => f.ready_ns - f.submit_ns,
        });
        schedule.publish_pipeline(&pipeline);
        out.shown.push((f, finished.shown_ns));
    }
    out
}

/// A 7.2 ms stage (the shipped network's 7.1 ms on the H200 and its
/// fence) whose first frames take three periods, for twice the estimates'
/// warm-up (the slowest of which they leave out), so that the estimates
/// still start far too high, as on a device whose first frames are slow.
fn slow_start(id: u64) -> u64 {
    if id < 2 * Estimate::WARM_UP as u64 {
        3 * PERIOD
    } else {
        7_200_000
    }
}

const SETTLED: usize = 120;

#[test]
fn frames_held_back_for_a_present_do_not_make_the_next_ones_planned_earlier() {
    let out = run(400, &slow_start, 900_000, Feed::LessHolds);
    assert!(out.shown.len() > 300, "{} shown", out.shown.len());
    for &(f, shown) in &out.shown[SETTLED..] {
        assert_eq!(
            shown, f.predicted_ns,
            "frame {} shown at {shown}, predicted {}",
            f.id, f.predicted_ns
        );
        assert_eq!(f.waited_ns, 0, "frame {} held back", f.id);
        // Made for the next refresh: within one period from submission to
        // the panel (7.2 ms of work, 0.9 ms of present and the margins).
        assert!(
            shown - f.submit_ns < PERIOD,
            "frame {}: {} ns from submission to the panel",
            f.id,
            shown - f.submit_ns
        );
    }
}

#[test]
fn with_the_waits_in_the_estimate_the_frames_stay_planned_too_early() {
    // The failure the first test guards against, reproduced: the same run
    // with the gate's waits fed into the estimate.
    let out = run(400, &slow_start, 900_000, Feed::WithWaits);
    let settled = &out.shown[SETTLED..];
    let early = settled.iter().filter(|(f, s)| *s < f.predicted_ns).count();
    let held = settled.iter().filter(|(f, _)| f.waited_ns > 0).count();
    eprintln!(
        "waits in the estimate: {early} of {} shown early, {held} held back",
        settled.len()
    );
    assert!(
        early + held > settled.len() / 2,
        "{early} early, {held} held of {}",
        settled.len()
    );
}

/// The shipped model on the H200 (2026-11-28): after a slow start,
/// 8.6–9.6 ms of device work (its 7.1 ms of timestamps, the upload and
/// the fence) and a 0.9 ms present. Learning submission to ready less
/// the holds and the queueing they pass on, every frame is shown on its
/// predicted refresh, none is held back for long, and each reaches the
/// panel within 1.3 periods of its submission. (This loop settles without
/// the passed-on queueing left out too; on the H200 it did not: that
/// queueing put the bound at 14.2 ms where leaving it out gives 9.7, from
/// the same frames' timelines, docs/benchmarks.md.)
#[test]
fn a_stage_near_a_period_is_planned_without_the_queue_behind_its_holds() {
    let near = |id: u64| {
        if id < 2 * Estimate::WARM_UP as u64 {
            3 * PERIOD
        } else {
            8_600_000 + (id.wrapping_mul(2_654_435_761) % 1000) * 1_000
        }
    };
    let out = run(400, &near, 900_000, Feed::LessHolds);
    assert!(out.shown.len() > 300, "{} shown", out.shown.len());
    let settled = &out.shown[SETTLED..];
    for &(f, shown) in settled {
        assert_eq!(shown, f.predicted_ns, "frame {} off its prediction", f.id);
        assert!(
            f.waited_ns <= PERIOD / 10,
            "frame {} held {} ns",
            f.id,
            f.waited_ns
        );
        assert!(
            shown - f.submit_ns < 13 * PERIOD / 10,
            "frame {}: {} ns from submission to the panel",
            f.id,
            shown - f.submit_ns
        );
    }
}
