//! Frame pacing: the present loop runs on the panel's refresh, never on
//! ingest. A [`Pacer`] turns a clock into vsync deadlines and counts the
//! refreshes it missed; a [`NewestSlot`] is the hand-over between the last
//! processing stage and the present loop: the newest frame wins, a frame
//! replaced before it was shown is counted as dropped, and taking never
//! blocks. The clock is a trait so tests run on a [`FakeClock`].

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

#[cfg(test)]
pub(crate) mod fake_loop;
mod gate;
mod jit;
pub use gate::{PresentGate, Slot};
pub use jit::{Estimate, Finished, PresentPacer, Wake};

/// Monotonic time in nanoseconds since an arbitrary origin.
pub trait Clock: Send + Sync + std::fmt::Debug {
    fn now_ns(&self) -> u64;
    fn sleep_until_ns(&self, deadline_ns: u64);
}

/// The real monotonic clock: CLOCK_MONOTONIC, the clock applications
/// stamp capture times with (docs/protocol.md).
#[derive(Debug, Clone, Copy, Default)]
pub struct SystemClock;

pub use nedrt_protocol::monotonic_ns;

impl Clock for SystemClock {
    fn now_ns(&self) -> u64 {
        monotonic_ns()
    }
    fn sleep_until_ns(&self, deadline_ns: u64) {
        let now = self.now_ns();
        if deadline_ns > now {
            std::thread::sleep(Duration::from_nanos(deadline_ns - now));
        }
    }
}

/// A clock that moves only when told to (or when slept on), for tests.
#[derive(Debug, Default)]
pub struct FakeClock {
    now_ns: AtomicU64,
}

impl FakeClock {
    pub fn advance_ns(&self, ns: u64) {
        self.now_ns.fetch_add(ns, Ordering::SeqCst);
    }
}

impl Clock for FakeClock {
    fn now_ns(&self) -> u64 {
        self.now_ns.load(Ordering::SeqCst)
    }
    fn sleep_until_ns(&self, deadline_ns: u64) {
        self.now_ns.fetch_max(deadline_ns, Ordering::SeqCst);
    }
}

/// One refresh to present at.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tick {
    /// The refresh's time.
    pub vsync_ns: u64,
    /// Refreshes that passed since the previous tick without a present.
    pub missed: u64,
}

/// Vsync deadlines at a fixed refresh rate.
#[derive(Debug, Clone)]
pub struct Pacer {
    period_ns: u64,
    next_vsync_ns: u64,
}

impl Pacer {
    /// Refreshes at `refresh_hz` from `start_ns` on.
    pub fn new(refresh_hz: f64, start_ns: u64) -> Self {
        let period_ns = Self::period_ns_of(refresh_hz);
        Self {
            period_ns,
            next_vsync_ns: start_ns + period_ns,
        }
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// The refresh period at `refresh_hz`, whole nanoseconds (at least 1).
    pub fn period_ns_of(refresh_hz: f64) -> u64 {
        (1e9 / refresh_hz).round().max(1.0) as u64
    }

    /// The next refresh at or after `now_ns`; refreshes already past are
    /// counted as missed and skipped (a late loop catches up, it does not
    /// present a burst).
    pub fn next(&mut self, now_ns: u64) -> Tick {
        let mut missed = 0;
        if now_ns > self.next_vsync_ns {
            missed = (now_ns - self.next_vsync_ns).div_ceil(self.period_ns);
            self.next_vsync_ns += missed * self.period_ns;
        }
        let tick = Tick {
            vsync_ns: self.next_vsync_ns,
            missed,
        };
        self.next_vsync_ns += self.period_ns;
        tick
    }
}

/// When frames will be on the panel: what the present loop tells
/// applications so they render for the time their frame is seen (as
/// Monado's `u_pacing` answers xrWaitFrame). The present loop records each
/// refresh it paces to, how long before a refresh it takes its frame (its
/// lead), and how long frames take from submission to ready; a frame
/// submitted at `now` is predicted on the first refresh whose take is at
/// or after `now` + that time (an [`Estimate`]'s bound, so a jittering
/// stage is still in time). Lock-free: submitters read it on their own
/// threads.
#[derive(Debug)]
pub struct DisplaySchedule {
    period_ns: AtomicU64,
    /// A refresh the present loop paced to: the refreshes' phase.
    refresh_ns: AtomicU64,
    /// Submission to ready (in the present slot): the estimate's mean and
    /// deviation ([`Estimate`]), ns.
    pipeline_ns: AtomicU64,
    pipeline_dev_ns: AtomicU64,
    /// How long before its refresh a frame must be ready: the loop's lead
    /// ([`PresentPacer::lead_ns`]), or a period for a sink whose present
    /// waits for the refresh (the loop takes the slot a period ahead).
    latch_ns: AtomicU64,
    /// The present loop's own lead (its work and margin) whether or not
    /// its sink waits for the refresh: what the device's time per refresh
    /// leaves the preprocessing ([`crate::pipeline::ladder::frame_budget_ns`]).
    present_lead_ns: AtomicU64,
}

impl DisplaySchedule {
    /// Refreshes every `period_ns` from `start_ns` (as [`Pacer::new`]).
    pub fn new(period_ns: u64, start_ns: u64) -> Self {
        Self {
            period_ns: AtomicU64::new(period_ns.max(1)),
            refresh_ns: AtomicU64::new(start_ns + period_ns.max(1)),
            pipeline_ns: AtomicU64::new(0),
            pipeline_dev_ns: AtomicU64::new(0),
            latch_ns: AtomicU64::new(0),
            present_lead_ns: AtomicU64::new(0),
        }
    }

