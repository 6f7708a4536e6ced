//! The gate on a fake clock: the real present pacer and gate, one
//! in-order device queue shared by the present's work and a preprocessing
//! that always has a frame to submit.

use super::*;
use crate::pipeline::pacing::{Clock, Estimate, FakeClock, PresentPacer};

const PERIOD: u64 = 11_111_111;
/// The present pacer's margin and the work's estimate settle by then.
const WARM_UP: usize = 24;

#[derive(Debug, Default)]
struct Outcome {
    /// Per present: how far past its refresh its work ended (0: in time).
    late_ns: Vec<u64>,
    /// Per present: how long before its refresh the loop woke to take the
    /// frame (what the frame waits on top of the pipeline).
    lead_ns: Vec<u64>,
    frames: u64,
    waits: u64,
}

/// `refreshes` refreshes at 90 Hz; the present's own device work is
/// `present_ns`; frame `i`'s preprocessing takes `work_ns(i)` on the
/// device, submitted as soon as the last one's fence signalled (asking the
/// gate first where `gated`).
fn run(refreshes: u64, work_ns: impl Fn(u64) -> u64, present_ns: u64, gated: bool) -> Outcome {
    let clock = FakeClock::default();
    let mut pacer = PresentPacer::new(90.0, clock.now_ns());
    let gate = PresentGate::new(pacer.period_ns());
    let mut estimate = Estimate::default();
    let mut device_free = 0u64;
    // When the preprocessing is next ready to submit, and the refresh
    // whose present it waits for.
    let mut ready = 0u64;
    let mut waiting: Option<u64> = None;
    let mut out = Outcome::default();
    for _ in 0..refreshes {
        let wake = pacer.next(clock.now_ns());
        gate.announce(wake.wake_ns, wake.vsync_ns);
        while waiting.is_none() && ready < wake.wake_ns {
            // Predicted as the service predicts: the first refresh whose
            // present comes after the work's end.
            let lead = wake.vsync_ns - wake.wake_ns;
            let predicted = (ready + estimate.bound_ns() + lead).div_ceil(PERIOD) * PERIOD;
            let slot = if gated {
                gate.slot(ready, estimate.bound_ns(), predicted)
            } else {
                Slot::Now
            };
            match slot {
                Slot::Now => {
                    let start = ready.max(device_free);
                    device_free = start + work_ns(out.frames);
                    // The stage waits for its fence.
                    estimate.observe(device_free - ready);
                    ready = device_free;
                    out.frames += 1;
                }
                Slot::AfterPresent(vsync) => {
                    waiting = Some(vsync);
                    out.waits += 1;
                }
            }
        }
        clock.sleep_until_ns(wake.wake_ns);
        // The present's work runs after whatever the device already has.
        let done = wake.wake_ns.max(device_free) + present_ns;
        device_free = done;
        clock.sleep_until_ns(done);
        pacer.finished(&wake, done);
        gate.done(wake.vsync_ns);
        out.late_ns.push(done.saturating_sub(wake.vsync_ns));
        out.lead_ns.push(wake.vsync_ns - wake.wake_ns);
        if waiting.is_some_and(|v| v <= wake.vsync_ns) {
            waiting = None;
            ready = ready.max(done);
        }
    }
    out
}

/// 0.3–0.6 of a period, varying frame to frame.
fn jittering(i: u64) -> u64 {
    PERIOD * 3 / 10 + (PERIOD * 3 / 10) * ((i * 7919) % 101) / 100
}

fn late_after_warm_up(o: &Outcome) -> usize {
    o.late_ns.iter().skip(WARM_UP).filter(|l| **l > 0).count()
}

/// The loop's mean lead after warm-up, in periods.
fn mean_lead(o: &Outcome) -> f64 {
    let leads = &o.lead_ns[WARM_UP..];
    leads.iter().sum::<u64>() as f64 / leads.len() as f64 / PERIOD as f64
}

#[test]
fn ungated_device_work_makes_the_present_loop_wake_early_to_wait_behind_it() {
    let o = run(400, jittering, PERIOD / 20, false);
    // docs/service.md quotes these (cargo test gate -- --nocapture).
    eprintln!(
        "ungated: lead {:.2} periods, {} late, {} frames",
        mean_lead(&o),
        late_after_warm_up(&o),
        o.frames
    );
    // The test can fail: without the gate, a present queues behind the
    // work, and the loop learns to wake that much earlier (every frame
    // then waits that long for its refresh) or is late.
    assert!(
        mean_lead(&o) > 0.3 || late_after_warm_up(&o) > 40,
        "lead {:.2} periods, {} late",
        mean_lead(&o),
        late_after_warm_up(&o)
    );
}

#[test]
fn gated_device_work_never_delays_a_present_and_keeps_up_with_the_refresh() {
    let o = run(400, jittering, PERIOD / 20, true);
    eprintln!(
        "gated: lead {:.2} periods, {} late, {} frames",
        mean_lead(&o),
        late_after_warm_up(&o),
        o.frames
    );
    // The loop wakes just before the refresh: its own work and margin.
    assert!(mean_lead(&o) < 0.15, "lead {:.2} periods", mean_lead(&o));
    assert_eq!(late_after_warm_up(&o), 0, "{:?}", &o.late_ns[WARM_UP..]);
    // A frame of preprocessing every refresh still: it fits between presents.
    assert!(o.frames >= 390, "{} frames in 400 refreshes", o.frames);
    assert!(o.waits > 0);
}

#[test]
fn work_longer_than_the_time_between_presents_is_not_held_back() {
    let long = |_| 3 * PERIOD / 2;
    let gated = run(200, long, PERIOD / 20, true);
    let ungated = run(200, long, PERIOD / 20, false);
    // Waiting could not save a present; the work goes as soon as it can.
    assert_eq!(gated.frames, ungated.frames);
    assert_eq!(gated.waits, 0);
}

#[test]
fn a_slot_is_now_before_any_present_after_the_loop_ends_and_for_work_that_ends_before_the_wake() {
    let gate = PresentGate::new(PERIOD);
    assert_eq!(gate.slot(5, PERIOD, 0), Slot::Now);
    gate.announce(10 * PERIOD - 1_000_000, 10 * PERIOD);
    // Ends before the wake: now.
    assert_eq!(gate.slot(9 * PERIOD, PERIOD / 2, 0), Slot::Now);
    // Would run into the present: after it.
    assert_eq!(
        gate.slot(9 * PERIOD + PERIOD / 2, PERIOD / 2, 0),
        Slot::AfterPresent(10 * PERIOD)
    );
    // A frame predicted for a later refresh is held the same way; one
    // predicted for that present's refresh is what it waits for: never held.
    assert_eq!(
        gate.slot(9 * PERIOD + PERIOD / 2, PERIOD / 2, 11 * PERIOD),
        Slot::AfterPresent(10 * PERIOD)
    );
    assert_eq!(
        gate.slot(9 * PERIOD + PERIOD / 2, PERIOD / 2, 10 * PERIOD),
        Slot::Now
    );
    // That present done: the next one is a period on.
    gate.done(10 * PERIOD);
    assert_eq!(gate.slot(10 * PERIOD, PERIOD / 2, 0), Slot::Now);
    assert!(gate.wait(10 * PERIOD, Duration::ZERO));
    assert!(!gate.wait(11 * PERIOD, Duration::from_millis(1)));
    gate.done(PresentGate::CLOSED);
    assert_eq!(gate.slot(11 * PERIOD - 100, PERIOD / 2, 0), Slot::Now);
    assert!(gate.wait(20 * PERIOD, Duration::ZERO));
}
