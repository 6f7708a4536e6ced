//! The dcnn stage's engine (host, or the sink's device with its switch to
//! the host path when the device fails) and the upload stage's host work.
//! Apart from the service's threads so that what a stage does to a frame
//! reads on its own.

use super::{DcnnStage, HostPrep, switch_to_fallback};
use crate::pipeline::frame::{SubmittedFrame, decode};
use crate::pipeline::resident::{DeviceFrames, DeviceInput};
use crate::pipeline::service::FallbackFactory;
use crate::pipeline::stats::{Stage, Stats};
use crate::present::DeviceDisplayFrame;
use nedrt_core::Image;
use nedrt_core::preprocess::PreprocessError;

/// The dcnn stage's engine: on the host, or on the sink's device.
pub(super) enum Engine {
    Host(DcnnStage),
    Device {
        frames: Box<DeviceFrames>,
        fallback: Option<FallbackFactory>,
    },
}

/// What the dcnn stage hands the encode stage.
pub(super) enum Processed {
    Host(Image),
    Device(DeviceDisplayFrame),
}

/// A frame from the upload stage as a host image.
pub(super) fn host_image(input: DeviceInput) -> Image {
    match input {
        DeviceInput::Client(f) => decode(&f),
        DeviceInput::Planar(im) => im,
    }
}

impl Engine {
    pub(super) fn describe(&self) -> String {
        match self {
            Engine::Host(d) => d.primary.describe(),
            Engine::Device { frames, .. } => frames.describe(),
        }
    }

    pub(super) fn run(&mut self, id: u64, input: DeviceInput, stats: &Stats) -> Option<Processed> {
        if let Engine::Device { frames, fallback } = self {
            match frames.run(id, &input) {
                Ok((frame, traffic)) => {
                    if let Some(ns) = frames.last_gpu_ns() {
                        stats.record(Stage::DcnnGpu, ns);
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
                    *self = Engine::Host(DcnnStage {
                        primary: next,
                        fallback: None,
                    });
                }
            }
        }
        let Engine::Host(dcnn) = self else {
            return None;
        };
        dcnn.run(&host_image(input), stats).map(Processed::Host)
    }
}

/// The upload stage's work on a frame.
pub(super) type UploadWork = Box<dyn FnMut(SubmittedFrame, &Stats) -> Option<DeviceInput> + Send>;

/// The upload stage of the device path with a host stage: as the host
/// path treats its engine, a frame the stage refuses is `failed`, and an
/// engine failure is counted and switches the stage off for good (frames
/// then go up as decoded).
pub(super) fn host_stage(
    mut prep: HostPrep,
) -> impl FnMut(SubmittedFrame, &Stats) -> Option<DeviceInput> + Send {
    use std::sync::atomic::Ordering::Relaxed;
    let mut failed_over = false;
    move |f, stats| {
        let decoded = decode(&f);
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
