//! The device twin of [`super::blend`]: `shaders/layer_blend.wgsl` blends
//! the quads into a view's f32 planes in place, recorded into the frame's
//! own command encoder (before the preprocessing stage), so a frame that
//! stays on the GPU gets its layers without a read-back.

use nedrt_core::preprocess::HostTraffic;
use nedrt_gpu::GpuError;

use super::{LayerError, MAX_QUADS, PlacedQuad};

const SHADER: &str = include_str!("../../../../shaders/layer_blend.wgsl");

/// The uniform block of `layer_blend.wgsl` (`Blend`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
struct BlendUniform {
    width: u32,
    height: u32,
    plane_stride: u32,
    quads: u32,
}

/// One element of `quads` in `layer_blend.wgsl` (`Quad`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
struct QuadUniform {
    x: u32,
    y: u32,
    width: u32,
    height: u32,
    offset: u32,
    _pad: [u32; 3],
}

/// Blends quad layers on a device. The quads' texels go up only when the
/// caller's `generation` changes (a layer came, went or moved).
#[derive(Debug)]
pub struct LayerBlender {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::ComputePipeline,
    uniform: wgpu::Buffer,
    quads: wgpu::Buffer,
    texels: wgpu::Buffer,
    /// The generation whose quads and texels are on the device.
    uploaded: Option<u64>,
    /// Bytes of `texels` in use.
    texel_bytes: u64,
    count: u32,
}

impl LayerBlender {
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Result<Self, GpuError> {
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("layer_blend"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("layer_blend"),
            layout: None,
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(e.into());
        }
        let buffer = |label, size: u64, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            pipeline,
            uniform: buffer(
                "layer_blend uniform",
                std::mem::size_of::<BlendUniform>() as u64,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            ),
            quads: buffer(
                "layer_blend quads",
                (MAX_QUADS * std::mem::size_of::<QuadUniform>()) as u64,
                storage,
            ),
            texels: buffer("layer_blend texels", 16, storage),
            uploaded: None,
            texel_bytes: 16,
            count: 0,
        })
    }

    /// Records the blend of `quads` into `planes` (a `width`×`height`
    /// view's R, G, B planes `plane_stride` values apart) on `encoder`;
    /// nothing is recorded without quads. Returns what went up to the
    /// device: the texels when `generation` is new, the uniform always.
    /// Once per submission: the uniform and quads are written through the
    /// queue, so a second record before the submit would see the last
    /// one's (the service records one per frame and waits for it).
    pub fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        planes: &wgpu::Buffer,
        (width, height, plane_stride): (u32, u32, u32),
        quads: &[PlacedQuad],
        generation: u64,
    ) -> Result<HostTraffic, LayerError> {
        let mut traffic = HostTraffic::default();
        if quads.is_empty() {
            return Ok(traffic);
        }
        if quads.len() > MAX_QUADS {
            return Err(LayerError::TooMany { count: quads.len() });
        }
        if self.uploaded != Some(generation) {
            let mut order: Vec<&PlacedQuad> = quads.iter().collect();
            order.sort_by_key(|q| (q.z, q.layer));
            let mut rects = Vec::with_capacity(order.len());
            let mut texels: Vec<f32> = Vec::new();
            for q in order {
                rects.push(QuadUniform {
                    x: q.x as u32,
                    y: q.y as u32,
                    width: q.width as u32,
                    height: q.height as u32,
                    offset: (texels.len() / 4) as u32,
                    _pad: [0; 3],
                });
                texels.extend_from_slice(&q.rgba);
            }
            let bytes: &[u8] = bytemuck::cast_slice(&texels);
            let limits = self.device.limits();
            let limit = limits
                .max_storage_buffer_binding_size
                .min(limits.max_buffer_size);
            if bytes.len() as u64 > limit {
                return Err(LayerError::TooLarge {
                    layer: quads.iter().map(|q| q.layer).max().unwrap_or(0),
                    texels: texels.len() / 4,
                    budget: (limit / 16) as usize,
                });
            }
            if bytes.len() as u64 > self.texels.size() {
                // Grown by doubling within the device's limit.
                let size = (bytes.len() as u64).max(2 * self.texels.size()).min(limit);
                self.texels = self.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("layer_blend texels"),
                    size,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                });
            }
            self.texel_bytes = bytes.len() as u64;
            let rect_bytes: &[u8] = bytemuck::cast_slice(&rects);
            self.queue.write_buffer(&self.quads, 0, rect_bytes);
            self.queue.write_buffer(&self.texels, 0, bytes);
            traffic.to_device_bytes += (rect_bytes.len() + bytes.len()) as u64;
            traffic.uploads += 2;
            self.uploaded = Some(generation);
            self.count = rects.len() as u32;
        }
        let uniform = BlendUniform {
            width,
            height,
            plane_stride,
            quads: self.count,
        };
        self.queue
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&uniform));
        traffic.to_device_bytes += std::mem::size_of::<BlendUniform>() as u64;
        traffic.uploads += 1;
        let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("layer_blend"),
            layout: &self.pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: self.quads.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    // Only the texels in use (a texel is 16 bytes).
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &self.texels,
                        offset: 0,
                        size: std::num::NonZeroU64::new(self.texel_bytes.max(16)),
                    }),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: planes.as_entire_binding(),
                },
            ],
        });
        let [x, y] = nedrt_gpu::workgroups(u64::from(width) * u64::from(height));
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("layer_blend"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(x, y, 1);
        Ok(traffic)
    }
}
