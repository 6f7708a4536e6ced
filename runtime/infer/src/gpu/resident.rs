//! The network on a frame that stays on the device: the service hands a
//! buffer with the frame and one for the display image, and the backend
//! records, in one compute pass, for each band (module docs of `gpu`): the
//! band's rows of the frame into the network's input with the reflection
//! padding of `Image::pad_reflect` (`shaders/frame_window.wgsl`), the
//! layers, and the band's kept rows back out into the display image,
//! cropped to the frame. Nothing is uploaded or read back; the copies'
//! params and bind groups are made once per frame size and pair of buffers.

use wgpu::util::DeviceExt;

use super::{GpuBackend, err};
use crate::{InferenceError, ModelFile};

const SHADER: &str = include_str!("../../../../shaders/frame_window.wgsl");
/// `frame_window.wgsl`'s workgroup: 16 × 16 pixels of one channel.
const TILE: u32 = 16;

/// The parameter block of `frame_window.wgsl` (`Window`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct WindowParams {
    src_width: u32,
    src_height: u32,
    src_plane: u32,
    src_offset: u32,
    dst_width: u32,
    dst_plane: u32,
    dst_offset: u32,
    row0: u32,
    rows: u32,
    channels: u32,
    row_shift: i32,
    reflect: u32,
}

/// The copy kernel, built with the backend.
#[derive(Debug)]
pub(super) struct WindowKernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl WindowKernel {
    pub(super) fn new(device: &wgpu::Device) -> Self {
        let entry = |binding: u32, ty| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty,
            count: None,
        };
        let storage = |read_only| wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("frame_window"),
            entries: &[
                // A storage buffer, not a uniform one: see layer_bindings.wgsl.
                entry(0, storage(true)),
                entry(1, storage(true)),
                entry(2, storage(false)),
            ],
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("frame_window"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("frame_window"),
            layout: Some(
                &device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some("frame_window"),
                    bind_group_layouts: &[Some(&layout)],
                    immediate_size: 0,
                }),
            ),
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
        Self { pipeline, layout }
    }

    /// One copy: its bind group and workgroups.
    fn copy(
        &self,
        device: &wgpu::Device,
        params: WindowParams,
        src: &wgpu::Buffer,
        dst: &wgpu::Buffer,
    ) -> WindowCopy {
        let params_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("frame_window params"),
            contents: bytemuck::bytes_of(&params),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("frame_window"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: params_buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: src.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: dst.as_entire_binding(),
                },
            ],
        });
        WindowCopy {
            bind_group,
            workgroups: [
                params.dst_width.div_ceil(TILE),
                params.rows.div_ceil(TILE),
                params.channels,
            ],
        }
    }
}

/// One recorded copy.
#[derive(Debug)]
struct WindowCopy {
    bind_group: wgpu::BindGroup,
    workgroups: [u32; 3],
}

/// Per band: the copy in and the copy out.
#[derive(Debug)]
pub(super) struct ResidentPlan {
    width: usize,
    height: usize,
    input: wgpu::Buffer,
    output: wgpu::Buffer,
    bands: Vec<(WindowCopy, WindowCopy)>,
}

/// The rows of a band: its top row in the padded frame, and the rows
/// [keep_start, keep_end) of the padded frame it keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Band {
    pub top: usize,
    pub keep_start: usize,
    pub keep_end: usize,
}

/// The bands of a frame `padded_height` rows tall run `rows` at a time
/// with `halo` rows of context (one band when `rows` is the whole frame);
/// the same split as `GpuBackend::run_tensor`'s.
pub(crate) fn bands(padded_height: usize, rows: usize, halo: usize) -> Vec<Band> {
    if rows >= padded_height {
        return vec![Band {
            top: 0,
            keep_start: 0,
            keep_end: padded_height,
        }];
    }
    let keep = rows - 2 * halo;
    let mut out = Vec::new();
    let mut y0 = 0;
    while y0 < padded_height {
        let y1 = (y0 + keep).min(padded_height);
        out.push(Band {
            top: y0.saturating_sub(halo).min(padded_height - rows),
            keep_start: y0,
            keep_end: y1,
        });
        y0 = y1;
    }
    out
}

