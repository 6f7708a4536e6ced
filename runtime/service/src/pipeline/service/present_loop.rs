//! The present loop: on the caller's thread, at the panel's refresh, just
//! in time ([`PresentPacer`]): it wakes at the refresh minus its own work
//! and a learnt margin, takes the newest finished frame and presents it.

use std::sync::atomic::Ordering;

use super::Service;
use super::compositor::Timed;
use super::control::Control;
use crate::pipeline::pacing::{Estimate, PresentPacer, Wake};
use crate::pipeline::stats::{Outcome, RSS_EVERY, RefreshMarks, Report, ShownFrame, Stage};
use crate::present::{PanelFrame, PresentError, Presented, Sink};

/// How often the loop looks into the slot while it waits for a late frame.
const LATE_LATCH_POLL_NS: u64 = 100_000;

impl Service {
    /// Presents at the panel's refresh until the pipeline has drained (all
    /// handles dropped and the last frame shown), the sink goes away, or
    /// `control.stop` is set. Returns the counts and latencies.
    pub fn present_loop(
        &mut self,
        sink: &mut dyn Sink,
        control: &Control,
    ) -> Result<Report, PresentError> {
        use std::sync::atomic::Ordering::Relaxed;
        let mut pacer = PresentPacer::new(self.panel.refresh_hz, self.clock.now_ns());
        let display_paced = sink.paced_by_display();
        // Submission to ready, learnt from the frames shown, less the time
        // a stage held a frame back for a present (Timed::waited_ns) and
        // the queueing that hold passed on to the next frame
        // (Timed::behind_hold_ns); published for the predictions and the
        // sources' plans.
        let mut pipeline = Estimate::default();
        let mut last: Option<PanelFrame> = None;
        let progress = &control.progress;
        progress.start("frames", 0);
        loop {
            if control.stop.load(Relaxed) || !sink.poll() {
                break;
            }
            if control.report.swap(false, Relaxed) {
                // The slot counts its replacements itself; bring the
                // count up to date for a mid-run table.
                self.stats
                    .dropped_at_present
                    .store(self.slot.dropped(), Relaxed);
                progress.note(&self.stats.snapshot().table());
            }
            // Just in time (pacing::jit): wake at the refresh minus this
            // loop's own work and its margin, take the newest frame then.
            // A display-paced present takes its frame a period before the
            // refresh it waits for.
            let wake = if display_paced {
                pacer.next_display_paced(self.clock.now_ns())
            } else {
                pacer.next(self.clock.now_ns())
            };
            self.schedule.observe_refresh(wake.vsync_ns);
            // The device's work yields to this present (pacing::gate); a
            // display-paced present waits in the sink and is not announced.
            if !display_paced {
                self.gate.announce(wake.wake_ns, wake.vsync_ns);
            }
            self.schedule.set_present_lead_ns(pacer.lead_ns());
            self.schedule.set_latch_ns(if display_paced {
                pacer.period_ns()
            } else {
                pacer.lead_ns()
            });
            self.stats.missed_refreshes.fetch_add(wake.missed, Relaxed);
            if !display_paced {
                self.clock.sleep_until_ns(wake.wake_ns);
            }
            // A frame a client rendered for a later refresh (its display
            // time) waits for it in the slot: the newest frame due is shown.
            let half = pacer.period_ns() / 2;
            let due = |t: &Timed<PanelFrame>| !t.hold || t.predicted_ns <= wake.vsync_ns + half;
            // Time spent waiting for a frame that came after the wake.
            let mut latched_ns = 0;
            let t = match self.take_due(due) {
                Some(t) => Some(t),
                None => {
                    // Read before the second look: once drained, no frame can
                    // arrive after it.
                    let drained = self.drained.load(Ordering::SeqCst);
                    match self.take_due(due) {
                        Some(t) => Some(t),
                        None if drained && !control.keep_open && self.slot.is_empty() => break,
                        None => {
                            if drained && let Some(frame) = &last {
                                // Keep the window's content (uncounted re-present).
                                sink.present(frame.codes())?;
                                None
                            } else if let Some((t, waited)) = (!drained && !display_paced)
                                .then(|| {
                                    let latest = pacer.latest_take_ns();
                                    self.late_latch(wake.vsync_ns.saturating_sub(latest), &due)
                                })
                                .flatten()
                            {
                                latched_ns = waited;
                                Some(t)
                            } else {
                                // Nothing to show at this refresh: let it pass.
                                self.gate.done(wake.vsync_ns);
                                self.clock.sleep_until_ns(wake.vsync_ns);
                                None
                            }
                        }
                    }
                }
            };
            let refresh = RefreshMarks {
                refresh_ns: wake.vsync_ns,
                wake_ns: wake.wake_ns,
                missed: wake.missed,
                bound_ns: self.schedule.pipeline_bound_ns(),
                ..RefreshMarks::default()
            };
            let Some(t) = t else {
                self.stats.record_refresh(&refresh);
                continue;
            };
            let t0 = self.clock.now_ns();
            let shown = {
                let _span =
                    tracing::info_span!("stage", stage = %"present", frame = t.id).entered();
                let presented = sink.present(t.item.codes());
                self.gate.done(wake.vsync_ns);
                match presented {
                    Ok(shown) => shown,
                    Err(e) => {
                        self.stats.failed.fetch_add(1, Relaxed);
                        self.stop_stages();
                        return Err(e);
                    }
                }
            };
            let now = self.clock.now_ns();
            let on_panel = if display_paced {
                wake.vsync_ns.max(now)
            } else {
                // The wait for a late frame is not the loop's work: counted
                // as such, it would wake the loop earlier for good.
                let worked = Wake {
                    wake_ns: wake.wake_ns + latched_ns,
                    ..wake
                };
                pacer.finished(&worked, now).shown_ns
            };
            let (outcome, shown_ns) = match shown {
                Presented::Shown => (Outcome::Shown, Some(on_panel)),
                Presented::Skipped => (Outcome::Skipped, None),
            };
            self.stats
                .record_timeline(&t.marks(), outcome, t0, shown_ns, None);
            self.stats.record_refresh(&RefreshMarks {
                taken_ns: Some(t0),
                presented_ns: Some(now),
                frame: Some(t.id),
                ..refresh
            });
            match shown {
                Presented::Shown => {
                    self.stats.present_traffic.record(sink.last_traffic());
                    // Less the waits the pacing chose: a frame held back
                    // for a present because it was early must not make the
                    // next ones planned earlier still (the H200, 2026-11-27:
                    // planned three refreshes ahead, shown one early). Nor
                    // the next frame's wait behind it: on the H200
                    // (2026-11-28) that put the shipped model's bound at
                    // 14.2 ms for 8.8 ms of work, so frames were planned two
                    // refreshes ahead and held again. A queue without a
                    // hold in front (a busy machine) stays in.
                    pipeline.observe(
                        t.ready_ns
                            .saturating_sub(t.submit_ns)
                            .saturating_sub(t.waited_ns)
                            .saturating_sub(t.behind_hold_ns),
                    );
                    self.schedule.publish_pipeline(&pipeline);
                    self.stats.record_vs_prediction(ShownFrame {
                        owner: t.owner,
                        submit_ns: t.submit_ns,
                        predicted_ns: t.predicted_ns,
                        shown_ns: if display_paced {
                            wake.vsync_ns
                        } else {
                            on_panel
                        },
                        period_ns: pacer.period_ns(),
                    });
                    let present_ns = now - t0;
                    // To the refresh the frame is on (stats::END_TO_END_FROM).
                    let e2e = on_panel.saturating_sub(t.start_ns);
                    self.stats.record(Stage::Present, present_ns);
                    self.stats.record(Stage::EndToEnd, e2e);
                    self.stats
                        .record(Stage::Queued, e2e.saturating_sub(t.work_ns + present_ns));
                    let n = self.stats.presented.fetch_add(1, Relaxed) + 1;
                    if n.is_multiple_of(RSS_EVERY) {
                        self.stats.sample_rss();
                    }
                    if n.is_multiple_of(10) {
                        // Not a snapshot: that copies the timelines too.
                        progress.status(&format!(
                            "{n} presented, {} dropped, {} rejected, e2e p50 {:.1} ms",
                            self.stats.dropped_queued.load(Relaxed) + self.slot.dropped(),
                            self.stats.rejected_total(),
                            self.stats.histogram(Stage::EndToEnd).quantile_ns(0.5) as f64 / 1e6
                        ));
                    }
                }
                Presented::Skipped => {
                    self.stats.skipped.fetch_add(1, Relaxed);
                }
            }
            last = Some(t.item);
        }
        progress.finish();
        self.stop_stages();
        Ok(self.stats.snapshot())
    }

