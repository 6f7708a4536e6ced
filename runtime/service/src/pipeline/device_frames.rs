//! The device path for any number of views: each view's frame goes to the
//! GPU once, in the form the client sent it, and the panel's codes never
//! come back. A view's 8-bit RGBA is unpacked on the device
//! (`shaders/frame_unpack.wgsl`, by the host decode's own table) into three
//! f32 planes and its quad layers are blended there; a float frame, or one
//! a host stage has already worked on (a network's Wiener), goes up as its
//! planes. Each view's device stage (its D-CNN or prefilter) writes its
//! display planes, and its encoder writes them as the panel's codes (the
//! CPU transfer's thresholds, bit for bit) into the view's region of one
//! codes buffer that the sink copies to its texture. Every view is
//! recorded into one submission per frame; a view whose frame did not
//! change is encoded again from its last display planes without running
//! its stage. One view on the whole panel is N = 1 of the same engine.
//! Everything is made once for the panel's size; a frame only writes its
//! bytes and records.

use std::sync::Arc;

use super::frame::{PixelFormat, ViewContent, ViewFrame, code_lut};
use crate::compose::gpu::LayerBlender;
use crate::compose::{LayerSet, ViewRegion};
use crate::present::encode_gpu::{CodesTarget, PanelEncoder, row_texels, workgroups};
use crate::present::transfer::Transfer;
use crate::present::{DeviceDisplayFrame, PresentError};
use nedrt_core::Image;
use nedrt_core::preprocess::HostTraffic;
use nedrt_gpu::{DeviceStage, PassTimer};
use wgpu::util::DeviceExt;

const UNPACK: &str = include_str!("../../../../shaders/frame_unpack.wgsl");

/// Codes buffers kept for reuse beyond which a warning says frames pile up
/// downstream (each holds one frame: the present slot, the frame on
/// screen, one in a channel).
const CODES_WARN: usize = 8;

const STAGE: &str = "device frames";

fn err(reason: impl std::fmt::Display) -> PresentError {
    PresentError::frame(STAGE, reason)
}

/// A view to prepare on the device: its region of the panel and its stage
/// (none: the frame as it comes, clamped).
#[derive(Debug)]
pub struct DeviceView {
    pub region: ViewRegion,
    pub stage: Option<Box<dyn DeviceStage>>,
}

/// One view's buffers and work on the device.
#[derive(Debug)]
struct ViewOnDevice {
    region: ViewRegion,
    /// The client's RGBA8 frame as it came.
    rgba: wgpu::Buffer,
    /// Three f32 planes: the frame, and the stage's output.
    frame: wgpu::Buffer,
    display: wgpu::Buffer,
    /// The unpack's bind groups for code/255 and the sRGB decode.
    unpack_linear: wgpu::BindGroup,
    unpack_srgb: wgpu::BindGroup,
    stage: Option<Box<dyn DeviceStage>>,
    /// Writes the view's codes into its region of the panel's.
    encoder: PanelEncoder,
    /// The view's quad layers, blended after the unpack of a frame that
    /// came up as it was sent (planes from the host had them blended there).
    layers: Option<Arc<LayerSet>>,
    blender: LayerBlender,
    /// The frame generation whose display planes are on the device (0: none).
    generation: u64,
}

impl ViewOnDevice {
    fn describe(&self) -> String {
        match &self.stage {
            Some(s) => s.describe(),
            None => "none (the frame as it comes, clamped to [0, 1])".into(),
        }
    }

    /// What the encoder reads: the stage's output, or the frame itself.
    fn shown(&self) -> &wgpu::Buffer {
        if self.stage.is_some() {
            &self.display
        } else {
            &self.frame
        }
    }
}

/// The device side of the frame path for one panel and its views.
#[derive(Debug)]
pub struct DeviceFrames {
    device: wgpu::Device,
    queue: wgpu::Queue,
    width: usize,
    height: usize,
    row_texels: u32,
    unpack: wgpu::ComputePipeline,
    views: Vec<ViewOnDevice>,
    /// Panel codes buffers; one is reused once no frame holds it.
    codes: Vec<Arc<wgpu::Buffer>>,
    /// A timestamp pair per view around its stage, where the device has
    /// them and a view has a stage: 16 bytes a view come back with the
    /// fence the frame waits on anyway, as the non-finite counts do.
    timer: Option<PassTimer>,
    last_view_ns: Vec<Option<u64>>,
    last_ran: Vec<bool>,
    last_blended: bool,
}

