//! The preprocess stage's engine, for any number of views: on the host,
//! or on the sink's device with its switch to the host when the device
//! fails. Apart from the service's threads so that what a stage does to a
//! frame reads on its own.

use std::sync::Arc;
use std::sync::atomic::Ordering::Relaxed;

use super::stages::{FallbackFactory, fallback_preprocessor};
use super::views::HostEngine;
use super::{PreprocessStage, Stage, Stats};
use crate::compose::{LayerSet, ViewRegion};
use crate::pipeline::device_frames::DeviceFrames;
use crate::pipeline::frame::ViewFrame;
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
    },
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
        frames_in: Vec<ViewFrame>,
        stats: &Stats,
    ) -> Option<Processed> {
        if let Engine::Device {
            frames,
            fallback,
            panel,
            views,
        } = self
        {
            match frames.run(id, &frames_in) {
                Ok((frame, traffic)) => {
                    if frames.last_blended() {
                        stats.frames_with_layers.fetch_add(1, Relaxed);
                    }
                    let single = frames.views() == 1;
                    for (v, ns) in frames.last_view_ns().iter().enumerate() {
                        match (ns, single) {
                            (Some(ns), true) => stats.record(Stage::PreprocessGpu, *ns),
                            (Some(ns), false) => stats.record_view(v, *ns),
                            (None, _) => {}
                        }
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
