//! The dcnn stage's engine (host, or the sink's device with its switch to
//! the host path when the device fails) and the upload stage's host work.
//! Apart from the service's threads so that what a stage does to a frame
//! reads on its own.

use super::{HostPrep, PreprocessStage, switch_to_fallback};
use crate::compose::LayerSet;
use crate::pipeline::frame::{SubmittedFrame, decode};
use crate::pipeline::resident::{DeviceFrames, DeviceInput};
use crate::pipeline::service::FallbackFactory;
use crate::pipeline::stats::{Stage, Stats};
use crate::present::DeviceDisplayFrame;
use nedrt_core::Image;
use nedrt_core::preprocess::PreprocessError;
use std::sync::Arc;

/// The dcnn stage's engine: on the host, or on the sink's device.
pub(super) enum Engine {
    Host(PreprocessStage, Option<Arc<LayerSet>>),
    /// Each view its own engine, on the host.
    Views(Box<super::views::ViewEngines>),
    /// Each view its own stage on the sink's device, one submission for
    /// both; the host engines take over if the device fails.
    DeviceViews {
        views: Box<crate::pipeline::device_views::DeviceViews>,
        host: Option<Box<super::views::ViewEngines>>,
    },
    Device {
        frames: Box<DeviceFrames>,
        fallback: Option<FallbackFactory>,
        layers: Option<Arc<LayerSet>>,
    },
}

/// What the dcnn stage hands the encode stage.
pub(super) enum Processed {
    Host(Image),
    Device(DeviceDisplayFrame),
}

/// A client's frame decoded to planes with the view's quad layers blended
/// over it (counted when there were any).
pub(super) fn decode_with_layers(f: &SubmittedFrame, layers: &LayerSet, stats: &Stats) -> Image {
    let mut im = decode(f);
    let snap = layers.snapshot();
    if !snap.quads.is_empty() {
        match crate::compose::blend(&mut im, &snap.quads) {
            Ok(()) => {
                stats
                    .frames_with_layers
                    .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            }
            // The set holds at most MAX_QUADS: a bug, not the client's.
            Err(e) => tracing::error!("blending frame {}: {e}", f.id),
        }
    }
    im
}

/// A frame from the upload stage as a host image: a frame uploaded as it
/// came is decoded here, with its layers (the device would have blended them).
fn host_image(input: DeviceInput, layers: Option<&LayerSet>, stats: &Stats) -> Image {
    match (input, layers) {
        (DeviceInput::Client(f), Some(layers)) => decode_with_layers(&f, layers, stats),
        (DeviceInput::Client(f), None) => decode(&f),
        (DeviceInput::Planar(im), _) => im,
        // Only the views' engine takes these.
        (DeviceInput::Views(_), _) => Image::zeros(0, 0, 3),
    }
}

impl Engine {
    pub(super) fn describe(&self) -> String {
        match self {
            Engine::Host(d, _) => d.primary.describe(),
            Engine::Views(v) => v.describe(),
            Engine::DeviceViews { views, .. } => views.describe(),
            Engine::Device { frames, .. } => frames.describe(),
        }
    }

    /// The view's layers, for frames that reach this stage undecoded.
    pub(super) fn attach_layers(&mut self, set: Arc<LayerSet>) {
        match self {
            Engine::Host(_, layers) => *layers = Some(set),
            // Each view's layers are blended in the upload stage.
            Engine::Views(_) | Engine::DeviceViews { .. } => {}
            Engine::Device { frames, layers, .. } => {
                frames.attach_layers(set.clone());
                *layers = Some(set);
            }
        }
    }