impl GpuBackend {
    /// Records the network from the frame in `input` to the display image
    /// in `output` (f32 planes of `width`×`height`: the network's input
    /// channels in, three out), padded to the network's multiple by
    /// reflection and cropped back, in bands where the activations do not
    /// fit the adapter. A display image is clamped to [0, 1] by the last
    /// layer; a correction is not.
    pub fn record_frame(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), InferenceError> {
        let (cin, cout) = (
            self.network.values[0].channels,
            self.network.values[self.network.output].channels,
        );
        if cout != 3 {
            return Err(err(format!(
                "a network to {cout} channels; a display image on the device has 3"
            )));
        }
        let plane_bytes = (width * height * 4) as u64;
        let (in_bytes, out_bytes) = (cin as u64 * plane_bytes, 3 * plane_bytes);
        if width == 0 || height == 0 || input.size() < in_bytes || output.size() < out_bytes {
            return Err(err(format!(
                "a {width}×{height} frame of {cin} planes in and 3 out needs buffers of {in_bytes} \
                 and {out_bytes} bytes; given {} and {}",
                input.size(),
                output.size()
            )));
        }
        self.prepare_frame(input, output, width, height)?;
        let (Some(plan), Some(resident)) = (&self.plan, &self.resident) else {
            return Err(err("no plan"));
        };
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("dcnn on the device's frame"),
            timestamp_writes: None,
        });
        for (copy_in, copy_out) in &resident.bands {
            for (pipeline, bind_group, [x, y, z]) in std::iter::once((
                &self.window.pipeline,
                &copy_in.bind_group,
                copy_in.workgroups,
            ))
            .chain(
                plan.dispatches
                    .iter()
                    .map(|d| (&d.pipeline, &d.bind_group, d.workgroups)),
            )
            .chain(std::iter::once((
                &self.window.pipeline,
                &copy_out.bind_group,
                copy_out.workgroups,
            ))) {
                pass.set_pipeline(pipeline);
                pass.set_bind_group(0, bind_group, &[]);
                pass.dispatch_workgroups(x, y, z);
            }
        }
        self.last_traffic = Default::default();
        self.last_gpu_ns = None;
        Ok(())
    }

    /// Compute pipelines built so far (each compiled once, when a frame
    /// size's plan first needs it).
    pub fn pipelines_built(&self) -> usize {
        self.pipelines.len()
    }

    /// The plan (its pipelines and buffers) and the band copies for a
    /// `width`×`height` frame between `input` and `output`, made where
    /// they are not yet.
    pub fn prepare_frame(
        &mut self,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), InferenceError> {
        let m = self.network.multiple.max(1);
        let (pw, ph) = (width.div_ceil(m) * m, height.div_ceil(m) * m);
        let rows = self.window_rows(pw, ph)?;
        self.report_banding(pw, ph, rows);
        self.ensure_plan(pw, rows)?;
        let stale = self.resident.as_ref().is_none_or(|r| {
            (r.width, r.height) != (width, height) || r.input != *input || r.output != *output
        });
        if stale {
            self.resident = None;
            self.resident = Some(self.prepare_resident(input, output, width, height, rows)?);
        }
        Ok(())
    }

    /// The copies of every band of a `width`×`height` frame between the
    /// service's buffers and the plan's (made for `rows`-row windows).
    fn prepare_resident(
        &self,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
        rows: usize,
    ) -> Result<ResidentPlan, InferenceError> {
        let Some(plan) = &self.plan else {
            return Err(err("no plan"));
        };
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let pw = plan.width;
        let ph = height.div_ceil(self.network.multiple.max(1)) * self.network.multiple.max(1);
        let u = |v: usize| -> Result<u32, InferenceError> {
            u32::try_from(v).map_err(|_| err(format!("{width}×{height} is too large")))
        };
        let mut out = Vec::new();
        for band in bands(ph, rows, self.halo) {
            let into_network = WindowParams {
                src_width: u(width)?,
                src_height: u(height)?,
                src_plane: u(width * height)?,
                src_offset: 0,
                dst_width: u(pw)?,
                dst_plane: u(pw * rows)?,
                dst_offset: u(plan.input.offset)?,
                row0: 0,
                rows: u(rows)?,
                channels: u(self.network.values[0].channels)?,
                row_shift: i32::try_from(band.top).map_err(|_| err("frame too tall"))?,
                reflect: 1,
            };
            // Padding rows below the frame are computed and not kept.
            let kept_end = band.keep_end.min(height);
            let out_of_network = WindowParams {
                src_width: u(pw)?,
                src_height: u(rows)?,
                src_plane: u(pw * rows)?,
                src_offset: u(plan.output.offset)?,
                dst_width: u(width)?,
                dst_plane: u(width * height)?,
                dst_offset: 0,
                row0: u(band.keep_start)?,
                rows: u(kept_end.saturating_sub(band.keep_start))?,
                channels: 3,
                row_shift: -i32::try_from(band.top).map_err(|_| err("frame too tall"))?,
                reflect: 0,
            };
            if out_of_network.rows == 0 {
                continue;
            }
            out.push((
                self.window.copy(
                    &self.device,
                    into_network,
                    input,
                    &plan.buffers[plan.input.buffer],
                ),
                self.window.copy(
                    &self.device,
                    out_of_network,
                    &plan.buffers[plan.output.buffer],
                    output,
                ),
            ));
        }
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(err(format!("preparing the device frame's copies: {e}")));
        }
        Ok(ResidentPlan {
            width,
            height,
            input: input.clone(),
            output: output.clone(),
            bands: out,
        })
    }
}