    /// Nothing was due at the wake: waits until `deadline_ns` (the latest
    /// take that can still make the refresh, [`PresentPacer::latest_take_ns`])
    /// for a frame that is ready just after it, which would otherwise miss
    /// this refresh and be replaced at the next (the timelines of lavapipe
    /// runs showed such frames ready 0.4–0.6 ms after the wake, 2 ms before
    /// the refresh). The frame and how long it was waited for.
    fn late_latch(
        &self,
        deadline_ns: u64,
        due: &impl Fn(&Timed<PanelFrame>) -> bool,
    ) -> Option<(Timed<PanelFrame>, u64)> {
        let t0 = self.clock.now_ns();
        loop {
            let now = self.clock.now_ns();
            if now >= deadline_ns {
                return None;
            }
            self.clock
                .sleep_until_ns((now + LATE_LATCH_POLL_NS).min(deadline_ns));
            if let Some(t) = self.take_due(due) {
                return Some((t, self.clock.now_ns().saturating_sub(t0)));
            }
        }
    }

    /// The newest frame due in the slot; the older ones it replaces go
    /// into the timelines as replaced by it.
    fn take_due(&self, due: impl Fn(&Timed<PanelFrame>) -> bool) -> Option<Timed<PanelFrame>> {
        let (taken, dropped) = self.slot.take_due_dropping(due);
        if let Some(t) = &taken {
            let now = self.clock.now_ns();
            for old in dropped {
                self.stats
                    .record_timeline(&old.marks(), Outcome::Replaced, now, None, Some(t.id));
            }
        }
        taken
    }
}
