//! Present: the encoded panel frame goes to a sink. One [`Sink`] trait, a
//! file per sink: [`window`] (winit + wgpu surface, vsync), [`headless`]
//! (an off-screen wgpu target of the panel's size), [`recorder`] (a PNG
//! sequence). [`transfer`] is the panel's transfer curve that the encode
//! stage applies before any sink sees the frame; [`gpu`] draws an encoded
//! frame onto a wgpu target for the window and headless sinks; [`encode_gpu`]
//! is the encode stage as a compute kernel, for frames that stay on the GPU.

pub mod encode_gpu;
pub mod gpu;
pub mod headless;
pub mod recorder;
pub mod transfer;
pub mod window;

/// An encoded frame ready for the panel.
#[derive(Debug, Clone)]
pub struct DisplayFrame {
    pub id: u64,
    pub width: usize,
    pub height: usize,
    /// Interleaved RGBA8 code values (alpha 255), row-major.
    pub rgba8: Vec<u8>,
}

/// Interleaved RGB8 from interleaved RGBA8 (alpha dropped): what a recording
/// holds, and what tests compare recordings with.
pub fn rgb8_of_rgba8(rgba8: &[u8]) -> Vec<u8> {
    rgba8
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect()
}

/// Errors of the present stage.
#[derive(Debug, thiserror::Error)]
pub enum PresentError {
    #[error("{sink} sink: {reason}")]
    Sink { sink: &'static str, reason: String },
}

/// What a sink reports back from a present.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Presented {
    /// The frame is on the target (for a window: handed to the swapchain).
    Shown,
    /// The target could not take it now (window occluded, surface
    /// outdated); the frame is counted as skipped, the next one is tried.
    Skipped,
}

/// A place frames are presented to.
pub trait Sink: std::fmt::Debug {
    /// For reports: "window 1920×1080 on 'llvmpipe'".
    fn describe(&self) -> String;
    /// Whether `present` itself waits for the display's refresh (a vsync'd
    /// swapchain); then the present loop does not sleep on its own pacer.
    fn paced_by_display(&self) -> bool {
        false
    }
    fn present(&mut self, frame: &DisplayFrame) -> Result<Presented, PresentError>;
    /// Lets the sink handle its events between frames; `false` once the
    /// sink is gone (the window was closed).
    fn poll(&mut self) -> bool {
        true
    }
    /// Flushes anything still pending (the recorder's writes).
    fn finish(&mut self) -> Result<(), PresentError> {
        Ok(())
    }
    /// Host↔device traffic of the last `present` (a GPU sink's upload).
    fn last_traffic(&self) -> nedrt_core::preprocess::HostTraffic {
        nedrt_core::preprocess::HostTraffic::default()
    }
    /// Frames `present` took that the sink then failed to deliver (known
    /// after `finish`): the recorder's queue when its disk filled.
    fn lost_frames(&self) -> u64 {
        0
    }
}
