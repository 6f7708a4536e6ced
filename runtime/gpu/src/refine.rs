//! `refine:K` on the device: the linear least-squares prefilter, then K
//! projected-gradient steps with momentum and gradient restart, per channel,
//! on the bounded least-squares problem of the display's optics
//! (nedrt-optics' `optimal.rs`, docs/optimal.md): the same operator, step
//! 1/L, restart rule and step count as the CPU, the operator applied by the
//! DCT filter ([`crate::fft::DctFilter`], three gain sets sharing its
//! buffers) and the steps by `shaders/fista.wgsl`. A frame records its
//! dispatches; nothing is allocated or read back. Warm-started
//! ([`RefineStage::warm_started`]), a still frame goes on from where the
//! last frame's steps stopped (`shaders/still.wgsl` decides on the device,
//! as the host's `SolvedPrefilter::warm_started` does).

use crate::GpuError;
use crate::fft::{DctFilter, FftError, FftKernels, TermsError, init_buffer, storage};

const SHADER: &str = include_str!("../../../shaders/fista.wgsl");
const STILL_SHADER: &str = include_str!("../../../shaders/still.wgsl");

/// The problem at one frame size, as the device takes it: per channel the
/// gains (DCT layout, [`DctFilter`]) of the linear prefilter (the start),
/// of Σ_D A_Dᵀ t_D (the gradient's constant term) and of Σ_D A_Dᵀ A_D
/// (its operator), and the step 1/L.
#[derive(Debug, Clone)]
pub struct RefineTerms {
    pub linear: Vec<Vec<f32>>,
    pub adjoint_target: Vec<Vec<f32>>,
    pub normal: Vec<Vec<f32>>,
    pub step: Vec<f32>,
}

/// The terms of a frame size, or why they cannot be made.
pub type TermsFor = Box<dyn FnMut(usize, usize) -> Result<RefineTerms, TermsError> + Send>;

/// `fista.wgsl`'s `Frame`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FrameParams {
    plane: u32,
    channels: u32,
    groups_per_plane: u32,
    groups_x: u32,
}

#[derive(Debug)]
struct Pipelines {
    layout: wgpu::BindGroupLayout,
    start: wgpu::ComputePipeline,
    project: wgpu::ComputePipeline,
    reduce: wgpu::ComputePipeline,
    advance: wgpu::ComputePipeline,
    emit: wgpu::ComputePipeline,
}

impl Pipelines {
    fn new(device: &wgpu::Device) -> Result<Self, FftError> {
        crate::fft::checked(device, || Self::make(device))
    }

    fn make(device: &wgpu::Device) -> Self {
        let (layout, mut p) = pipelines(
            device,
            "fista",
            SHADER,
            8,
            &[0, 5, 6],
            &["start", "project", "reduce", "advance", "emit"],
        );
        let [start, project, reduce, advance, emit] = [0; 5].map(|_| p.remove(0));
        Self {
            start,
            project,
            reduce,
            advance,
            emit,
            layout,
        }
    }
}

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

/// Everything one frame size needs.
#[derive(Debug)]
struct Plan {
    width: usize,
    height: usize,
    filter: DctFilter,
    /// y, x, x⁺ (the internal buffers the filter reads or writes) and the
    /// bind group of start/project/reduce/advance.
    y: wgpu::Buffer,
    xn: wgpu::Buffer,
    ay: wgpu::Buffer,
    b: wgpu::Buffer,
    buffers: [wgpu::Buffer; 4],
    main: wgpu::BindGroup,
    emits: GroupCache,
    groups: [u32; 3],
    /// Warm-started: the last frame's planes, and the still test's bind
    /// groups by input buffer.
    last: Option<wgpu::Buffer>,
    stills: GroupCache,
}

/// `refine:K` (or `optimal` with a step budget K) as a
/// [`crate::DeviceStage`].
pub struct RefineStage {
    name: String,
    steps: usize,
    device: wgpu::Device,
    kernels: FftKernels,
    pipelines: Pipelines,
    terms_for: TermsFor,
    plan: Option<Plan>,
    /// Warm-started: the still test's pipelines and RMS threshold.
    warm: Option<(StillPipelines, f32)>,
}

impl std::fmt::Debug for RefineStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RefineStage")
            .field("name", &self.name)
            .field("steps", &self.steps)
            .finish()
    }
}

impl RefineStage {
    pub fn new(
        device: &wgpu::Device,
        name: String,
        steps: usize,
        terms_for: TermsFor,
    ) -> Result<Self, FftError> {
        Ok(Self {
            name,
            steps,
            device: device.clone(),
            kernels: FftKernels::new(device)?,
            pipelines: Pipelines::new(device)?,
            terms_for,
            plan: None,
            warm: None,
        })
    }

    /// Goes on from the last frame's x, y and t where this frame differs
    /// from the last by an RMS of at most `still_rms` (the host's
    /// `SolvedPrefilter::STILL_RMS`), instead of from the linear prefilter:
    /// a still scene converges over frames at K steps a frame.
    pub fn warm_started(mut self, still_rms: f32) -> Result<Self, FftError> {
        self.warm = Some((StillPipelines::new(&self.device)?, still_rms));
        self.plan = None;
        Ok(self)
    }

