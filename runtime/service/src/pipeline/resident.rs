//! The resident path: a frame goes to the GPU once, in the form the client
//! sent it, and its panel codes never come back. The client's 8-bit RGBA
//! is unpacked on the device (`shaders/frame_unpack.wgsl`, by the host
//! decode's own table) into three f32 planes; a float frame, or one a host
//! stage has already worked on (a network's Wiener stage), goes up as its
//! planes. The device stage (the D-CNN's kernels) writes the display image
//! into a second buffer, the encode kernel turns it into the panel's codes
//! (the CPU transfer's thresholds, bit for bit) in a buffer the sink then
//! copies to its texture: one submission per frame, one upload, no
//! read-back. Everything is made once for the panel's size; a frame only
//! writes its bytes and records.

use std::sync::Arc;

use super::frame::{PixelFormat, SubmittedFrame, code_lut};
use crate::compose::LayerSet;
use crate::compose::gpu::LayerBlender;
use crate::present::encode_gpu::{PanelEncoder, workgroups};
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

/// What goes up to the device for a frame.
#[derive(Debug)]
pub enum DeviceInput {
    /// The frame as the client sent it (validated).
    Client(SubmittedFrame),
    /// Planes a host stage made from it.
    Planar(Image),
    /// Each view's newest planes (two views on one panel); these go
    /// through the host (`service::views`).
    Views(Vec<crate::compose::ViewImage>),
}

/// The device side of the resident path for one panel size.
#[derive(Debug)]
pub struct DeviceFrames {
    device: wgpu::Device,
    queue: wgpu::Queue,
    width: usize,
    height: usize,
    unpack: wgpu::ComputePipeline,
    /// The unpack's bind groups for code/255 and the sRGB decode.
    unpack_linear: wgpu::BindGroup,
    unpack_srgb: wgpu::BindGroup,
    /// The client's RGBA8 frame as it came.
    rgba: wgpu::Buffer,
    /// Three f32 planes: the frame.
    frame: wgpu::Buffer,
    /// Three f32 planes: the display image (the stage's output).
    display: wgpu::Buffer,
    encoder: PanelEncoder,
    /// Codes buffers; one is reused once no frame holds it.
    codes: Vec<Arc<wgpu::Buffer>>,
    stage: Option<Box<dyn DeviceStage>>,
    /// Timestamps before and after the stage's passes, where the device has
    /// them and there is a stage: its 16 bytes come back with the fence the
    /// frame waits on anyway, as the non-finite count does.
    timer: Option<PassTimer>,
    last_gpu_ns: Option<u64>,
    /// The view's quad layers, blended after the unpack of a frame that
    /// came up as it was sent (a decoded frame had them blended on the host).
    layers: Option<Arc<LayerSet>>,
    blender: LayerBlender,
    last_blended: bool,
}

