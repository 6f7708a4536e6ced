//! Device work and the present on one queue. wgpu gives a device one
//! in-order queue, so a preprocessing submitted just before the present
//! loop wakes makes the present wait behind it and miss its refresh. The
//! present loop announces each present (its wake and its refresh) and says
//! when it is done with it; the device's preprocessing asks [`PresentGate::slot`]
//! before it submits work of a predicted duration: now, if the work ends
//! before the next wake, or if its frame is predicted for that present's
//! refresh (the present waits for it); else after that present, if the
//! work is shorter than a period; else now (work of a period or more
//! delays a present whenever it runs, and waiting would only add latency).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::Duration;

/// When device work may be submitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Slot {
    Now,
    /// Once the present for the refresh at this time is done.
    AfterPresent(u64),
}

/// The present loop's announcements, for the device's submitters.
#[derive(Debug)]
pub struct PresentGate {
    period_ns: u64,
    /// The next present's wake and refresh, ns (0: none announced yet).
    wake_ns: AtomicU64,
    vsync_ns: AtomicU64,
    /// The refresh of the last present done ([`PresentGate::CLOSED`]: the
    /// loop has ended).
    done: Mutex<u64>,
    changed: Condvar,
}

impl PresentGate {
    /// Done for good: every wait ends, every slot is now.
    pub const CLOSED: u64 = u64::MAX;

    pub fn new(period_ns: u64) -> Self {
        Self {
            period_ns: period_ns.max(1),
            wake_ns: AtomicU64::new(0),
            vsync_ns: AtomicU64::new(0),
            done: Mutex::new(0),
            changed: Condvar::new(),
        }
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// The present loop will wake at `wake_ns` to present for `vsync_ns`.
    pub fn announce(&self, wake_ns: u64, vsync_ns: u64) {
        self.wake_ns.store(wake_ns, Ordering::SeqCst);
        self.vsync_ns.store(vsync_ns, Ordering::SeqCst);
    }

    /// The present loop is done with the refresh at `vsync_ns` (its work
    /// submitted, or nothing to show); [`PresentGate::CLOSED`] when it ends.
    pub fn done(&self, vsync_ns: u64) {
        let mut done = self.done.lock().unwrap_or_else(|p| p.into_inner());
        *done = (*done).max(vsync_ns);
        self.changed.notify_all();
    }

    /// When work predicted to take `work_ns` on the device may be
    /// submitted at `now_ns` (module docs), for a frame predicted to be on
    /// the panel at `frame_refresh_ns` (0: no prediction). A frame
    /// predicted for the refresh of the present in question is the one
    /// that present waits for: holding it back would only make it late.
    pub fn slot(&self, now_ns: u64, work_ns: u64, frame_refresh_ns: u64) -> Slot {
        let (mut wake, mut vsync) = (
            self.wake_ns.load(Ordering::SeqCst),
            self.vsync_ns.load(Ordering::SeqCst),
        );
        let done = *self.done.lock().unwrap_or_else(|p| p.into_inner());
        if vsync == 0 || done == Self::CLOSED {
            return Slot::Now;
        }
        if done >= vsync {
            // That present is done; the next is a period on.
            wake += self.period_ns;
            vsync += self.period_ns;
        }
        if now_ns.saturating_add(work_ns) <= wake
            || (frame_refresh_ns != 0 && frame_refresh_ns <= vsync)
        {
            return Slot::Now;
        }
        // Not the present's lead: that grows with the very queueing this
        // prevents, and would keep the loop waking early for good.
        if work_ns >= self.period_ns {
            return Slot::Now;
        }
        Slot::AfterPresent(vsync)
    }

    /// Waits until the present for `vsync_ns` is done, at most `timeout`;
    /// whether it was.
    pub fn wait(&self, vsync_ns: u64, timeout: Duration) -> bool {
        let done = self.done.lock().unwrap_or_else(|p| p.into_inner());
        let (done, _) = self
            .changed
            .wait_timeout_while(done, timeout, |d| *d < vsync_ns)
            .unwrap_or_else(|p| p.into_inner());
        *done >= vsync_ns
    }
}

#[cfg(test)]
#[path = "gate_tests.rs"]
mod tests;
