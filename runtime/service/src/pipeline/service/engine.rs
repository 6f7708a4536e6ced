//! The preprocess stage's engine, for any number of views: on the host,
//! or on the sink's device with its switch to the host when the device
//! fails. Apart from the service's threads so that what a stage does to a
//! frame reads on its own.

use std::sync::Arc;
use std::sync::atomic::Ordering::Relaxed;

use super::stages::{FallbackFactory, fallback_preprocessor};
use super::views::HostViews;
use super::{PreprocessStage, Stage, StageNotes, Stats};
use crate::compose::{LayerSet, ViewRegion};
use crate::pipeline::device_frames::DeviceFrames;
use crate::pipeline::frame::{ViewContent, ViewFrame};
use crate::pipeline::ladder::{
    BudgetReport, Controller, Ladder, Selection, frame_budget_ns, pareto_front,
};
use crate::pipeline::pacing::{Clock, DisplaySchedule, Estimate, PresentGate, Slot};
use crate::present::DeviceDisplayFrame;
use nedrt_core::Image;

/// The preprocess stage's engine.
pub(super) enum Engine {
    Host(HostViews),
    /// Every view on the sink's device, one submission a frame; each
    /// view's fallback runs on the host if the device fails.
    Device {
        frames: Box<DeviceFrames>,
        fallback: Vec<Option<FallbackFactory>>,
        /// What the host engine needs to take over: the panel and each
        /// view's region and layers.
        panel: (usize, usize),
        views: Vec<(ViewRegion, Arc<LayerSet>)>,
        /// Keeps this work from queueing in front of a present.
        gate: DeviceGate,
    },
}

/// The device's submissions and the present loop's: the gate they share,
/// the clock, and how long a frame's device work takes (its submission to
/// its fence, learnt).
pub(super) struct DeviceGate {
    pub(super) gate: Arc<PresentGate>,
    pub(super) clock: Arc<dyn Clock>,
    pub(super) work: Estimate,
}

impl DeviceGate {
    /// Waits, where the gate says so, until the next present is
    /// submitted (at most two periods: a loop that has ended or stalled
    /// never holds the work up for long).
    /// A frame predicted for the refresh that present is for is what the
    /// present waits for: it is never held.
    /// Returns how long it waited.
    fn yield_to_present(&self, predicted_ns: u64, stats: &Stats) -> u64 {
        let t0 = self.clock.now_ns();
        let Slot::AfterPresent(vsync) = self.gate.slot(t0, self.work.bound_ns(), predicted_ns)
        else {
            return 0;
        };
        let _span = tracing::info_span!("yield to present").entered();
        self.gate.wait(
            vsync,
            std::time::Duration::from_nanos(2 * self.gate.period_ns()),
        );
        let waited = self.clock.now_ns().saturating_sub(t0);
        stats.record(Stage::YieldToPresent, waited);
        waited
    }
}

/// What the preprocess stage hands the encode stage.
pub(super) enum Processed {
    Host(Image),
    Device(DeviceDisplayFrame),
}

/// The frame budget of a preprocess stage with a ladder: the controller,
/// the selection the views' engines follow, and the schedule the budget
/// comes from (pipeline::ladder).
pub(super) struct Budget {
    controller: Controller,
    /// The engines' level of each of the controller's (the Pareto front's).
    kept: Vec<usize>,
    /// The levels dropped from the front, for the report.
    dropped: Vec<String>,
    selection: Selection,
    schedule: Arc<DisplaySchedule>,
}

impl Budget {
    /// How long the start-up measurement may take (a software adapter at
    /// the real panel takes seconds a frame for the higher levels); the
    /// levels left then are placed, not run.
    const MEASURE_FOR_NS: u64 = 5_000_000_000;

