//! Draws encoded panel frames onto a wgpu render target
//! (`shaders/panel_blit.wgsl`): the frame is uploaded once into a
//! panel-sized RGBA8 texture (or, for a frame that stayed on the device,
//! its codes are copied there on the device) and drawn with nearest-pixel scaling, so a
//! panel-sized target receives every code value unchanged (the CPU twin is
//! the identity; `headless` tests check it). The pipeline is built once per
//! target format; a frame only uploads and records one pass.

use super::{DeviceDisplayFrame, DisplayFrame, PanelCodes, PresentError};
use nedrt_core::preprocess::HostTraffic;
use nedrt_gpu::map_and_wait;

const SHADER: &str = include_str!("../../../../shaders/panel_blit.wgsl");

const STAGE: &str = "panel renderer";

/// The uniform block of `panel_blit.wgsl` (`Target`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TargetUniform {
    pub size: [f32; 2],
}

/// The panel frame's texture and the pipeline that draws it.
#[derive(Debug)]
pub struct PanelRenderer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    pipeline: wgpu::RenderPipeline,
    panel: wgpu::Texture,
    uniform: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    width: u32,
    height: u32,
    target_size: [u32; 2],
    /// What the last draw uploaded.
    last_traffic: HostTraffic,
}

impl PanelRenderer {
    /// Prepares drawing `width`×`height` panel frames onto targets of
    /// `format` (a non-sRGB unorm format: the codes are already encoded).
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        width: u32,
        height: u32,
        format: wgpu::TextureFormat,
    ) -> Result<Self, PresentError> {
        if format.is_srgb() {
            return Err(PresentError::open(
                STAGE,
                format!(
                    "{format:?} would re-encode the panel's code values; a unorm target is needed"
                ),
            ));
        }
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("panel_blit"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("panel_blit"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("panel_blit"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("panel_blit"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let panel = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("panel frame"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("panel_blit target"),
            size: std::mem::size_of::<TargetUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let view = panel.create_view(&wgpu::TextureViewDescriptor::default());
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("panel_blit"),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&view),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: uniform.as_entire_binding(),
                },
            ],
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(PresentError::kernel(STAGE, "the panel pipeline", e));
        }
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            pipeline,
            panel,
            uniform,
            bind_group,
            width,
            height,
            target_size: [0, 0],
            last_traffic: HostTraffic::default(),
        })
    }

    /// Sets the size of the target the frames are drawn onto (a draw to a
    /// target of another size sets it again, counted in its traffic).
    pub fn set_target_size(&mut self, size: [u32; 2]) {
        let u = TargetUniform {
            size: [size[0] as f32, size[1] as f32],
        };
        self.queue
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&u));
        self.target_size = size;
    }

    /// Draws `frame` onto `target` (`size` pixels): a host frame is
    /// uploaded into the panel texture, a device frame's codes are copied
    /// into it on the device (through the host if they live on another
    /// device). Returns the submission to wait on.
    pub fn draw(
        &mut self,
        frame: PanelCodes<'_>,
        target: &wgpu::TextureView,
        size: [u32; 2],
    ) -> Result<wgpu::SubmissionIndex, PresentError> {
        self.last_traffic = HostTraffic::default();
        if size != self.target_size {
            self.last_traffic.to_device_bytes += std::mem::size_of::<TargetUniform>() as u64;
            self.last_traffic.uploads += 1;
            self.set_target_size(size);
        }
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("present"),
            });
        match frame {
            PanelCodes::Host(f) => self.upload(f)?,
            PanelCodes::Device(f) if f.device == self.device => self.copy_codes(&mut encoder, f)?,
            // Codes on another device come through the host.
            PanelCodes::Device(f) => {
                let host = f.to_host()?;
                self.last_traffic.add(f.read_back_traffic());
                self.upload(&host)?
            }
        }
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("present"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.draw(0..3, 0..1);
        }
        Ok(self.queue.submit([encoder.finish()]))
    }

    fn check_size(&self, width: usize, height: usize, detail: String) -> Result<(), PresentError> {
        if (width, height) != (self.width as usize, self.height as usize) {
            return Err(PresentError::frame(
                STAGE,
                format!(
                    "{width}×{height} frame ({detail}) for a {}×{} panel",
                    self.width, self.height
                ),
            ));
        }
        Ok(())
    }

    /// Records the copy of a device frame's codes into the panel texture.
    fn copy_codes(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        frame: &DeviceDisplayFrame,
    ) -> Result<(), PresentError> {
        let pitch = 4 * u64::from(frame.row_texels);
        self.check_size(
            frame.width,
            frame.height,
            format!("{} bytes, rows of {pitch}", frame.codes.size()),
        )?;
        if frame.row_texels < self.width
            || !pitch.is_multiple_of(u64::from(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT))
            || frame.codes.size() < pitch * u64::from(self.height)
            || !frame.codes.usage().contains(wgpu::BufferUsages::COPY_SRC)
        {
            return Err(PresentError::frame(
                STAGE,
                format!(
                    "the codes of frame {} ({} bytes, rows of {pitch}, {:?}) cannot be copied to \
                     a {}×{} panel",
                    frame.id,
                    frame.codes.size(),
                    frame.codes.usage(),
                    self.width,
                    self.height
                ),
            ));
        }
        encoder.copy_buffer_to_texture(
            wgpu::TexelCopyBufferInfo {
                buffer: &frame.codes,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(pitch as u32),
                    rows_per_image: Some(self.height),
                },
            },
            wgpu::TexelCopyTextureInfo {
                texture: &self.panel,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::Extent3d {
                width: self.width,
                height: self.height,
                depth_or_array_layers: 1,
            },
        );
        Ok(())
    }

    /// Uploads a host frame's codes into the panel texture.
    fn upload(&mut self, frame: &DisplayFrame) -> Result<(), PresentError> {
        self.check_size(
            frame.width,
            frame.height,
            format!("{} bytes", frame.rgba8.len()),
        )?;
        if frame.rgba8.len() != 4 * frame.width * frame.height {
            return Err(PresentError::frame(
                STAGE,
                format!(
                    "{}×{} frame with {} bytes of codes",
                    frame.width,
                    frame.height,
                    frame.rgba8.len()
                ),
            ));
        }
        self.last_traffic.to_device_bytes += frame.rgba8.len() as u64;
        self.last_traffic.uploads += 1;
        self.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &self.panel,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            &frame.rgba8,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(4 * self.width),
                rows_per_image: Some(self.height),
            },
            wgpu::Extent3d {
                width: self.width,
                height: self.height,
                depth_or_array_layers: 1,
            },
        );
        Ok(())
    }

    /// Host→device bytes of the last draw (a host frame's codes, and the
    /// target's size when it changed); a draw reads nothing back.
    pub fn last_traffic(&self) -> HostTraffic {
        self.last_traffic
    }

    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }
}