    /// See the field: the present loop sets it from its pacer.
    pub fn set_present_lead_ns(&self, ns: u64) {
        self.present_lead_ns.store(ns, Ordering::Relaxed);
    }

    pub fn present_lead_ns(&self) -> u64 {
        self.present_lead_ns.load(Ordering::Relaxed)
    }

    /// See the field: the present loop sets it from its sink and pacer.
    pub fn set_latch_ns(&self, ns: u64) {
        self.latch_ns.store(ns, Ordering::Relaxed);
    }

    pub fn latch_ns(&self) -> u64 {
        self.latch_ns.load(Ordering::Relaxed)
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns.load(Ordering::Relaxed)
    }

    /// The present loop paced to a refresh at `vsync_ns`.
    pub fn observe_refresh(&self, vsync_ns: u64) {
        self.refresh_ns.store(vsync_ns, Ordering::Relaxed);
    }

    /// The pipeline's estimate, as last published.
    pub fn pipeline(&self) -> (u64, u64) {
        (
            self.pipeline_ns.load(Ordering::Relaxed),
            self.pipeline_dev_ns.load(Ordering::Relaxed),
        )
    }

    /// Publishes the pipeline's estimate (the present loop keeps it).
    pub fn publish_pipeline(&self, estimate: &Estimate) {
        self.pipeline_ns
            .store(estimate.mean_ns(), Ordering::Relaxed);
        self.pipeline_dev_ns
            .store(estimate.dev_ns(), Ordering::Relaxed);
    }

    /// Submission to ready that the predictions plan with: the estimate's
    /// bound ([`Estimate::bound_ns`]).
    pub fn pipeline_bound_ns(&self) -> u64 {
        let (mean, dev) = self.pipeline();
        mean + Estimate::DEVIATIONS * dev
    }

    /// The first refresh at or after `t_ns`. The refresh the loop paces to
    /// is the next one there is, so anything before it gets it.
    pub fn refresh_at_or_after(&self, t_ns: u64) -> u64 {
        let period = self.period_ns();
        let phase = self.refresh_ns.load(Ordering::Relaxed);
        if t_ns <= phase {
            phase
        } else {
            phase + (t_ns - phase).div_ceil(period) * period
        }
    }

    /// When a frame submitted at `now_ns` is predicted to be on the panel.
    pub fn predicted_display_ns(&self, now_ns: u64) -> u64 {
        self.refresh_at_or_after(now_ns + self.pipeline_bound_ns() + self.latch_ns())
    }

    /// A source's next frame: the first refresh after `after_ns` that a
    /// frame started now (taking `make_ns` to make before it is submitted)
    /// can reach, and when to start making it so that it is submitted just
    /// in time for that refresh, with a thirty-second of a period to spare
    /// (so that the estimate moving a little between the plan and the
    /// submission does not move the prediction to the next refresh).
    pub fn plan_submission(&self, now_ns: u64, after_ns: u64, make_ns: u64) -> SubmitPlan {
        let ahead = self.ahead_ns(make_ns);
        let mut refresh_ns = self.refresh_at_or_after(now_ns + ahead);
        if refresh_ns <= after_ns {
            refresh_ns = self.refresh_at_or_after(after_ns + 1);
        }
        SubmitPlan {
            refresh_ns,
            start_ns: refresh_ns.saturating_sub(ahead).max(now_ns),
        }
    }

    /// How long before its refresh a frame taking `make_ns` to make is
    /// started: its making, the pipeline's bound, the loop's latch and a
    /// 32nd of a period to spare.
    fn ahead_ns(&self, make_ns: u64) -> u64 {
        make_ns + self.pipeline_bound_ns() + self.latch_ns() + self.period_ns() / 32
    }