    /// Runs each level of `ladder` whose time is not known on `engine`
    /// (a grey frame of each view's size: the levels' work does not
    /// depend on the picture) and starts the controller.
    pub(super) fn start(
        mut ladder: Ladder,
        engine: &mut Engine,
        regions: &[ViewRegion],
        schedule: Arc<DisplaySchedule>,
        clock: &dyn Clock,
    ) -> Self {
        let grey: Vec<Arc<Image>> = regions
            .iter()
            .map(|r| {
                let planes = vec![vec![0.5; r.width * r.height]; 3];
                Arc::new(Image::from_planes(r.width, r.height, planes))
            })
            .collect();
        let frames = |generation: u64| -> Vec<ViewFrame> {
            grey.iter()
                .map(|im| ViewFrame {
                    generation,
                    content: ViewContent::Planar(im.clone()),
                })
                .collect()
        };
        // Generations no client frame reaches (they count from 1, one a
        // submission): the first real frame runs.
        let mut generation = u64::MAX / 2;
        let scratch = Stats::default();
        let started = clock.now_ns();
        let mut below_ns = 0;
        for (j, level) in ladder.levels.iter_mut().enumerate() {
            if level.reference_ns > 0 {
                below_ns = level.reference_ns;
                continue;
            }
            // A level not measured (the measuring's time spent, or a run
            // that failed) is placed above the one below it: twice its time.
            let placed = (2 * below_ns).max(1_000_000);
            let spent = clock.now_ns().saturating_sub(started);
            if spent > Self::MEASURE_FOR_NS {
                level.reference_ns = placed;
                below_ns = placed;
                tracing::info!(
                    "frame budget: level {} not measured ({:.1} s spent measuring): placed at {:.3} ms",
                    level.name,
                    spent as f64 / 1e9,
                    placed as f64 / 1e6
                );
                continue;
            }
            ladder.selection.set(j);
            let mut times = Vec::new();
            // The first run pays what is left of the level's one-time
            // costs; the fastest of up to three more is its time (a busy
            // machine only adds), as many as fit in half a second; a first
            // run over a second is its time (no budget takes it anyway).
            for run in 0..4 {
                generation += 1;
                let t0 = clock.now_ns();
                let ran = engine.run_unpaced(generation, frames(generation), &scratch);
                let ns = clock.now_ns().saturating_sub(t0);
                if !ran {
                    break;
                }
                if run > 0 || ns > 1_000_000_000 {
                    times.push(ns);
                }
                if ns > 1_000_000_000 || times.iter().sum::<u64>() > 500_000_000 {
                    break;
                }
            }
            level.reference_ns = times
                .iter()
                .copied()
                .min()
                .filter(|&ns| ns > 0)
                .unwrap_or(placed);
            below_ns = level.reference_ns;
            tracing::info!(
                "frame budget: level {} takes {:.3} ms at start-up",
                level.name,
                level.reference_ns as f64 / 1e6
            );
        }
        // Measured: a level no better than a faster one is left out.
        let kept = pareto_front(&ladder.levels);
        let dropped: Vec<String> = (0..ladder.levels.len())
            .filter(|j| !kept.contains(j))
            .map(|j| ladder.levels[j].name.clone())
            .collect();
        if !dropped.is_empty() {
            tracing::info!(
                "frame budget: {} no better than a faster level, left out",
                dropped.join(", ")
            );
        }
        let levels = kept.iter().map(|&j| ladder.levels[j].clone()).collect();
        let budget = frame_budget_ns(schedule.period_ns(), schedule.present_lead_ns());
        let controller = Controller::new(levels, budget);
        ladder.selection.set(kept[controller.level()]);
        Self {
            controller,
            kept,
            dropped,
            selection: ladder.selection,
            schedule,
        }
    }

    /// Before a frame: the budget as the present's lead now leaves it, and
    /// the level the frame runs.
    pub(super) fn select(&mut self) {
        self.controller.set_budget_ns(frame_budget_ns(
            self.schedule.period_ns(),
            self.schedule.present_lead_ns(),
        ));
        self.selection.set(self.kept[self.controller.level()]);
    }

    /// After a frame: its own time (the stage's, less any hold for a
    /// present), learnt; the report brought up to date.
    pub(super) fn observe(&mut self, own_ns: u64, stats: &Stats) {
        self.controller.observe(own_ns);
        let mut report = stats.frame_budget.lock().unwrap_or_else(|p| p.into_inner());
        match report.as_mut() {
            Some(r) => r.update(&self.controller),
            None => {
                let mut r = BudgetReport::of(&self.controller);
                r.dropped = self.dropped.clone();
                *report = Some(r);
            }
        }
    }

