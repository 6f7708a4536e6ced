//! Just-in-time presentation: the present loop wakes for a refresh as late
//! as it can and still have its work done by then (as Monado's
//! `u_pacing_compositor` does), so the frame it takes is the newest there
//! is, and sources render for the refresh they will be shown at
//! ([`super::DisplaySchedule::plan_submission`]). Both learn their timings
//! from what they measure, with [`Estimate`].

use super::Pacer;

/// A running estimate of a duration that jitters: its mean and its mean
/// deviation, updated as TCP's round-trip estimator (Jacobson and Karels,
/// RFC 6298: gains 1/8 and 1/4, the first sample's deviation half of it).
/// `bound_ns()` (mean + 4 deviations) is what the pacing plans with: it
/// holds for all but a few samples of a jittering stage.
///
/// The first [`Estimate::WARM_UP`] samples are averaged plainly, not
/// exponentially, and the largest of them is left out: a stage's first
/// frame pays its one-time costs (shaders compiled, buffers allocated,
/// clocks ramped up), up to 1343 ms where the next frames took 8–11 ms
/// (the half network on the H200, 2026-11-28). Seeded with it, the
/// exponential average kept the bound seconds long for tens of frames,
/// and the pacing planned frames that far ahead (docs/service.md, "The
/// warm-up").
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Estimate {
    mean_ns: u64,
    dev_ns: u64,
    samples: u64,
    /// The first samples, while warming up.
    first: [u64; Estimate::WARM_UP],
}

impl Estimate {
    /// Deviations above the mean that [`Estimate::bound_ns`] allows.
    pub const DEVIATIONS: u64 = 4;

    /// Samples taken robustly (the largest left out) before the running
    /// average takes over.
    pub const WARM_UP: usize = 8;

    pub fn observe(&mut self, ns: u64) {
        let n = self.samples as usize;
        self.samples += 1;
        if n >= Self::WARM_UP {
            let err = ns.abs_diff(self.mean_ns);
            self.dev_ns = (3 * self.dev_ns + err) / 4;
            self.mean_ns = (7 * self.mean_ns + ns) / 8;
            return;
        }
        self.first[n] = ns;
        let mut kept = self.first;
        let kept = &mut kept[..=n];
        kept.sort_unstable();
        // One sample alone is all there is. The deviation is the samples'
        // mean deviation, but no less than the running average's would be
        // for samples all alike (half the first, 3/4 of it a sample after):
        // a few samples cannot show how a stage jitters.
        let kept = if n == 0 { &kept[..] } else { &kept[..n] };
        let len = kept.len() as u64;
        self.mean_ns = kept.iter().sum::<u64>() / len;
        let spread = kept.iter().map(|s| s.abs_diff(self.mean_ns)).sum::<u64>() / len;
        let shrink = (len - 1) as u32;
        let floor = self.mean_ns / 2 * 3u64.pow(shrink) / 4u64.pow(shrink);
        self.dev_ns = spread.max(floor);
    }

    /// Whether the estimate is still in its first samples.
    pub fn warming_up(&self) -> bool {
        self.samples < Self::WARM_UP as u64
    }

    pub fn mean_ns(&self) -> u64 {
        self.mean_ns
    }

    pub fn dev_ns(&self) -> u64 {
        self.dev_ns
    }

    /// Mean + [`Estimate::DEVIATIONS`] deviations.
    pub fn bound_ns(&self) -> u64 {
        self.mean_ns + Self::DEVIATIONS * self.dev_ns
    }
}

/// One refresh the present loop works for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wake {
    /// The refresh.
    pub vsync_ns: u64,
    /// When the loop wakes to take the newest frame and present it.
    pub wake_ns: u64,
    /// Refreshes passed since the previous one without a present.
    pub missed: u64,
}

/// When the present loop's work for a refresh ended, against the refresh.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Finished {
    /// The refresh the frame is on: the one worked for, or the first after
    /// the work ended when it ended late.
    pub shown_ns: u64,
    /// How far past its refresh the work ended (0: in time).
    pub late_ns: u64,
}

