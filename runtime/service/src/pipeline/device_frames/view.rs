//! One view on the device: its buffers (the client's bytes, the frame's
//! planes, the stage's output), its unpack, layers, stage and encoder.

use std::sync::Arc;

use super::{DeviceView, STAGE, err};
use crate::compose::gpu::LayerBlender;
use crate::compose::{LayerSet, ViewRegion};
use crate::pipeline::frame::{PixelFormat, ViewContent};
use crate::present::PresentError;
use crate::present::encode_gpu::{CodesTarget, PanelEncoder, workgroups};
use crate::present::transfer::Transfer;
use nedrt_core::preprocess::HostTraffic;
use nedrt_gpu::DeviceStage;
use wgpu::util::DeviceExt;

/// What every view of a panel is prepared with.
pub(super) struct Shared<'a> {
    pub device: &'a wgpu::Device,
    pub queue: &'a wgpu::Queue,
    pub unpack: &'a wgpu::ComputePipeline,
    /// The decode tables: code/255, and sRGB.
    pub luts: &'a [wgpu::Buffer; 2],
    pub panel: (usize, usize),
    pub row_texels: u32,
    pub transfer: &'a Transfer,
}

/// One view's buffers and work on the device.
#[derive(Debug)]
pub(super) struct ViewOnDevice {
    pub(super) region: ViewRegion,
    /// The client's RGBA8 frame as it came.
    pub(super) rgba: wgpu::Buffer,
    /// Three f32 planes: the frame, and the stage's output.
    pub(super) frame: wgpu::Buffer,
    pub(super) display: wgpu::Buffer,
    /// The unpack's bind groups for code/255 and the sRGB decode.
    pub(super) unpack_linear: wgpu::BindGroup,
    pub(super) unpack_srgb: wgpu::BindGroup,
    pub(super) stage: Option<Box<dyn DeviceStage>>,
    /// Writes the view's codes into its region of the panel's.
    pub(super) encoder: PanelEncoder,
    /// The view's quad layers, blended after the unpack of a frame that
    /// came up as it was sent (planes from the host had them blended there).
    pub(super) layers: Option<Arc<LayerSet>>,
    pub(super) blender: LayerBlender,
    /// The frame generation whose display planes are on the device (0: none).
    pub(super) generation: u64,
    /// Whether that frame passed the stage unchanged
    /// ([`DeviceStage::passes_through`]): its planes are then shown.
    pub(super) passed: bool,
}

impl ViewOnDevice {
    /// Makes the view's stage ready for its size and buffers before the
    /// first frame ([`DeviceStage::warm_up`]). A failure is logged and
    /// left for the first frame to meet, where the fallback takes over as
    /// for any frame that fails.
    pub(super) fn warm_up(&mut self, device: &wgpu::Device, v: usize) {
        let started = std::time::Instant::now();
        let (w, h) = (self.region.width, self.region.height);
        let Some(stage) = &mut self.stage else {
            return;
        };
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let warmed = stage.warm_up(&self.frame, &self.display, w, h);
        // Popped on every path: a scope left open would catch later errors.
        let validation = pollster::block_on(scope.pop());
        let took = started.elapsed();
        // The stage's own error first: it is the cause of a validation one.
        let failed =
            (warmed.err().map(|e| e.to_string())).or_else(|| validation.map(|e| e.to_string()));
        match failed {
            None => tracing::info!(
                "view {v}: {} made ready for {w}×{h} in {:.1} ms",
                stage.describe(),
                took.as_secs_f64() * 1e3
            ),
            Some(e) => tracing::warn!(
                "view {v}: {} could not be made ready for {w}×{h} ({e}); its first frame will say",
                stage.describe()
            ),
        }
    }