    /// The refresh a source's last frame (made for `planned_ns`, submitted
    /// at `submitted_ns`) will be on, for its next plan's `after_ns`: the
    /// planned one, unless the pipeline's estimate has shrunk since by more
    /// than a period. Such a frame is shown when ready, refreshes before
    /// its plan, and waiting for that plan would stall the source (the
    /// H200, 2026-11-28: a 1343 ms first frame had frames planned up to
    /// 4.7 s ahead, and the source made one each 60–335 ms as the
    /// estimate shrank).
    pub fn replan_after(&self, planned_ns: u64, submitted_ns: u64, make_ns: u64) -> u64 {
        let period = self.period_ns();
        let now_planned = self.refresh_at_or_after(submitted_ns + self.ahead_ns(make_ns));
        if now_planned + period < planned_ns {
            now_planned
        } else {
            planned_ns
        }
    }
}

/// When a source is to start its next frame, and for which refresh.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SubmitPlan {
    pub refresh_ns: u64,
    pub start_ns: u64,
}

/// Newest-wins hand-over between two threads, with room for frames that
/// wait for a later refresh: an item put replaces every item waiting
/// unless the putter keeps it ([`NewestSlot::put_keeping`]), and a take
/// takes the newest item due, dropping the older ones.
#[derive(Debug, Default)]
pub struct NewestSlot<T> {
    slot: Mutex<std::collections::VecDeque<T>>,
    dropped: AtomicU64,
}

/// Items waiting for their refresh at most (a client as far ahead as a
/// slow pipeline's lead, several refreshes); past it, the newest but one
/// is dropped: the next due and the newest stay, so the panel keeps
/// moving and ends on the newest.
const WAITING: usize = 8;

