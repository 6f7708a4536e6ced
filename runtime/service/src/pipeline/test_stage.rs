//! A device stage for the service's GPU tests: out = 1.4 · in − 0.2 on
//! every plane value (the encode then clamps), optionally poisoned.

use nedrt_gpu::DeviceStage;

/// A device stage with work of its own: out = 1.4 · in − 0.2, which
/// pushes values outside [0, 1] for the encode to clamp.
#[derive(Debug)]
pub(crate) struct Stretch {
    pipeline: wgpu::ComputePipeline,
    device: wgpu::Device,
}

impl Stretch {
    pub(crate) fn new(device: &wgpu::Device) -> Self {
        Self::with_poison(device, false)
    }

    /// `poison`: pixel 5 of the red plane becomes +inf, as a network
    /// that overflows.
    pub(crate) fn with_poison(device: &wgpu::Device, poison: bool) -> Self {
        let poison = if poison {
            "if (id.x == 5u) { dst[id.x] = bitcast<f32>(0x7f800000u); }"
        } else {
            ""
        };
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("stretch"),
            source: wgpu::ShaderSource::Wgsl(
                format!(
                    "@group(0) @binding(0) var<storage, read> src: array<f32>;
                     @group(0) @binding(1) var<storage, read_write> dst: array<f32>;
                     @compute @workgroup_size(64)
                     fn main(@builtin(global_invocation_id) id: vec3<u32>) {{
                         if (id.x < arrayLength(&dst)) {{ dst[id.x] = 1.4 * src[id.x] - 0.2; }}
                         {poison}
                     }}"
                )
                .into(),
            ),
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("stretch"),
            layout: None,
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
        Self {
            pipeline,
            device: device.clone(),
        }
    }
}

impl DeviceStage for Stretch {
    fn describe(&self) -> String {
        "stretch".into()
    }
    fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), nedrt_gpu::GpuError> {
        let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &self.pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: input.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: output.as_entire_binding(),
                },
            ],
        });
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups((3 * width * height).div_ceil(64) as u32, 1, 1);
        Ok(())
    }
}