    /// View `v` of the panel, its buffers made and its encoder aimed at
    /// its region of the panel's codes.
    pub(super) fn new(
        shared: &Shared<'_>,
        v: usize,
        DeviceView { region, stage }: DeviceView,
    ) -> Result<Self, PresentError> {
        let Shared {
            device,
            queue,
            unpack,
            luts,
            panel: (width, height),
            row_texels: row,
            transfer,
        } = *shared;
        let h32 = height as u32;
        let binding = device.limits().max_storage_buffer_binding_size;
        let pixels = region.width * region.height;
        let p32 = match u32::try_from(3 * pixels) {
            Ok(_) if pixels > 0 && region.fits((width, height)) => pixels as u32,
            _ => {
                return Err(err(format!(
                    "view {v}: a {}×{} view at ({}, {}) on a {width}×{height} panel",
                    region.width, region.height, region.x, region.y
                )));
            }
        };
        let plane_bytes = 3 * 4 * pixels as u64;
        if plane_bytes > binding {
            return Err(err(format!(
                "view {v}: a {}×{} frame's planes need {:.0} MiB in one binding; the \
                 adapter binds at most {:.0} MiB",
                region.width,
                region.height,
                plane_bytes as f64 / 1048576.0,
                binding as f64 / 1048576.0
            )));
        }
        let storage = |label, size: u64| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_DST
                    | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        };
        let rgba = storage("client frame", 4 * pixels as u64);
        let frame = storage("frame planes", plane_bytes);
        let display = storage("display planes", plane_bytes);
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("frame_unpack"),
            contents: bytemuck::cast_slice(&[p32, 0, 0, 0]),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let group = |lut: &wgpu::Buffer| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("frame_unpack"),
                layout: &unpack.get_bind_group_layout(0),
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: uniform.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: rgba.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: lut.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: frame.as_entire_binding(),
                    },
                ],
            })
        };
        let target = CodesTarget {
            row_texels: row,
            base_texel: (region.y as u32) * row + region.x as u32,
            rows: h32,
        };
        let encoder = PanelEncoder::new_into(
            device,
            queue,
            (region.width as u32, region.height as u32),
            p32,
            transfer,
            target,
        )?;
        Ok(Self {
            region,
            unpack_linear: group(&luts[0]),
            unpack_srgb: group(&luts[1]),
            rgba,
            frame,
            display,
            stage,
            encoder,
            layers: None,
            blender: LayerBlender::new(device, queue).map_err(PresentError::gpu(STAGE))?,
            generation: 0,
            passed: false,
        })
    }

    pub(super) fn describe(&self) -> String {
        match &self.stage {
            Some(s) => s.describe(),
            None => "none (the frame as it comes, clamped to [0, 1])".into(),
        }
    }

    /// What the encoder reads: the stage's output, or the frame itself.
    pub(super) fn shown(&self) -> &wgpu::Buffer {
        if self.stage.is_some() {
            &self.display
        } else {
            &self.frame
        }
    }

    /// Stages `content` in `belt` and records its copy to the view, its
    /// unpack (a frame as it came) and its quad layers; the bytes sent, the
    /// layers' traffic and whether any were blended.
    pub(super) fn upload(
        &mut self,
        belt: &mut wgpu::util::StagingBelt,
        unpack: &wgpu::ComputePipeline,
        encoder: &mut wgpu::CommandEncoder,
        content: &ViewContent,
    ) -> Result<(usize, HostTraffic, bool), PresentError> {
        let view = self;
        let f = match content {
            ViewContent::Planar(im) => {
                let bytes = bytemuck::cast_slice(im.data());
                stage_copy(belt, encoder, &view.frame, bytes)?;
                return Ok((bytes.len(), HostTraffic::default(), false));
            }
            ViewContent::Client(f) => f,
        };
        match f.format {
            PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb => {
                stage_copy(belt, encoder, &view.rgba, &f.payload)?;
                let group = if f.format == PixelFormat::Rgba8Srgb {
                    &view.unpack_srgb
                } else {
                    &view.unpack_linear
                };
                let [x, y] = workgroups((f.width * f.height) as u32);
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("frame_unpack"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(unpack);
                pass.set_bind_group(0, group, &[]);
                pass.dispatch_workgroups(x, y, 1);
            }
            // Planar little-endian f32 is the planes' own layout.
            PixelFormat::Rgb32fPlanar => stage_copy(belt, encoder, &view.frame, &f.payload)?,
        }
        let Some(layers) = &view.layers else {
            return Ok((f.payload.len(), HostTraffic::default(), false));
        };
        let snap = layers.snapshot();
        let r = view.region;
        let dims = (r.width as u32, r.height as u32, (r.width * r.height) as u32);
        // Layers the device cannot hold are left out of the frame (and
        // said so), not a failure of the device path.
        Ok(
            match view
                .blender
                .record(encoder, &view.frame, dims, &snap.quads, snap.generation)
            {
                Ok(t) => (f.payload.len(), t, !snap.quads.is_empty()),
                Err(e) => {
                    tracing::warn!("a frame's quad layers are left out: {e}");
                    (f.payload.len(), HostTraffic::default(), false)
                }
            },
        )
    }
}

/// Copies `bytes` into `belt`'s mapped staging memory and records their
/// copy to the start of `target`. The belt's chunks are kept mapped and
/// reused frame after frame, where `Queue::write_buffer` made (and later
/// freed) a staging buffer of the frame's size for every write.
fn stage_copy(
    belt: &mut wgpu::util::StagingBelt,
    encoder: &mut wgpu::CommandEncoder,
    target: &wgpu::Buffer,
    bytes: &[u8],
) -> Result<(), PresentError> {
    let size = bytes.len() as u64;
    let fits = size <= target.size() && size.is_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
    let Some(size) = wgpu::BufferSize::new(size).filter(|_| fits) else {
        return Err(err(format!(
            "a frame of {size} bytes for a buffer of {} (whole 4-byte words, at least one)",
            target.size()
        )));
    };
    belt.write_buffer(encoder, target, 0, size)
        .copy_from_slice(bytes);
    Ok(())
}