/// The present loop's clock: for each refresh, when to wake. The wake is
/// the refresh minus the predicted time of the loop's own work (its
/// [`Estimate`]'s mean) minus a margin learnt from the misses: four of the
/// work's deviations (at least [`PresentPacer::MIN_MARGIN_DIV`]-th of a
/// period), plus what a late present adds (past the work estimate's
/// warm-up), decaying by 1/16 a present in time. The lead never exceeds a
/// period: a loop whose work takes longer than that cannot be in time
/// anyway, and waking earlier would only show older frames.
#[derive(Debug, Clone)]
pub struct PresentPacer {
    refreshes: Pacer,
    work: Estimate,
    /// Margin added by late presents (decays when in time).
    learnt_ns: u64,
}

impl PresentPacer {
    /// The margin's floor: a period over this (0.35 ms at 90 Hz), for the
    /// wake-up's own lateness (a sleeping thread wakes tens of µs late).
    pub const MIN_MARGIN_DIV: u64 = 32;

    /// Refreshes at `refresh_hz` from `start_ns` on.
    pub fn new(refresh_hz: f64, start_ns: u64) -> Self {
        Self {
            refreshes: Pacer::new(refresh_hz, start_ns),
            work: Estimate::default(),
            learnt_ns: 0,
        }
    }

    pub fn period_ns(&self) -> u64 {
        self.refreshes.period_ns()
    }

    /// The margin the loop keeps between the end of its work and the refresh.
    pub fn margin_ns(&self) -> u64 {
        let period = self.period_ns();
        (Estimate::DEVIATIONS * self.work.dev_ns()).max(period / Self::MIN_MARGIN_DIV)
            + self.learnt_ns
    }

    /// How long before a refresh the loop wakes: its work and the margin.
    pub fn lead_ns(&self) -> u64 {
        (self.work.mean_ns() + self.margin_ns()).min(self.period_ns())
    }

    /// How long before a refresh a frame may still be taken for it when
    /// none was there at the wake: the work's mean and two deviations
    /// (the wake keeps the whole margin; a frame that comes after it would
    /// otherwise miss this refresh and be replaced at the next).
    pub fn latest_take_ns(&self) -> u64 {
        (self.work.mean_ns() + 2 * self.work.dev_ns()).min(self.lead_ns())
    }

    /// The next refresh whose wake-up is not past at `now_ns`.
    pub fn next(&mut self, now_ns: u64) -> Wake {
        let lead = self.lead_ns();
        let tick = self.refreshes.next(now_ns + lead);
        Wake {
            vsync_ns: tick.vsync_ns,
            wake_ns: tick.vsync_ns - lead,
            missed: tick.missed,
        }
    }

    /// The next refresh for a sink whose present waits for the display
    /// itself: no lead (the sink's wait is the pacing).
    pub fn next_display_paced(&mut self, now_ns: u64) -> Wake {
        let tick = self.refreshes.next(now_ns);
        Wake {
            vsync_ns: tick.vsync_ns,
            wake_ns: now_ns,
            missed: tick.missed,
        }
    }

    /// The loop's work for `wake` ended at `done_ns`: learn from it.
    pub fn finished(&mut self, wake: &Wake, done_ns: u64) -> Finished {
        // From the planned wake, so a wake-up that comes late counts as work.
        self.work.observe(done_ns.saturating_sub(wake.wake_ns));
        let period = self.period_ns();
        if done_ns <= wake.vsync_ns {
            self.learnt_ns -= self.learnt_ns / 16;
            return Finished {
                shown_ns: wake.vsync_ns,
                late_ns: 0,
            };
        }
        let late_ns = done_ns - wake.vsync_ns;
        // The first presents pay one-time costs (the present's pipelines,
        // a GPU busy with the first frames' compiles): learnt, they kept
        // the wake a period early for 0.8 s after (the H200, 2026-11-28).
        if !self.work.warming_up() {
            self.learnt_ns = (self.learnt_ns + late_ns).min(period / 2);
        }
        Finished {
            shown_ns: wake.vsync_ns + late_ns.div_ceil(period) * period,
            late_ns,
        }
    }
}

#[cfg(test)]
#[path = "jit_tests.rs"]
mod tests;
