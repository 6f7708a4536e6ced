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

use super::frame::{ViewContent, ViewFrame, code_lut};
use crate::compose::{LayerSet, ViewRegion};
use crate::present::encode_gpu::row_texels;
use crate::present::transfer::Transfer;
use crate::present::{DeviceDisplayFrame, PresentError};
use nedrt_core::Image;
use nedrt_core::preprocess::HostTraffic;
use nedrt_gpu::{DeviceStage, PassTimer};
use view::ViewOnDevice;
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
    /// The uploads' staging memory, mapped and reused frame after frame.
    belt: wgpu::util::StagingBelt,
    /// Where the device has timestamps: a pair per view around its stage,
    /// and one around the whole frame (its last), from before the uploads'
    /// copies to after the last encode. Their 16 bytes a pair come back
    /// with the fence the frame waits on anyway, as the non-finite counts
    /// do.
    timer: Option<PassTimer>,
    last_view_ns: Vec<Option<u64>>,
    last_frame_gpu_ns: Option<u64>,
    last_ran: Vec<bool>,
    last_blended: bool,
    /// The last frame's host time up to its submission, ns.
    last_record_ns: u64,
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
        let w32 = match (u32::try_from(width), u32::try_from(height)) {
            (Ok(w), Ok(h)) if w > 0 && h > 0 => w,
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
        let mut prepared = Vec::new();
        let shared = view::Shared {
            device,
            queue,
            unpack: &unpack,
            luts: &luts,
            panel: (width, height),
            row_texels: row,
            transfer,
        };
        for (v, view) in views.into_iter().enumerate() {
            prepared.push(ViewOnDevice::new(&shared, v, view)?);
        }
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(PresentError::Gpu {
                stage: STAGE,
                source: e.into(),
            });
        }
        for (v, view) in prepared.iter_mut().enumerate() {
            view.warm_up(device, v);
        }
        let n = prepared.len();
        // One chunk holds the largest single upload, a view's f32 planes.
        let largest = prepared.iter().map(|v| v.frame.size()).max().unwrap_or(0);
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            width,
            height,
            row_texels: row,
            unpack,
            views: prepared,
            codes: Vec::new(),
            belt: wgpu::util::StagingBelt::new(device.clone(), largest),
            timer: PassTimer::new(device, queue, n + 1),
            last_view_ns: vec![None; n],
            last_frame_gpu_ns: None,
            last_ran: vec![false; n],
            last_blended: false,
            last_record_ns: 0,
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

    /// The last frame's host time up to its submission, ns: the uploads'
    /// copies into the device's staging memory and the recording of every
    /// pass. With [`DeviceFrames::last_view_ns`] and
    /// [`DeviceFrames::last_frame_gpu_ns`] it says where a frame's time
    /// went that its stages' device time does not show (issue 56, item 5).
    pub fn last_record_ns(&self) -> u64 {
        self.last_record_ns
    }

    /// The last frame's whole submission on the device, ns (timestamps,
    /// where the device has them): the uploads' copies, unpacks, layers,
    /// stages and encodes. Less the stages' time it is the device's part
    /// of a frame's overhead; the frame's wall time less this and the
    /// record time is the submission's and the fence's latency.
    pub fn last_frame_gpu_ns(&self) -> Option<u64> {
        self.last_frame_gpu_ns
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

    /// Uploads, records, submits and waits; the codes and the traffic.
    fn record(
        &mut self,
        frames: &[ViewFrame],
    ) -> Result<(Arc<wgpu::Buffer>, HostTraffic), PresentError> {
        let started = std::time::Instant::now();
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
        let n = self.views.len();
        if let Some(t) = &self.timer {
            mark(&mut encoder, t.start(n));
        }
        for (v, (f, view)) in frames.iter().zip(&mut self.views).enumerate() {
            self.last_ran[v] = false;
            // No frame for this view yet: its region stays black.
            if f.generation == 0 {
                continue;
            }
            if f.generation != view.generation {
                // A failed frame leaves its staged bytes in the belt's
                // active chunk; the next frame's finish closes it.
                let (bytes, layers, blended) =
                    view.upload(&mut self.belt, &self.unpack, &mut encoder, &f.content)?;
                traffic.to_device_bytes += bytes as u64;
                traffic.uploads += 1;
                traffic.add(layers);
                self.last_blended |= blended;
                let (w, h) = (view.region.width, view.region.height);
                // A stage with nothing to do this frame records nothing:
                // its input is shown (the frame budget's lowest level).
                view.passed = view.stage.as_ref().is_some_and(|s| s.passes_through());
                if let Some(stage) = view.stage.as_mut().filter(|_| !view.passed) {
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
            let shown = if view.stage.is_some() && !view.passed {
                &view.display
            } else {
                &view.frame
            };
            view.encoder.record(&mut encoder, shown, &codes)?;
            encoded[v] = true;
        }
        if let Some(t) = &self.timer {
            mark(&mut encoder, t.end(n));
        }
        // The views whose stage recorded its work and timestamps this
        // frame (the frame budget's lowest level passes the frame through).
        let staged: Vec<bool> = (self.views.iter().enumerate())
            .map(|(v, view)| self.last_ran[v] && view.stage.is_some() && !view.passed)
            .collect();
        let timer = self.timer.as_ref();
        let timer_bytes = timer.map_or(0, |t| t.resolve(&mut encoder));
        self.belt.finish();
        let submission = self.queue.submit([encoder.finish()]);
        self.last_record_ns = started.elapsed().as_nanos() as u64;
        // Each chunk is mapped again once the device has copied from it:
        // within the fence wait below, ready for the next frame.
        self.belt.recall();
        for (view, _) in self.views.iter().zip(&encoded).filter(|(_, e)| **e) {
            view.encoder.map_non_finite();
        }
        if let Some(t) = timer {
            t.map();
        }
        // The fence wait the stage does anyway (its time includes the
        // device's work); it also brings the 4-byte non-finite counts and
        // the timestamps back.
        nedrt_gpu::wait_for(&self.device, submission).map_err(PresentError::gpu(STAGE))?;
        let spans = timer.and_then(|t| t.spans_ns().ok());
        for (v, staged) in staged.into_iter().enumerate() {
            // Only a view that ran a stage wrote its timestamps.
            self.last_view_ns[v] = spans
                .as_ref()
                .filter(|_| staged)
                .and_then(|s| s.get(v).copied());
        }
        self.last_frame_gpu_ns = spans.as_ref().and_then(|s| s.get(n).copied());
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

mod view;

#[cfg(test)]
#[path = "device_frames_tests.rs"]
mod tests;