    /// Makes the plan of `width`×`height` frames now (the terms computed
    /// and uploaded), as the first frame of that size would.
    pub fn prepare(&mut self, width: usize, height: usize) -> Result<(), FftError> {
        if matches!(&self.plan, Some(p) if (p.width, p.height) == (width, height)) {
            return Ok(());
        }
        let terms = (self.terms_for)(width, height).map_err(|e| FftError::Gains(e.to_string()))?;
        let channels = terms.step.len();
        if channels == 0
            || [&terms.linear, &terms.adjoint_target, &terms.normal]
                .iter()
                .any(|g| g.len() != channels)
        {
            return Err(FftError::Gains(format!(
                "terms of {} / {} / {} channels and {channels} steps",
                terms.linear.len(),
                terms.adjoint_target.len(),
                terms.normal.len()
            )));
        }
        if terms.step.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(FftError::Gains(
                "a step 1/L is not a positive number".into(),
            ));
        }
        let filter = DctFilter::with_gain_sets(
            &mut self.kernels,
            width,
            height,
            &[&terms.linear, &terms.adjoint_target, &terms.normal],
        )?;
        let device = &self.device;
        let plane = (width * height) as u32;
        let bytes = u64::from(plane) * channels as u64 * 4;
        let buffer = |label| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            })
        };
        let [gx, gy] = crate::workgroups(u64::from(plane));
        let params = FrameParams {
            plane,
            channels: channels as u32,
            groups_per_plane: gx * gy,
            groups_x: gx,
        };
        let init = |label, contents: &[u8]| init_buffer(device, label, contents);
        let frame = init("fista frame", bytemuck::bytes_of(&params));
        // Per channel [1/L, t, m, u], then the warm start's [warm, had_last,
        // still_rms, 0] (still.wgsl).
        let still_rms = self.warm.as_ref().map_or(0.0, |(_, rms)| *rms);
        let state: Vec<f32> = terms
            .step
            .iter()
            .flat_map(|s| [*s, 1.0, 0.0, 0.0])
            .chain([0.0, 0.0, still_rms, 0.0])
            .collect();
        let state = init("fista state", bytemuck::cast_slice(&state));
        let partials = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("fista partial sums"),
            size: u64::from(gx * gy) * channels as u64 * 4,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let (y, x, xn, ay, b) = (
            buffer("fista y"),
            buffer("fista x"),
            buffer("fista x+"),
            buffer("fista Ay"),
            buffer("fista b"),
        );
        let main = bind(
            device,
            "fista",
            &self.pipelines.layout,
            &[&frame, &state, &y, &x, &xn, &ay, &b, &partials],
        );
        self.plan = Some(Plan {
            width,
            height,
            filter,
            y,
            xn,
            ay,
            b,
            buffers: [frame, state, x, partials],
            main,
            emits: GroupCache::default(),
            groups: [gx, gy, channels as u32],
            last: self.warm.is_some().then(|| buffer("fista last frame")),
            stills: GroupCache::default(),
        });
        Ok(())
    }
}

/// A bind group of `buffers` at bindings 0, 1, ….
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

impl crate::DeviceStage for RefineStage {
    fn describe(&self) -> String {
        let warm = if self.warm.is_some() {
            ", going on from the last frame's on a still one"
        } else {
            ""
        };
        format!("{} on the device ({} steps{warm})", self.name, self.steps)
    }

    fn warm_up(
        &mut self,
        _input: &wgpu::Buffer,
        _output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        self.prepare(width, height).map_err(GpuError::from)
    }

    fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        self.prepare(width, height)?;
        let Some(plan) = self.plan.as_mut() else {
            return Err(GpuError::Buffers(
                "the refinement's plan was not made".into(),
            ));
        };
        let need = plan.y.size();
        crate::refine::check_frame_buffers("the refinement", input, output, need)?;
        let [frame, state, x, partials] = &plan.buffers;
        let emit = plan.emits.get(output, || {
            bind(
                &self.device,
                "fista",
                &self.pipelines.layout,
                &[
                    frame, state, &plan.y, x, output, &plan.ay, &plan.b, partials,
                ],
            )
        });
        // Warm-started: is this frame the last one still? (The flag `start`
        // reads.)
        if let (Some((still, _)), Some(last)) = (&self.warm, &plan.last) {
            let group = plan.stills.get(input, || {
                bind(
                    &self.device,
                    "still",
                    &still.layout,
                    &[frame, input, last, partials, state],
                )
            });
            still.record(encoder, &group, plan.groups);
        }
        // b = Σ A_Dᵀ t_D(I); the start: the linear prefilter, clamped. One
        // input: the two share its rows' forward transform.
        plan.filter
            .record_sets(encoder, input, &[(&plan.b, 1), (&plan.xn, 0)])?;
        let [gx, gy, c] = plan.groups;
        let p = &self.pipelines;
        let dispatch = |encoder: &mut wgpu::CommandEncoder,
                        steps: &[(&wgpu::ComputePipeline, [u32; 3])],
                        group: &wgpu::BindGroup| {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("fista"),
                timestamp_writes: None,
            });
            pass.set_bind_group(0, group, &[]);
            for (pipeline, g) in steps {
                pass.set_pipeline(pipeline);
                pass.dispatch_workgroups(g[0], g[1], g[2]);
            }
        };
        dispatch(encoder, &[(&p.start, [gx, gy, c])], &plan.main);
        for _ in 0..self.steps {
            plan.filter.record_set(encoder, &plan.y, &plan.ay, 2)?;
            dispatch(
                encoder,
                &[
                    (&p.project, [gx, gy, c]),
                    (&p.reduce, [1, 1, c]),
                    (&p.advance, [gx, gy, c]),
                ],
                &plan.main,
            );
        }
        dispatch(encoder, &[(&p.emit, [gx, gy, c])], &emit);
        Ok(())
    }
}
