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

/// An encoded frame that stays on the GPU: the panel's codes in a buffer
/// on the device of the sink that presents it (the resident path).
#[derive(Debug, Clone)]
pub struct DeviceDisplayFrame {
    pub id: u64,
    pub width: usize,
    pub height: usize,
    /// RGBA8 codes, one texel per pixel (red in the low byte), rows
    /// `row_texels` apart (the 256-byte pitch a texture copy needs). Shared:
    /// the encoder reuses a buffer once no frame holds it.
    pub codes: std::sync::Arc<wgpu::Buffer>,
    pub row_texels: u32,
}

/// A frame for the panel, on the host or on the sink's device.
#[derive(Debug, Clone)]
pub enum PanelFrame {
    Host(DisplayFrame),
    Device(DeviceDisplayFrame),
}

/// A borrowed [`PanelFrame`]: what a sink draws.
#[derive(Debug, Clone, Copy)]
pub enum PanelCodes<'a> {
    Host(&'a DisplayFrame),
    Device(&'a DeviceDisplayFrame),
}

impl PanelFrame {
    pub fn codes(&self) -> PanelCodes<'_> {
        match self {
            PanelFrame::Host(f) => PanelCodes::Host(f),
            PanelFrame::Device(f) => PanelCodes::Device(f),
        }
    }

    pub fn id(&self) -> u64 {
        match self {
            PanelFrame::Host(f) => f.id,
            PanelFrame::Device(f) => f.id,
        }
    }
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
    /// The device this sink presents from, where it can take frames that
    /// stay there ([`Sink::present_device`]); `None` for a sink that needs
    /// the frame's bytes on the host (the recorder).
    fn shared_device(&self) -> Option<(wgpu::Device, wgpu::Queue)> {
        None
    }
    /// Presents a frame encoded on [`Sink::shared_device`], without a
    /// copy through the host.
    fn present_device(&mut self, frame: &DeviceDisplayFrame) -> Result<Presented, PresentError> {
        Err(PresentError::Sink {
            sink: "present",
            reason: format!(
                "{} takes frames from the host only (frame {})",
                self.describe(),
                frame.id
            ),
        })
    }
    /// Either kind of frame.
    fn present_frame(&mut self, frame: &PanelFrame) -> Result<Presented, PresentError> {
        match frame {
            PanelFrame::Host(f) => self.present(f),
            PanelFrame::Device(f) => self.present_device(f),
        }
    }
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