impl DeviceFrames {
    /// One view on the whole `width`×`height` panel through `stage`.
    pub fn single(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        (width, height): (usize, usize),
        transfer: &Transfer,
        stage: Option<Box<dyn DeviceStage>>,
    ) -> Result<Self, PresentError> {
        let region = ViewRegion {
            x: 0,
            y: 0,
            width,
            height,
        };
        Self::new(
            device,
            queue,
            (width, height),
            vec![DeviceView { region, stage }],
            transfer,
        )
    }

    /// Prepares a `width`×`height` panel of `views` on `device` (the
    /// sink's) with `transfer`'s codes.
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        (width, height): (usize, usize),
        views: Vec<DeviceView>,
        transfer: &Transfer,
    ) -> Result<Self, PresentError> {
        if views.is_empty() {
            return Err(err("a panel with no views"));
        }
        let (w32, h32) = match (u32::try_from(width), u32::try_from(height)) {
            (Ok(w), Ok(h)) if w > 0 && h > 0 => (w, h),
            _ => return Err(err(format!("a {width}×{height} panel"))),
        };
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("frame_unpack"),
            source: wgpu::ShaderSource::Wgsl(UNPACK.into()),
        });
        let unpack = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("frame_unpack"),
            layout: None,
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
        let lut = |srgb: bool| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("code table"),
                contents: bytemuck::cast_slice(&code_lut(srgb)),
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let luts = [lut(false), lut(true)];
        let row = row_texels(w32);
        let binding = device.limits().max_storage_buffer_binding_size;
        let mut prepared = Vec::new();
        for (v, DeviceView { region, stage }) in views.into_iter().enumerate() {
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
            prepared.push(ViewOnDevice {
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
            });
        }
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(PresentError::Gpu {
                stage: STAGE,
                source: e.into(),
            });
        }
        let n = prepared.len();
        let staged = prepared.iter().any(|v| v.stage.is_some());
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            width,
            height,
            row_texels: row,
            unpack,
            views: prepared,
            codes: Vec::new(),
            timer: staged.then(|| PassTimer::new(device, queue, n)).flatten(),
            last_view_ns: vec![None; n],
            last_ran: vec![false; n],
            last_blended: false,
        })
    }

    /// The number of views.
    pub fn views(&self) -> usize {
        self.views.len()
    }

    /// Blends `layers` into every frame of `view` uploaded as it came.
    pub fn attach_layers(&mut self, view: usize, layers: Arc<LayerSet>) {
        if let Some(v) = self.views.get_mut(view) {
            v.layers = Some(layers);
        }
    }

    /// Whether the last frame had quad layers blended on the device.
    pub fn last_blended(&self) -> bool {
        self.last_blended
    }

    /// Each view's own device time for its stage in the last frame, ns,
    /// where it ran its stage and the device has timestamp queries.
    pub fn last_view_ns(&self) -> &[Option<u64>] {
        &self.last_view_ns
    }

    /// Whether each view ran its stage in the last frame (its frame changed).
    pub fn last_ran(&self) -> &[bool] {
        &self.last_ran
    }

    /// For reports: the stage (one view), or each view's.
    pub fn describe(&self) -> String {
        if let [one] = self.views.as_slice() {
            return one.describe();
        }
        self.views
            .iter()
            .enumerate()
            .map(|(v, view)| format!("view {v} on the GPU: {}", view.describe()))
            .collect::<Vec<_>>()
            .join("; ")
    }

    /// A codes buffer no frame holds (a new one if all are held).
    fn free_codes(&mut self) -> Arc<wgpu::Buffer> {
        // get_mut succeeds only where no frame holds the buffer (an
        // acquire of the other holders' drops).
        if let Some(c) = self.codes.iter_mut().find_map(|c| {
            Arc::get_mut(c)?;
            Some(c.clone())
        }) {
            return c;
        }
        // Opaque black at creation, as the host encodes a black panel:
        // outside the views, and in a view that has had no frame yet.
        let texels = self.row_texels as usize * self.height;
        let c = Arc::new(
            self.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("panel codes"),
                    contents: &[0, 0, 0, 255].repeat(texels),
                    usage: wgpu::BufferUsages::STORAGE
                        | wgpu::BufferUsages::COPY_SRC
                        | wgpu::BufferUsages::COPY_DST,
                }),
        );
        self.codes.push(c.clone());
        if self.codes.len() == CODES_WARN {
            tracing::warn!("{CODES_WARN} encoded frames are held downstream of the GPU stage");
        }
        c
    }

    /// Uploads the views whose frame changed, records each one's unpack,
    /// layers and stage (where it changed) and every view's encode into one
    /// submission, and waits for the device (no data comes back). Returns
    /// the panel for the sink and what crossed to the device. A view's
    /// generation, once it has had a frame, never goes back to 0.
    pub fn run(
        &mut self,
        id: u64,
        frames: &[ViewFrame],
    ) -> Result<(DeviceDisplayFrame, HostTraffic), PresentError> {
        if frames.len() != self.views.len() {
            return Err(err(format!(
                "frame {id}: {} view frames for {} views",
                frames.len(),
                self.views.len()
            )));
        }
        for (v, (f, view)) in frames.iter().zip(&self.views).enumerate() {
            let r = view.region;
            let planes = match &f.content {
                ViewContent::Planar(im) => im.channels(),
                ViewContent::Client(_) => 3,
            };
            if f.generation != 0 && (f.content.size(), planes) != ((r.width, r.height), 3) {
                let (w, h) = f.content.size();
                return Err(err(format!(
                    "frame {id}: a {w}×{h} frame of {planes} planes for view {v} of {}×{}",
                    r.width, r.height
                )));
            }
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let recorded = self.record(frames);
        // Popped on every path: a scope left open would catch later errors.
        let validation = pollster::block_on(scope.pop());
        // The validation error first: it is the cause of a failed wait.
        if let Some(e) = validation {
            return Err(PresentError::Gpu {
                stage: STAGE,
                source: e.into(),
            });
        }
        let (codes, traffic) = recorded?;
        Ok((
            DeviceDisplayFrame {
                id,
                width: self.width,
                height: self.height,
                codes,
                row_texels: self.row_texels,
                device: self.device.clone(),
                queue: self.queue.clone(),
            },
            traffic,
        ))
    }

    /// Uploads `content` to `view` and records its unpack (a frame as it
    /// came) and quad layers; the bytes sent, and the layers' traffic.
    fn upload(
        queue: &wgpu::Queue,
        unpack: &wgpu::ComputePipeline,
        encoder: &mut wgpu::CommandEncoder,
        view: &mut ViewOnDevice,
        content: &ViewContent,
    ) -> (usize, HostTraffic, bool) {
        let f = match content {
            ViewContent::Planar(im) => {
                queue.write_buffer(&view.frame, 0, bytemuck::cast_slice(im.data()));
                return (
                    std::mem::size_of_val(im.data()),
                    HostTraffic::default(),
                    false,
                );
            }
            ViewContent::Client(f) => f,
        };
        match f.format {
            PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb => {
                queue.write_buffer(&view.rgba, 0, &f.payload);
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
            PixelFormat::Rgb32fPlanar => queue.write_buffer(&view.frame, 0, &f.payload),
        }
        let Some(layers) = &view.layers else {
            return (f.payload.len(), HostTraffic::default(), false);
        };
        let snap = layers.snapshot();
        let r = view.region;
        let dims = (r.width as u32, r.height as u32, (r.width * r.height) as u32);
        // Layers the device cannot hold are left out of the frame (and
        // said so), not a failure of the device path.
        match view
            .blender
            .record(encoder, &view.frame, dims, &snap.quads, snap.generation)
        {
            Ok(t) => (f.payload.len(), t, !snap.quads.is_empty()),
            Err(e) => {
                tracing::warn!("a frame's quad layers are left out: {e}");
                (f.payload.len(), HostTraffic::default(), false)
            }
        }
    }

    /// Uploads, records, submits and waits; the codes and the traffic.
    fn record(
        &mut self,
        frames: &[ViewFrame],
    ) -> Result<(Arc<wgpu::Buffer>, HostTraffic), PresentError> {
        let codes = self.free_codes();
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("device frame"),
            });
        let mut traffic = HostTraffic::default();
        self.last_blended = false;
        // Passes with no work of their own carry the stages' timestamps.
        let mark = |encoder: &mut wgpu::CommandEncoder, writes| {
            encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("stage timestamp"),
                timestamp_writes: Some(writes),
            });
        };
        // Which views were encoded into this submission (their non-finite
        // counts come back with it).
        let mut encoded = vec![false; self.views.len()];
        for (v, (f, view)) in frames.iter().zip(&mut self.views).enumerate() {
            self.last_ran[v] = false;
            // No frame for this view yet: its region stays black.
            if f.generation == 0 {
                continue;
            }
            if f.generation != view.generation {
                let (bytes, layers, blended) =
                    Self::upload(&self.queue, &self.unpack, &mut encoder, view, &f.content);
                traffic.to_device_bytes += bytes as u64;
                traffic.uploads += 1;
                traffic.add(layers);
                self.last_blended |= blended;
                let (w, h) = (view.region.width, view.region.height);
                if let Some(stage) = &mut view.stage {
                    if let Some(t) = &self.timer {
                        mark(&mut encoder, t.start(v));
                    }
                    stage
                        .record(&mut encoder, &view.frame, &view.display, w, h)
                        .map_err(PresentError::gpu(STAGE))?;
                    if let Some(t) = &self.timer {
                        mark(&mut encoder, t.end(v));
                    }
                }
                view.generation = f.generation;
                self.last_ran[v] = true;
            }
            let shown = if view.stage.is_some() {
                &view.display
            } else {
                &view.frame
            };
            view.encoder.record(&mut encoder, shown, &codes)?;
            encoded[v] = true;
        }
        let timer_bytes = self.timer.as_ref().map_or(0, |t| t.resolve(&mut encoder));
        let submission = self.queue.submit([encoder.finish()]);
        for (view, _) in self.views.iter().zip(&encoded).filter(|(_, e)| **e) {
            view.encoder.map_non_finite();
        }
        if let Some(t) = &self.timer {
            t.map();
        }
        // The fence wait the stage does anyway (its time includes the
        // device's work); it also brings the 4-byte non-finite counts and
        // the timestamps back.
        nedrt_gpu::wait_for(&self.device, submission).map_err(PresentError::gpu(STAGE))?;
        let spans = self.timer.as_ref().and_then(|t| t.spans_ns().ok());
        for (v, view) in self.views.iter().enumerate() {
            // Only a view that ran a stage wrote its timestamps.
            let staged = self.last_ran[v] && view.stage.is_some();
            self.last_view_ns[v] = spans
                .as_ref()
                .filter(|_| staged)
                .and_then(|s| s.get(v).copied());
        }
        traffic.to_host_bytes += timer_bytes;
        // Every count read (and its buffer unmapped) before any is judged.
        let mut counts = Vec::new();
        for (v, view) in self.views.iter().enumerate().filter(|(v, _)| encoded[*v]) {
            traffic.to_host_bytes += 4;
            counts.push((v, view.encoder.non_finite_pixels()));
        }
        for (v, count) in counts {
            let non_finite = count?;
            if non_finite > 0 {
                // As on the host path: an engine failure, not black pixels.
                let who = match self.views.len() {
                    1 => self.views[v].describe(),
                    _ => format!("view {v} ({})", self.views[v].describe()),
                };
                return Err(err(format!(
                    "{who}: the display image has {non_finite} pixels that are not finite"
                )));
            }
        }
        Ok((codes, traffic))
    }

    /// The display planes of `view`'s last frame, read back (tests and
    /// checks only: it waits for the GPU).
    pub fn read_display(&self, view: usize) -> Result<Image, PresentError> {
        let v = self
            .views
            .get(view)
            .ok_or_else(|| err(format!("no view {view}")))?;
        let (w, h) = (v.region.width, v.region.height);
        let bytes = 3 * 4 * (w * h) as u64;
        let readback = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("display read-back"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(v.shown(), 0, &readback, 0, bytes);
        self.queue.submit([encoder.finish()]);
        nedrt_gpu::map_and_wait(&self.device, &readback).map_err(PresentError::gpu(STAGE))?;
        let data = nedrt_gpu::read_mapped(&readback, |bytes| {
            bytemuck::cast_slice::<u8, f32>(bytes).to_vec()
        })
        .map_err(PresentError::gpu(STAGE))?;
        Ok(Image::rgb(w, h, data))
    }
}

#[cfg(test)]
#[path = "device_frames_tests.rs"]
mod tests;