impl DeviceFrames {
    /// Prepares `width`×`height` frames on `device` (the sink's) with
    /// `transfer`'s codes, through `stage` (none: the frame is shown as it
    /// comes, clamped).
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        width: usize,
        height: usize,
        transfer: &Transfer,
        stage: Option<Box<dyn DeviceStage>>,
    ) -> Result<Self, PresentError> {
        let pixels = width * height;
        let (w32, h32, p32) = match (
            u32::try_from(width),
            u32::try_from(height),
            u32::try_from(3 * pixels),
        ) {
            (Ok(w), Ok(h), Ok(_)) if pixels > 0 => (w, h, pixels as u32),
            _ => return Err(err(format!("a {width}×{height} panel"))),
        };
        let plane_bytes = 3 * 4 * pixels as u64;
        let binding = device.limits().max_storage_buffer_binding_size;
        if plane_bytes > binding {
            return Err(err(format!(
                "a {width}×{height} frame's planes need {:.0} MiB in one binding; the adapter \
                 binds at most {:.0} MiB",
                plane_bytes as f64 / 1048576.0,
                binding as f64 / 1048576.0
            )));
        }
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let encoder = PanelEncoder::new(device, queue, w32, h32, p32, transfer)?;
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
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("frame_unpack"),
            contents: bytemuck::cast_slice(&[p32, 0, 0, 0]),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let group = |srgb: bool| {
            let lut = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("code table"),
                contents: bytemuck::cast_slice(&code_lut(srgb)),
                usage: wgpu::BufferUsages::STORAGE,
            });
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
        let (unpack_linear, unpack_srgb) = (group(false), group(true));
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(PresentError::Gpu {
                stage: STAGE,
                source: e.into(),
            });
        }
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            width,
            height,
            unpack,
            unpack_linear,
            unpack_srgb,
            rgba,
            frame,
            display,
            encoder,
            codes: Vec::new(),
            timer: stage
                .as_ref()
                .and_then(|_| PassTimer::new(device, queue, 1)),
            stage,
            last_gpu_ns: None,
            layers: None,
            blender: LayerBlender::new(device, queue).map_err(PresentError::gpu(STAGE))?,
            last_blended: false,
        })
    }

    /// Blends `layers` into every frame uploaded as it came.
    pub fn attach_layers(&mut self, layers: Arc<LayerSet>) {
        self.layers = Some(layers);
    }

    /// Whether the last frame had quad layers blended on the device.
    pub fn last_blended(&self) -> bool {
        self.last_blended
    }

    /// The device's own time for the stage's work on the last frame, ns,
    /// where the device has timestamp queries (the report's `dcnn-gpu`).
    pub fn last_gpu_ns(&self) -> Option<u64> {
        self.last_gpu_ns
    }

    /// For reports.
    pub fn describe(&self) -> String {
        match &self.stage {
            Some(s) => s.describe(),
            None => "none (the frame as it comes, clamped to [0, 1])".into(),
        }
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
        let c = Arc::new(self.encoder.codes_buffer());
        self.codes.push(c.clone());
        if self.codes.len() == CODES_WARN {
            tracing::warn!("{CODES_WARN} encoded frames are held downstream of the GPU stage");
        }
        c
    }

    /// Uploads `input`, records unpack → stage → encode, submits and waits
    /// for the device (no data comes back). Returns the frame for the sink
    /// and what crossed to the device.
    pub fn run(
        &mut self,
        id: u64,
        input: &DeviceInput,
    ) -> Result<(DeviceDisplayFrame, HostTraffic), PresentError> {
        let (w, h) = (self.width, self.height);
        match input {
            DeviceInput::Client(f) if (f.width, f.height) != (w, h) => {
                return Err(err(format!("{}×{} frame for {w}×{h}", f.width, f.height)));
            }
            DeviceInput::Views(_) => {
                return Err(err("frames of two views go through the host"));
            }
            DeviceInput::Planar(im) if (im.width, im.height, im.channels()) != (w, h, 3) => {
                return Err(err(format!(
                    "{}×{} frame of {} planes for {w}×{h}×3",
                    im.width,
                    im.height,
                    im.channels()
                )));
            }
            _ => {}
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let recorded = self.record(input);
        // Popped on every path: a scope left open would catch later errors.
        let validation = pollster::block_on(scope.pop());
        // The validation error first: it is the cause of a failed wait.
        if let Some(e) = validation {
            return Err(PresentError::Gpu {
                stage: STAGE,
                source: e.into(),
            });
        }
        let (frame, traffic) = recorded?;
        Ok((
            DeviceDisplayFrame {
                id,
                width: w,
                height: h,
                codes: frame,
                row_texels: self.encoder.row_texels(),
                device: self.device.clone(),
                queue: self.queue.clone(),
            },
            traffic,
        ))
    }

    /// Uploads, records, submits and waits; the codes and the traffic.
    fn record(
        &mut self,
        input: &DeviceInput,
    ) -> Result<(Arc<wgpu::Buffer>, HostTraffic), PresentError> {
        let (w, h) = (self.width, self.height);
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("device frame"),
            });
        let uploaded = match input {
            DeviceInput::Client(f) => match f.format {
                PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb => {
                    self.queue.write_buffer(&self.rgba, 0, &f.payload);
                    let group = if f.format == PixelFormat::Rgba8Srgb {
                        &self.unpack_srgb
                    } else {
                        &self.unpack_linear
                    };
                    let [x, y] = workgroups((w * h) as u32);
                    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                        label: Some("frame_unpack"),
                        timestamp_writes: None,
                    });
                    pass.set_pipeline(&self.unpack);
                    pass.set_bind_group(0, group, &[]);
                    pass.dispatch_workgroups(x, y, 1);
                    f.payload.len()
                }
                // Planar little-endian f32 is the planes' own layout.
                PixelFormat::Rgb32fPlanar => {
                    self.queue.write_buffer(&self.frame, 0, &f.payload);
                    f.payload.len()
                }
            },
            DeviceInput::Planar(im) => {
                self.queue
                    .write_buffer(&self.frame, 0, bytemuck::cast_slice(im.data()));
                std::mem::size_of_val(im.data())
            }
            // Refused by `run` before anything is recorded.
            DeviceInput::Views(_) => 0,
        };
        let mut layer_traffic = HostTraffic::default();
        self.last_blended = false;
        if let (DeviceInput::Client(_), Some(layers)) = (input, &self.layers) {
            let snap = layers.snapshot();
            let dims = (w as u32, h as u32, (w * h) as u32);
            // Layers the device cannot hold are left out of the frame (and
            // said so), not a failure of the device path.
            let blended = self.blender.record(
                &mut encoder,
                &self.frame,
                dims,
                &snap.quads,
                snap.generation,
            );
            match blended {
                Ok(t) => {
                    layer_traffic = t;
                    self.last_blended = !snap.quads.is_empty();
                }
                Err(e) => tracing::warn!("a frame's quad layers are left out: {e}"),
            }
        }
        let codes = self.free_codes();
        // Passes with no work of their own carry the stage's timestamps.
        let mark = |encoder: &mut wgpu::CommandEncoder, writes| {
            encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("stage timestamp"),
                timestamp_writes: Some(writes),
            });
        };
        if let Some(stage) = &mut self.stage {
            if let Some(t) = &self.timer {
                mark(&mut encoder, t.start(0));
            }
            stage
                .record(&mut encoder, &self.frame, &self.display, w, h)
                .map_err(PresentError::gpu(STAGE))?;
            if let Some(t) = &self.timer {
                mark(&mut encoder, t.end(0));
            }
        }
        let display = if self.stage.is_some() {
            &self.display
        } else {
            &self.frame
        };
        self.encoder.record(&mut encoder, display, &codes)?;
        // The timer exists only with a stage (new).
        let timer_bytes = self.timer.as_ref().map_or(0, |t| t.resolve(&mut encoder));
        let submission = self.queue.submit([encoder.finish()]);
        self.encoder.map_non_finite();
        if let Some(t) = &self.timer {
            t.map();
        }
        // The fence wait the stage does anyway (its time includes the
        // device's work); it also brings the 4-byte non-finite count and
        // the timestamps back.
        nedrt_gpu::wait_for(&self.device, submission).map_err(PresentError::gpu(STAGE))?;
        self.last_gpu_ns = self
            .timer
            .as_ref()
            .and_then(|t| t.spans_ns().ok())
            .and_then(|spans| spans.first().copied());
        let non_finite = self.encoder.non_finite_pixels()?;
        if non_finite > 0 {
            // As on the host path: an engine failure, not black pixels.
            return Err(err(format!(
                "{}: the display image has {non_finite} pixels that are not finite",
                self.describe()
            )));
        }
        let mut traffic = HostTraffic {
            to_device_bytes: uploaded as u64,
            uploads: 1,
            to_host_bytes: 4 + timer_bytes,
            read_backs: 0,
        };
        traffic.add(layer_traffic);
        Ok((codes, traffic))
    }

    /// The display image of the last frame, read back (tests and checks
    /// only: it waits for the GPU).
    pub fn read_display(&self) -> Result<Image, PresentError> {
        let source = if self.stage.is_some() {
            &self.display
        } else {
            &self.frame
        };
        let bytes = 3 * 4 * (self.width * self.height) as u64;
        let readback = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("display read-back"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(source, 0, &readback, 0, bytes);
        self.queue.submit([encoder.finish()]);
        nedrt_gpu::map_and_wait(&self.device, &readback).map_err(PresentError::gpu(STAGE))?;
        let data = nedrt_gpu::read_mapped(&readback, |bytes| {
            bytemuck::cast_slice::<u8, f32>(bytes).to_vec()
        })
        .map_err(PresentError::gpu(STAGE))?;
        Ok(Image::rgb(self.width, self.height, data))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::frame::{decode, planar_payload};
    use crate::pipeline::test_stage::Stretch;
    use crate::present::headless::HeadlessSink;
    use crate::present::{PanelCodes, Presented, Sink};
    use nedrt_gpu::test_device;

    /// A `width`×`height` frame in `format` with every 8-bit code.
    fn client_frame(id: u64, width: usize, height: usize, format: PixelFormat) -> SubmittedFrame {
        let n = width * height;
        let payload = match format {
            PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb => (0..4 * n)
                .map(|i| ((i * 37 + id as usize) % 256) as u8)
                .collect(),
            PixelFormat::Rgb32fPlanar => {
                let data: Vec<f32> = (0..3 * n).map(|i| (i * 7 % 1001) as f32 / 1000.0).collect();
                planar_payload(&Image::rgb(width, height, data))
            }
        };
        SubmittedFrame {
            id,
            capture_ns: 0,
            width,
            height,
            format,
            payload,
        }
    }

    mod needs_gpu {
        use super::*;

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn the_panel_shows_what_the_cpu_transfer_gives_for_the_device_display_image() {
            let (device, queue) = test_device(false);
            // 37 wide: the codes' rows are padded to the copy pitch.
            let (w, h) = (37usize, 21usize);
            let transfer = Transfer::from_gamma([2.2, 1.0, 2.4]);
            let mut sink = HeadlessSink::new(&device, &queue, "test".into(), w as u32, h as u32)
                .expect("sink");
            for with_stage in [false, true] {
                let stage: Option<Box<dyn DeviceStage>> =
                    with_stage.then(|| Box::new(Stretch::new(&device)) as _);
                let mut frames =
                    DeviceFrames::new(&device, &queue, w, h, &transfer, stage).expect("frames");
                let stamps = device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
                let timed = if with_stage && stamps { 16 } else { 0 };
                let formats = [
                    PixelFormat::Rgba8Linear,
                    PixelFormat::Rgba8Srgb,
                    PixelFormat::Rgb32fPlanar,
                ];
                for (id, format) in formats.into_iter().enumerate() {
                    let client = client_frame(id as u64, w, h, format);
                    let want_up = client.payload.len() as u64;
                    for input in [
                        DeviceInput::Planar(decode(&client)),
                        DeviceInput::Client(client.clone()),
                    ] {
                        let planar = matches!(input, DeviceInput::Planar(_));
                        let (frame, traffic) = frames.run(id as u64, &input).expect("runs");
                        // One upload of the frame as it came (or of the host's
                        // planes), nothing back.
                        let up = if planar {
                            (3 * 4 * w * h) as u64
                        } else {
                            want_up
                        };
                        assert_eq!(
                            traffic,
                            HostTraffic {
                                to_device_bytes: up,
                                uploads: 1,
                                // The non-finite count, and the stage's
                                // timestamps where it has them, back with
                                // the fence.
                                to_host_bytes: 4 + timed,
                                read_backs: 0
                            },
                            "{format:?}"
                        );
                        assert_eq!(frames.last_gpu_ns().is_some(), timed > 0);
                        assert_eq!(
                            sink.present(PanelCodes::Device(&frame)).expect("shown"),
                            Presented::Shown
                        );
                        assert_eq!(sink.last_traffic(), HostTraffic::default());
                        // Only the test reads back: the panel, and the display
                        // image it was encoded from.
                        let shown = sink.read_back().expect("panel");
                        let display = frames.read_display().expect("display");
                        if !with_stage {
                            // The device's unpack is the host decode, bit for bit.
                            assert!(display.data() == decode(&client).data(), "{format:?}");
                        } else {
                            let clipped =
                                display.data().iter().filter(|v| !(0.0..=1.0).contains(*v));
                            assert!(clipped.count() > 0, "the stage's output reaches the clamp");
                        }
                        let mut cpu = Vec::new();
                        transfer.encode_rgba8(&display, &mut cpu);
                        assert!(
                            shown == cpu,
                            "{format:?} stage {with_stage} planar {planar}"
                        );
                    }
                }
            }
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn codes_buffers_are_reused_only_once_no_frame_holds_them() {
            let (device, queue) = test_device(false);
            let transfer = Transfer::from_gamma([2.2; 3]);
            let mut frames =
                DeviceFrames::new(&device, &queue, 8, 4, &transfer, None).expect("frames");
            let input = DeviceInput::Client(client_frame(0, 8, 4, PixelFormat::Rgba8Linear));
            let (a, _) = frames.run(0, &input).expect("runs");
            let (b, _) = frames.run(1, &input).expect("runs");
            // Both held: two buffers.
            assert!(!Arc::ptr_eq(&a.codes, &b.codes));
            drop(a);
            let (c, _) = frames.run(2, &input).expect("runs");
            assert!(!Arc::ptr_eq(&b.codes, &c.codes));
            assert_eq!(frames.codes.len(), 2);
            // A stage whose output is not finite fails the frame, as the
            // host path's engine failure, instead of showing black or white.
            let stage: Box<dyn DeviceStage> = Box::new(Stretch::with_poison(&device, true));
            let mut poisoned =
                DeviceFrames::new(&device, &queue, 8, 4, &transfer, Some(stage)).expect("frames");
            let e = poisoned.run(4, &input).expect_err("non-finite").to_string();
            assert!(e.contains("1 pixels that are not finite"), "{e}");
            // A frame of another size is refused, not drawn.
            let wrong = DeviceInput::Client(client_frame(3, 4, 4, PixelFormat::Rgba8Linear));
            let e = frames.run(3, &wrong).expect_err("wrong size").to_string();
            assert!(e.contains("4×4 frame for 8×4"), "{e}");
        }
    }

    #[test]
    #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
    fn quad_layers_are_blended_on_the_device_as_on_the_host_and_uploaded_once() {
        use crate::compose::{Placement, QuadLayer, ViewGeometry, blend};
        use crate::pipeline::frame::SubmittedFrame;
        let (device, queue) = test_device(false);
        let (w, h) = (37usize, 21usize);
        let transfer = Transfer::from_gamma([2.2, 2.0, 2.4]);
        let view = ViewGeometry {
            width: w,
            height: h,
            pixels_per_tan: 1000.0,
        };
        let layers = Arc::new(LayerSet::default());
        for (layer, z, x, y, qw, qh, a) in
            [(1, 0, 3, 2, 20, 10, 0.6f32), (2, 1, 15, 8, 22, 13, 1.0)]
        {
            let rgba = (0..qw * qh)
                .flat_map(|t| {
                    let c = |k: usize| a * (((t * 17 + k * 29 + layer) % 97) as f32 / 96.0);
                    [c(0), c(1), c(2), a]
                })
                .collect();
            let quad = QuadLayer {
                layer: layer as u32,
                z,
                placement: Placement::Pixels { x, y },
                width: qw,
                height: qh,
                rgba,
            };
            layers
                .set(9, quad.place(&view).expect("placed"), usize::MAX)
                .expect("set");
        }
        let mut frames = DeviceFrames::new(&device, &queue, w, h, &transfer, None).expect("frames");
        frames.attach_layers(layers.clone());
        let client = SubmittedFrame {
            id: 0,
            capture_ns: 0,
            width: w,
            height: h,
            format: PixelFormat::Rgba8Srgb,
            payload: (0..4 * w * h).map(|i| (i * 7 % 256) as u8).collect(),
        };
        let (frame, first) = frames
            .run(0, &DeviceInput::Client(client.clone()))
            .expect("runs");
        assert!(frames.last_blended());
        let on_device = frame.to_host().expect("codes").rgba8;
        let mut im = decode(&client);
        blend(&mut im, &layers.snapshot().quads).expect("blends");
        let mut on_host = Vec::new();
        transfer.encode_rgba8(&im, &mut on_host);
        let worst = on_device
            .iter()
            .zip(&on_host)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap_or(0);
        assert!(worst <= 1, "codes differ by {worst}");
        // The same layers on the next frame: their texels stay on the device.
        let (_, second) = frames.run(1, &DeviceInput::Client(client)).expect("runs");
        assert!(second.to_device_bytes < first.to_device_bytes);
        assert_eq!(second.read_backs, 0);
    }
}