    /// The level the frame runs, as the report's levels number it.
    pub(super) fn level_index(&self) -> u8 {
        u8::try_from(self.controller.level()).unwrap_or(u8::MAX)
    }

    pub(super) fn level_name(&self) -> &str {
        &self.controller.levels()[self.controller.level()].name
    }
}

impl Engine {
    /// Runs `frames` with no pacing and no counts kept (the ladder's
    /// start-up measurement); whether it ran.
    fn run_unpaced(&mut self, generation: u64, frames: Vec<ViewFrame>, scratch: &Stats) -> bool {
        match self {
            Engine::Host(host) => host.run(&frames, scratch).is_some(),
            Engine::Device { frames: device, .. } => device.run(generation, &frames).is_ok(),
        }
    }

    pub(super) fn describe(&self) -> String {
        match self {
            Engine::Host(h) => h.describe(),
            Engine::Device { frames, .. } => frames.describe(),
        }
    }

    pub(super) fn run(
        &mut self,
        id: u64,
        predicted_ns: u64,
        frames_in: Vec<ViewFrame>,
        stats: &Stats,
        notes: &mut StageNotes,
    ) -> Option<Processed> {
        if let Engine::Device {
            frames,
            fallback,
            panel,
            views,
            gate,
        } = self
        {
            notes.waited_ns += gate.yield_to_present(predicted_ns, stats);
            let t0 = gate.clock.now_ns();
            let ran = frames.run(id, &frames_in);
            gate.work.observe(gate.clock.now_ns().saturating_sub(t0));
            match ran {
                Ok((frame, traffic)) => {
                    if frames.last_blended() {
                        stats.frames_with_layers.fetch_add(1, Relaxed);
                    }
                    let single = frames.views() == 1;
                    for (v, ns) in frames.last_view_ns().iter().enumerate() {
                        let Some(ns) = *ns else { continue };
                        // The frame's device time: every view's summed.
                        notes.gpu_ns = Some(notes.gpu_ns.unwrap_or(0) + ns);
                        if single {
                            stats.record(Stage::PreprocessGpu, ns);
                        } else {
                            stats.record_view(v, ns);
                        }
                    }
                    stats.record(Stage::PreprocessRecord, frames.last_record_ns());
                    notes.record_ns = Some(frames.last_record_ns());
                    if let Some(ns) = frames.last_frame_gpu_ns() {
                        stats.record(Stage::PreprocessFrameGpu, ns);
                        notes.frame_gpu_ns = Some(ns);
                    }
                    stats.dcnn_traffic.record(traffic);
                    return Some(Processed::Device(frame));
                }
                Err(e) => {
                    // Each view's fallback gets what its device stage got:
                    // the frame (decoded and blended on the host now), or
                    // the host stage's output.
                    stats.dcnn_failures.fetch_add(1, Relaxed);
                    let failed = frames.describe();
                    let stages = views
                        .drain(..)
                        .zip(fallback.drain(..))
                        .map(|((region, layers), factory)| {
                            let stage = PreprocessStage {
                                primary: fallback_preprocessor(factory),
                                fallback: None,
                            };
                            (region, layers, stage)
                        })
                        .collect();
                    let host = HostViews::new(*panel, stages);
                    tracing::error!(
                        "{failed} failed: {e}; frames now go through the host: {}",
                        host.describe()
                    );
                    *stats.backend.lock().unwrap_or_else(|p| p.into_inner()) =
                        format!("{} (after a failure of {failed})", host.describe());
                    *stats.frame_path.lock().unwrap_or_else(|p| p.into_inner()) =
                        "host (after the device path failed)".into();
                    *self = Engine::Host(host);
                }
            }
        }
        let Engine::Host(host) = self else {
            return None;
        };
        host.run(&frames_in, stats).map(Processed::Host)
    }
}