    pub(super) fn run(&mut self, id: u64, input: DeviceInput, stats: &Stats) -> Option<Processed> {
        if let Engine::Device {
            frames,
            fallback,
            layers,
        } = self
        {
            match frames.run(id, &input) {
                Ok((frame, traffic)) => {
                    if frames.last_blended() {
                        stats
                            .frames_with_layers
                            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    }
                    if let Some(ns) = frames.last_gpu_ns() {
                        stats.record(Stage::PreprocessGpu, ns);
                    }
                    stats.dcnn_traffic.record(traffic);
                    return Some(Processed::Device(frame));
                }
                Err(e) => {
                    let reason = format!("{e}; frames now go through the host");
                    let next =
                        switch_to_fallback(fallback.take(), &frames.describe(), &reason, stats);
                    *stats.frame_path.lock().unwrap_or_else(|p| p.into_inner()) =
                        "host (after the device path failed)".into();
                    *self = Engine::Host(
                        PreprocessStage {
                            primary: next,
                            fallback: None,
                        },
                        layers.take(),
                    );
                }
            }
        }
        if let Engine::DeviceViews { views, host } = self {
            let DeviceInput::Views(images) = &input else {
                tracing::error!("frame {id} is not of views");
                return None;
            };
            match views.run(id, images) {
                Ok((frame, traffic)) => {
                    for (v, ns) in views.last_view_ns().iter().enumerate() {
                        if let Some(ns) = ns {
                            stats.record_view(v, *ns);
                        }
                    }
                    stats.dcnn_traffic.record(traffic);
                    return Some(Processed::Device(frame));
                }
                Err(e) => {
                    stats
                        .dcnn_failures
                        .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    *stats.frame_path.lock().unwrap_or_else(|p| p.into_inner()) =
                        "host (after the device path of the views failed)".into();
                    match host.take() {
                        Some(h) => {
                            tracing::error!(
                                "{} failed: {e}; the views now run on the host: {}",
                                views.describe(),
                                h.describe()
                            );
                            *stats.backend.lock().unwrap_or_else(|p| p.into_inner()) = format!(
                                "{} (after a failure of the views on the device)",
                                h.describe()
                            );
                            *self = Engine::Views(h);
                        }
                        None => {
                            tracing::error!("{} failed: {e}; no host engines", views.describe());
                            stats
                                .failed
                                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                            return None;
                        }
                    }
                }
            }
        }
        if let Engine::Views(views) = self {
            let DeviceInput::Views(images) = input else {
                tracing::error!("frame {id} is not of views");
                return None;
            };
            return views.run(&images, stats).map(Processed::Host);
        }
        let Engine::Host(dcnn, layers) = self else {
            return None;
        };
        let frame = host_image(input, layers.as_deref(), stats);
        dcnn.run(&frame, stats).map(Processed::Host)
    }
}

/// The upload stage's work on a frame.
pub(super) type UploadWork =
    Box<dyn FnMut(super::Submission, &Stats) -> Option<DeviceInput> + Send>;

/// The upload stage of the device path with a host stage: as the host
/// path treats its engine, a frame the stage refuses is `failed`, and an
/// engine failure is counted and switches the stage off for good (frames
/// then go up as decoded).
pub(super) fn host_stage(
    mut prep: HostPrep,
    layers: Arc<LayerSet>,
) -> impl FnMut(SubmittedFrame, &Stats) -> Option<DeviceInput> + Send {
    use std::sync::atomic::Ordering::Relaxed;
    let mut failed_over = false;
    move |f, stats| {
        let decoded = decode_with_layers(&f, &layers, stats);
        if failed_over {
            return Some(DeviceInput::Planar(decoded));
        }
        match (prep.run)(&decoded) {
            Ok(im) => Some(DeviceInput::Planar(im)),
            Err(PreprocessError::Frame(e)) => {
                tracing::error!("{} refused frame {}: {e}", prep.name, f.id);
                stats.failed.fetch_add(1, Relaxed);
                None
            }
            Err(e) => {
                tracing::error!(
                    "{} failed: {e}; frames now go to the device without it",
                    prep.name
                );
                stats.dcnn_failures.fetch_add(1, Relaxed);
                *stats.frame_path.lock().unwrap_or_else(|p| p.into_inner()) =
                    format!("device, without its host stage ({} failed)", prep.name);
                failed_over = true;
                Some(DeviceInput::Planar(decoded))
            }
        }
    }
}
