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
    /// Where the codes live, so that any sink can reach them.
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
}

impl DeviceDisplayFrame {
    /// The codes brought to the host (one read-back): for a sink that
    /// writes bytes (the recorder), and for tests.
    pub fn to_host(&self) -> Result<DisplayFrame, PresentError> {
        let (w, h) = (self.width, self.height);
        let row_bytes = 4 * self.row_texels as u64;
        let bytes = row_bytes * h as u64;
        if (self.row_texels as usize) < w
            || self.codes.size() < bytes
            || !self.codes.usage().contains(wgpu::BufferUsages::COPY_SRC)
        {
            return Err(PresentError::frame(
                "device frame",
                format!(
                    "frame {}: {} bytes of codes ({:?}) at {} texels a row for {w}×{h}",
                    self.id,
                    self.codes.size(),
                    self.codes.usage(),
                    self.row_texels
                ),
            ));
        }
        let stage = "device frame read-back";
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("panel codes read-back"),
            size: bytes,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("panel codes read-back"),
            });
        encoder.copy_buffer_to_buffer(&self.codes, 0, &staging, 0, bytes);
        self.queue.submit([encoder.finish()]);
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(PresentError::Gpu {
                stage,
                source: e.into(),
            });
        }
        nedrt_gpu::map_and_wait(&self.device, &staging).map_err(PresentError::gpu(stage))?;
        let rgba8 = nedrt_gpu::read_mapped(&staging, |b| {
            b.chunks_exact(row_bytes as usize)
                .flat_map(|row| &row[..4 * w])
                .copied()
                .collect()
        })
        .map_err(PresentError::gpu(stage))?;
        Ok(DisplayFrame {
            id: self.id,
            width: w,
            height: h,
            rgba8,
        })
    }

    /// What [`DeviceDisplayFrame::to_host`] moves.
    pub fn read_back_traffic(&self) -> nedrt_core::preprocess::HostTraffic {
        nedrt_core::preprocess::HostTraffic {
            to_host_bytes: 4 * self.row_texels as u64 * self.height as u64,
            read_backs: 1,
            ..Default::default()
        }
    }
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

/// Errors of the present stage: the encode kernel, the device frames, the
/// sinks. Each names its `stage` ("recorder sink", "GPU encode", …).
#[derive(Debug, thiserror::Error)]
pub enum PresentError {
    /// The sink could not be opened: no display, no surface, no folder.
    #[error("{stage}: {reason}")]
    Open { stage: &'static str, reason: String },
    /// A frame the stage cannot take: its size, its buffer's length, or
    /// codes the sink has no way to reach.
    #[error("{stage}: {reason}")]
    Frame { stage: &'static str, reason: String },
    /// A kernel or render pipeline failed to build (shader validation).
    #[error("{stage}: building {what}: {reason}")]
    Kernel {
        stage: &'static str,
        what: &'static str,
        reason: String,
    },
    /// The GPU failed under the stage: device lost, a wait or a read-back.
    #[error("{stage}: {source}")]
    Gpu {
        stage: &'static str,
        #[source]
        source: nedrt_gpu::GpuError,
    },
    /// Writing a presented frame failed (the recorder's disk), or the
    /// writer is gone.
    #[error("{stage}: {reason}")]
    Write { stage: &'static str, reason: String },
}

impl PresentError {
    pub fn open(stage: &'static str, reason: impl std::fmt::Display) -> Self {
        PresentError::Open {
            stage,
            reason: reason.to_string(),
        }
    }
    pub fn frame(stage: &'static str, reason: impl std::fmt::Display) -> Self {
        PresentError::Frame {
            stage,
            reason: reason.to_string(),
        }
    }
    pub fn kernel(stage: &'static str, what: &'static str, reason: impl std::fmt::Display) -> Self {
        PresentError::Kernel {
            stage,
            what,
            reason: reason.to_string(),
        }
    }
    /// For `map_err`: the GPU failed under `stage`.
    pub fn gpu(stage: &'static str) -> impl Fn(nedrt_gpu::GpuError) -> Self {
        move |source| PresentError::Gpu { stage, source }
    }
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
    /// Presents the panel's codes, on the host or on [`Sink::shared_device`]
    /// (then without a copy through the host).
    fn present(&mut self, frame: PanelCodes<'_>) -> Result<Presented, PresentError>;
    /// The GPU panel this sink draws with (window, headless): where it can
    /// take frames that stay on the device, and what its uploads cost.
    /// `None` for a sink that needs the codes' bytes on the host.
    fn renderer(&self) -> Option<&gpu::PanelRenderer> {
        None
    }
    /// The device this sink presents from, where frames can stay.
    fn shared_device(&self) -> Option<(wgpu::Device, wgpu::Queue)> {
        self.renderer()
            .map(|r| (r.device().clone(), r.queue().clone()))
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
        self.renderer()
            .map(|r| r.last_traffic())
            .unwrap_or_default()
    }
    /// Frames `present` took that the sink then failed to deliver (known
    /// after `finish`): the recorder's queue when its disk filled.
    fn lost_frames(&self) -> u64 {
        0
    }
}