/// The D-CNN as a [`nedrt_gpu::DeviceStage`]: the wgpu backend on the
/// device the sink presents from.
#[derive(Debug)]
pub struct DeviceDcnn {
    pub model: ModelFile,
    backend: GpuBackend,
}

impl DeviceDcnn {
    /// Prepares `model` on a device the caller opened (the sink's).
    pub fn on_device(
        model: ModelFile,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        adapter_name: String,
        options: &crate::BackendOptions,
    ) -> Result<Self, InferenceError> {
        let network = model.lower()?;
        let backend = GpuBackend::with_options(device, queue, adapter_name, &network, options)?;
        Ok(Self { model, backend })
    }

    /// Caps each activation buffer (tests of the banding).
    pub fn with_binding_limit(mut self, bytes: u64) -> Self {
        self.backend = self.backend.with_binding_limit(bytes);
        self
    }
}

impl nedrt_gpu::DeviceStage for DeviceDcnn {
    fn describe(&self) -> String {
        use crate::Backend;
        format!(
            "D-CNN {} on {}, on the device's frame",
            self.model.path.display(),
            self.backend.describe()
        )
    }

    fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), nedrt_gpu::GpuError> {
        self.backend
            .record_frame(encoder, input, output, width, height)
            .map_err(stage_error)
    }

    fn warm_up(
        &mut self,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), nedrt_gpu::GpuError> {
        self.backend
            .prepare_frame(input, output, width, height)
            .map_err(stage_error)
    }
}

fn stage_error(e: InferenceError) -> nedrt_gpu::GpuError {
    match e {
        InferenceError::Gpu(g) => g,
        e => nedrt_gpu::GpuError::Stage(Box::new(e)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bands_cover_the_frame_once_with_their_halo() {
        assert_eq!(
            bands(64, 64, 8),
            vec![Band {
                top: 0,
                keep_start: 0,
                keep_end: 64
            }]
        );
        for (h, rows, halo) in [(64, 32, 8), (80, 48, 16), (96, 40, 4), (37, 21, 5)] {
            let b = bands(h, rows, halo);
            assert_eq!(b[0].keep_start, 0);
            assert_eq!(b.last().map(|b| b.keep_end), Some(h));
            for w in b.windows(2) {
                assert_eq!(w[0].keep_end, w[1].keep_start);
            }
            for band in &b {
                assert!(band.top + rows <= h, "{band:?}");
                // Every kept row has its halo inside the band, or the frame's edge.
                assert!(band.top == 0 || band.keep_start >= band.top + halo);
                assert!(band.top + rows == h || band.keep_end + halo <= band.top + rows);
            }
        }
    }
}