impl<T> NewestSlot<T> {
    pub fn new() -> Self {
        Self {
            slot: Mutex::new(std::collections::VecDeque::new()),
            dropped: AtomicU64::new(0),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, std::collections::VecDeque<T>> {
        self.slot.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Puts `item`, replacing (and counting as dropped) any not yet taken.
    pub fn put(&self, item: T) {
        self.put_keeping(item, |_| false);
    }

    /// Puts `item`, replacing the items not yet taken except those `keep`
    /// holds on to (frames for a later refresh than a newer one may be
    /// for); at most [`WAITING`] wait.
    pub fn put_keeping(&self, item: T, keep: impl Fn(&T) -> bool) {
        drop(self.put_keeping_dropping(item, keep));
    }

    /// As [`NewestSlot::put_keeping`], returning the items it replaced
    /// (oldest first), for the caller to account for outside the lock.
    pub fn put_keeping_dropping(&self, item: T, keep: impl Fn(&T) -> bool) -> Vec<T> {
        let mut slot = self.lock();
        let mut dropped = Vec::new();
        for t in std::mem::take(&mut *slot) {
            if keep(&t) {
                slot.push_back(t);
            } else {
                dropped.push(t);
            }
        }
        if slot.len() >= WAITING {
            dropped.extend(slot.pop_back());
        }
        slot.push_back(item);
        self.dropped
            .fetch_add(dropped.len() as u64, Ordering::Relaxed);
        dropped
    }

    /// Takes the newest item, if any, dropping older ones; never waits.
    pub fn take(&self) -> Option<T> {
        self.take_due(|_| true)
    }

    /// Takes the newest item that `due` says is due, dropping the older
    /// ones; the items after it (not due yet) stay.
    pub fn take_due(&self, due: impl Fn(&T) -> bool) -> Option<T> {
        self.take_due_dropping(due).0
    }

    /// As [`NewestSlot::take_due`], with the items it dropped (oldest first).
    pub fn take_due_dropping(&self, due: impl Fn(&T) -> bool) -> (Option<T>, Vec<T>) {
        let mut slot = self.lock();
        let Some(i) = slot.iter().rposition(due) else {
            return (None, Vec::new());
        };
        self.dropped.fetch_add(i as u64, Ordering::Relaxed);
        let dropped: Vec<T> = slot.drain(..i).collect();
        (slot.pop_front(), dropped)
    }

    /// Whether an item waits.
    pub fn is_empty(&self) -> bool {
        self.lock().is_empty()
    }

    /// Empties the slot; how many items were there.
    pub fn drain(&self) -> u64 {
        let mut slot = self.lock();
        let n = slot.len() as u64;
        slot.clear();
        n
    }

    /// Items replaced before anyone took them.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
#[path = "pacing/plan_tests.rs"]
mod plan_tests;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_slot_keeps_frames_for_later_refreshes_and_shows_the_newest_due() {
        // Items are (display time, held).
        let slot = NewestSlot::<(u64, bool)>::new();
        slot.put((1, false));
        slot.put((2, false));
        assert_eq!((slot.take(), slot.dropped()), (Some((2, false)), 1));
        // Held frames for refreshes 10, 11, 12 wait together.
        for t in 10..13 {
            slot.put_keeping((t, true), |old| old.1);
        }
        let due = |now: u64| move |x: &(u64, bool)| !x.1 || x.0 <= now;
        assert_eq!(slot.take_due(due(9)), None);
        assert_eq!(slot.take_due(due(11)), Some((11, true)));
        // 10 was due and older: dropped; 12 waits.
        assert_eq!((slot.dropped(), slot.is_empty()), (2, false));
        assert_eq!(slot.take_due(due(12)), Some((12, true)));
        // Past WAITING, the newest but one goes: the next due and the
        // newest stay.
        for t in 20..20 + WAITING as u64 + 3 {
            slot.put_keeping((t, true), |old| old.1);
        }
        assert_eq!(slot.drain(), WAITING as u64);
        assert_eq!(slot.dropped(), 2 + 3);
        slot.put_keeping((30, true), |old| old.1);
        slot.put_keeping((31, false), |old| old.1);
        // An unheld frame is always due, and newer: the held one goes.
        assert_eq!(slot.take_due(due(0)), Some((31, false)));
    }

    #[test]
    fn ticks_follow_the_refresh_and_count_missed_ones() {
        let clock = FakeClock::default();
        let mut pacer = Pacer::new(90.0, clock.now_ns());
        let period = pacer.period_ns();
        assert_eq!(period, 11_111_111);
        let t1 = pacer.next(clock.now_ns());
        assert_eq!(
            t1,
            Tick {
                vsync_ns: period,
                missed: 0
            }
        );
        clock.sleep_until_ns(t1.vsync_ns);
        let t2 = pacer.next(clock.now_ns());
        assert_eq!(
            t2,
            Tick {
                vsync_ns: 2 * period,
                missed: 0
            }
        );
        // The loop stalls for 3.5 periods: refreshes 3, 4 and 5 are missed.
        clock.advance_ns(period + 7 * period / 2);
        let t3 = pacer.next(clock.now_ns());
        assert_eq!(t3.missed, 3);
        assert_eq!(t3.vsync_ns, 6 * period);
        assert!(t3.vsync_ns >= clock.now_ns());
        // Exactly on a refresh is not late.
        clock.sleep_until_ns(t3.vsync_ns);
        assert_eq!(pacer.next(clock.now_ns()).missed, 0);
    }

    #[test]
    fn the_newest_frame_wins_and_replaced_ones_are_counted() {
        let slot = NewestSlot::new();
        assert_eq!(slot.take(), None::<u32>);
        slot.put(1);
        slot.put(2);
        slot.put(3);
        assert_eq!(slot.take(), Some(3));
        assert_eq!(slot.dropped(), 2);
        assert_eq!(slot.take(), None);
        slot.put(4);
        assert_eq!(slot.take(), Some(4));
        assert_eq!(slot.dropped(), 2);
    }

    #[test]
    fn the_replaced_items_come_back_to_the_caller_oldest_first() {
        let slot = NewestSlot::new();
        assert!(slot.put_keeping_dropping(1, |_| false).is_empty());
        assert_eq!(slot.put_keeping_dropping(2, |_| false), [1]);
        // 3 is kept (a frame held for a later refresh), 4 replaces 2.
        assert!(slot.put_keeping_dropping(3, |_| false).len() == 1);
        assert!(slot.put_keeping_dropping(4, |&x| x == 3).is_empty());
        assert_eq!(slot.put_keeping_dropping(5, |&x| x == 3), [4]);
        assert_eq!(slot.take_due_dropping(|&x| x > 3), (Some(5), vec![3]));
        assert_eq!(slot.take_due_dropping(|_| true), (None, vec![]));
        // Every item handed back was counted, and only those.
        assert_eq!(slot.dropped(), 4);
    }

    #[test]
    fn a_producer_faster_than_the_consumer_loses_only_counted_frames() {
        let slot = std::sync::Arc::new(NewestSlot::new());
        let producer = {
            let slot = slot.clone();
            std::thread::spawn(move || {
                for i in 0..10_000u32 {
                    slot.put(i);
                }
            })
        };
        let mut taken = Vec::new();
        let start = std::time::Instant::now();
        while !producer.is_finished() {
            assert!(
                start.elapsed() < crate::deadline::THREAD,
                "timed out waiting for the producer's 10 000 frames"
            );
            if let Some(v) = slot.take() {
                taken.push(v);
            }
        }
        crate::deadline::join_within(producer, crate::deadline::THREAD, "the producer to end");
        taken.extend(slot.take());
        assert!(taken.windows(2).all(|w| w[0] < w[1]), "in order");
        assert_eq!(taken.last(), Some(&9_999), "the last frame is never lost");
        assert_eq!(taken.len() as u64 + slot.dropped(), 10_000);
    }
}