/// Reads an RGBA8/BGRA8 texture back as tightly packed rows (tests and
/// checks only: it waits for the GPU).
pub fn read_texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
) -> Result<Vec<u8>, PresentError> {
    let (w, h) = (texture.width(), texture.height());
    let row = (4 * w).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: (row * h) as u64,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
        label: Some("readback"),
    });
    encoder.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row),
                rows_per_image: Some(h),
            },
        },
        wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
    );
    queue.submit([encoder.finish()]);
    map_and_wait(device, &buffer).map_err(PresentError::gpu(STAGE))?;
    nedrt_gpu::read_mapped(&buffer, |bytes| {
        let mut out = Vec::with_capacity((4 * w * h) as usize);
        for y in 0..h as usize {
            let start = y * row as usize;
            out.extend_from_slice(&bytes[start..start + 4 * w as usize]);
        }
        out
    })
    .map_err(PresentError::gpu(STAGE))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn target_uniform_matches_the_wgsl_block() {
        let module = naga::front::wgsl::parse_str(SHADER).expect("panel_blit.wgsl parses");
        let (_, ty) = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some("Target"))
            .expect("struct Target");
        let naga::TypeInner::Struct { members, span } = &ty.inner else {
            panic!("Target is a struct")
        };
        assert_eq!(*span as usize, std::mem::size_of::<TargetUniform>());
        assert_eq!(members[0].name.as_deref(), Some("size"));
        assert_eq!(
            members[0].offset as usize,
            std::mem::offset_of!(TargetUniform, size)
        );
    }
}
