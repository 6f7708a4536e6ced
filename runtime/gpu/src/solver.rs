//! What the solvers' device stages share (`refine.rs`, `split.rs`,
//! `unrolled.rs`): a shader's pipelines over one bind group, the warm
//! start's still test (`shaders/still.wgsl`), bind groups kept per frame
//! buffer, the per-pixel dispatch and the frame buffers' check.

use crate::GpuError;
use crate::fft::{FftError, storage};

const STILL_SHADER: &str = include_str!("../../../shaders/still.wgsl");

/// A shader's compute pipelines, `entries`, over one bind group of
/// `bindings` storage buffers (`read_only` among them).
pub(crate) fn pipelines(
    device: &wgpu::Device,
    label: &str,
    source: &str,
    bindings: u32,
    read_only: &[u32],
    entries: &[&str],
) -> (wgpu::BindGroupLayout, Vec<wgpu::ComputePipeline>) {
    let layout_entries: Vec<wgpu::BindGroupLayoutEntry> = (0..bindings)
        .map(|binding| storage(binding, read_only.contains(&binding)))
        .collect();
    let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &layout_entries,
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(label),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let pipelines = entries
        .iter()
        .map(|entry| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        })
        .collect();
    (layout, pipelines)
}

/// `still.wgsl`'s pipelines: the change from the last frame, and the flag.
#[derive(Debug)]
pub(crate) struct StillPipelines {
    pub(crate) layout: wgpu::BindGroupLayout,
    change: wgpu::ComputePipeline,
    decide: wgpu::ComputePipeline,
}

impl StillPipelines {
    pub(crate) fn new(device: &wgpu::Device) -> Result<Self, FftError> {
        crate::fft::checked(device, || {
            let (layout, mut p) = pipelines(
                device,
                "still",
                STILL_SHADER,
                5,
                &[0, 1],
                &["change", "decide"],
            );
            let [change, decide] = [0; 2].map(|_| p.remove(0));
            Self {
                change,
                decide,
                layout,
            }
        })
    }
}

impl StillPipelines {
    /// Records the still test of a frame: `group` binds still.wgsl's
    /// frame, input, last frame, partial sums and state; `groups` are the
    /// per-pixel dispatch's workgroups (x, y, channels).
    pub(crate) fn record(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        group: &wgpu::BindGroup,
        groups: [u32; 3],
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("still"),
            timestamp_writes: None,
        });
        pass.set_bind_group(0, group, &[]);
        pass.set_pipeline(&self.change);
        pass.dispatch_workgroups(groups[0], groups[1], groups[2]);
        pass.set_pipeline(&self.decide);
        pass.dispatch_workgroups(1, 1, 1);
    }
}

/// Bind groups by the buffer they were made for (a stage's output or
/// input: the service cycles a few), the last few kept.
#[derive(Debug, Default)]
pub(crate) struct GroupCache(Vec<(wgpu::Buffer, wgpu::BindGroup)>);

impl GroupCache {
    const KEPT: usize = 8;

    /// The group made for `key`, made by `make` the first time.
    pub(crate) fn get(
        &mut self,
        key: &wgpu::Buffer,
        make: impl FnOnce() -> wgpu::BindGroup,
    ) -> wgpu::BindGroup {
        if let Some((_, g)) = self.0.iter().find(|(b, _)| b == key) {
            return g.clone();
        }
        let g = make();
        if self.0.len() == Self::KEPT {
            self.0.remove(0);
        }
        self.0.push((key.clone(), g.clone()));
        g
    }
}

/// Whether `input` and `output` each hold a frame of `need` bytes; else
/// the error, naming `what` ("the refinement").
pub(crate) fn check_frame_buffers(
    what: &str,
    input: &wgpu::Buffer,
    output: &wgpu::Buffer,
    need: u64,
) -> Result<(), GpuError> {
    if output.size() < need || input.size() < need {
        return Err(GpuError::Buffers(format!(
            "{what}'s buffers hold {} and {} bytes; a frame is {need}",
            input.size(),
            output.size()
        )));
    }
    Ok(())
}

/// One compute pass of `pipeline` over `groups` with `group` bound (the
/// per-pixel passes of the solvers' stages).
pub(crate) fn dispatch(
    encoder: &mut wgpu::CommandEncoder,
    label: &str,
    pipeline: &wgpu::ComputePipeline,
    group: &wgpu::BindGroup,
    groups: [u32; 3],
) {
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(label),
        timestamp_writes: None,
    });
    pass.set_bind_group(0, group, &[]);
    pass.set_pipeline(pipeline);
    pass.dispatch_workgroups(groups[0], groups[1], groups[2]);
}

/// A bind group of `buffers` at bindings 0, 1, ….
pub(crate) fn bind(
    device: &wgpu::Device,
    label: &str,
    layout: &wgpu::BindGroupLayout,
    buffers: &[&wgpu::Buffer],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout,
        entries: &entries,
    })
}
