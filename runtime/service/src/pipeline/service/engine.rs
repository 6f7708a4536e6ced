//! The preprocess stage's engine, for any number of views: on the host,
//! or on the sink's device with its switch to the host when the device
//! fails. Apart from the service's threads so that what a stage does to a
//! frame reads on its own.

use std::sync::Arc;
use std::sync::atomic::Ordering::Relaxed;

use super::stages::{FallbackFactory, fallback_preprocessor};
use super::views::HostEngine;
use super::{PreprocessStage, Stage, StageNotes, Stats};
use crate::compose::{LayerSet, ViewRegion};
use crate::pipeline::device_frames::DeviceFrames;
use crate::pipeline::frame::ViewFrame;
use crate::pipeline::pacing::{Clock, Estimate, PresentGate, Slot};
use crate::present::DeviceDisplayFrame;
use nedrt_core::Image;

/// The preprocess stage's engine.
pub(super) enum Engine {
    Host(HostEngine),
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

impl Engine {
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
                    let host = HostEngine::new(*panel, stages);
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
