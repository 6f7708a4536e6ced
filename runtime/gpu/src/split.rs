//! `admm:K` on the device: the linear least-squares prefilter, then K steps
//! of the split solver (ADMM at a constant penalty) per channel, the same
//! steps as nedrt-optics' `ProblemPlan::split_from` (docs/optimal.md). The
//! data step's two filters are gain sets of one [`DctFilter`] (the frame's
//! data term once, the penalty's share every step) and the rest is
//! `shaders/admm.wgsl`: a step is one filter and one per-pixel pass, with
//! no reduction. A frame records its dispatches; nothing is allocated or
//! read back. Warm-started ([`SplitStage::warm_started`]), a still frame
//! goes on from where the last frame's steps stopped (`shaders/still.wgsl`
//! decides, as for the refinement).

use crate::GpuError;
use crate::fft::{DctFilter, FftError, FftKernels, TermsError, init_buffer};
use crate::solver::{GroupCache, StillPipelines, bind, pipelines};

const SHADER: &str = include_str!("../../../shaders/admm.wgsl");

/// The split solver at one frame size, as the device takes it: per channel
/// the gains (DCT layout, [`DctFilter`]) of the linear prefilter (the
/// start), of the data term Σ_D A_Dᵀ t_D / (N + ρ) and of the penalty's
/// share ρ / (N + ρ); and the relaxation α.
#[derive(Debug, Clone)]
pub struct SplitTerms {
    pub linear: Vec<Vec<f32>>,
    pub data: Vec<Vec<f32>>,
    pub penalty: Vec<Vec<f32>>,
    pub relaxation: f32,
}

/// The terms of a frame size, or why they cannot be made.
pub type SplitTermsFor = Box<dyn FnMut(usize, usize) -> Result<SplitTerms, TermsError> + Send>;

/// `admm.wgsl`'s `Frame`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FrameParams {
    plane: u32,
    channels: u32,
    groups_x: u32,
    relaxation: f32,
}

#[derive(Debug)]
struct Pipelines {
    layout: wgpu::BindGroupLayout,
    start: wgpu::ComputePipeline,
    step: wgpu::ComputePipeline,
    emit: wgpu::ComputePipeline,
}

/// `still.wgsl`'s `Frame` (the refinement's layout).
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct StillParams {
    plane: u32,
    channels: u32,
    groups_per_plane: u32,
    groups_x: u32,
}

/// Everything one frame size needs.
#[derive(Debug)]
struct Plan {
    width: usize,
    height: usize,
    filter: DctFilter,
    /// frame, z, u, v, ax, c, the linear start, the still test's state.
    buffers: [wgpu::Buffer; 8],
    main: wgpu::BindGroup,
    emits: GroupCache,
    groups: [u32; 3],
    /// Warm-started: still.wgsl's frame, the last frame's planes, the
    /// partial sums, and its bind groups by input buffer.
    still: Option<[wgpu::Buffer; 3]>,
    stills: GroupCache,
}

/// `admm:K` as a [`crate::DeviceStage`].
pub struct SplitStage {
    name: String,
    steps: usize,
    device: wgpu::Device,
    kernels: FftKernels,
    pipelines: Pipelines,
    terms_for: SplitTermsFor,
    plan: Option<Plan>,
    /// Warm-started: the still test's pipelines and RMS threshold.
    warm: Option<(StillPipelines, f32)>,
}

impl std::fmt::Debug for SplitStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SplitStage")
            .field("name", &self.name)
            .field("steps", &self.steps)
            .finish()
    }
}

impl SplitStage {
    pub fn new(
        device: &wgpu::Device,
        name: String,
        steps: usize,
        terms_for: SplitTermsFor,
    ) -> Result<Self, FftError> {
        let pipelines = crate::fft::checked(device, || {
            let (layout, mut p) = pipelines(
                device,
                "admm",
                SHADER,
                8,
                &[0, 4, 5, 7],
                &["start", "step", "emit"],
            );
            let [start, step, emit] = [0; 3].map(|_| p.remove(0));
            Pipelines {
                layout,
                start,
                step,
                emit,
            }
        })?;
        Ok(Self {
            name,
            steps,
            device: device.clone(),
            kernels: FftKernels::new(device)?,
            pipelines,
            terms_for,
            plan: None,
            warm: None,
        })
    }

    /// Goes on from the last frame's z and u where this frame differs from
    /// the last by an RMS of at most `still_rms` (the host's
    /// `SolvedPrefilter::STILL_RMS`): a still scene converges over frames.
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
        let channels = terms.linear.len();
        if channels == 0 || terms.data.len() != channels || terms.penalty.len() != channels {
            return Err(FftError::Gains(format!(
                "split terms of {} / {} / {} channels",
                terms.linear.len(),
                terms.data.len(),
                terms.penalty.len()
            )));
        }
        if !(terms.relaxation.is_finite() && terms.relaxation > 0.0 && terms.relaxation < 2.0) {
            return Err(FftError::Gains(format!(
                "a relaxation of {} is outside (0, 2)",
                terms.relaxation
            )));
        }
        let filter = DctFilter::with_gain_sets(
            &mut self.kernels,
            width,
            height,
            &[&terms.linear, &terms.data, &terms.penalty],
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
            groups_x: gx,
            relaxation: terms.relaxation,
        };
        let frame = init_buffer(device, "admm frame", bytemuck::bytes_of(&params));
        // still.wgsl's flag and its memory: 4 values per channel, then
        // [warm, had_last, still_rms, 0].
        let still_rms = self.warm.as_ref().map_or(0.0, |(_, rms)| *rms);
        let mut state = vec![0.0f32; 4 * channels];
        state.extend([0.0, 0.0, still_rms, 0.0]);
        let state = init_buffer(device, "admm still state", bytemuck::cast_slice(&state));
        let still = self.warm.is_some().then(|| {
            let still_params = StillParams {
                plane,
                channels: channels as u32,
                groups_per_plane: gx * gy,
                groups_x: gx,
            };
            let partials = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("admm still partial sums"),
                size: u64::from(gx * gy) * channels as u64 * 4,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            });
            [
                init_buffer(
                    device,
                    "admm still frame",
                    bytemuck::bytes_of(&still_params),
                ),
                buffer("admm last frame"),
                partials,
            ]
        });
        let buffers = [
            frame,
            buffer("admm z"),
            buffer("admm u"),
            buffer("admm v"),
            buffer("admm ax"),
            buffer("admm c"),
            buffer("admm start"),
            state,
        ];
        let main = bind(
            device,
            "admm",
            &self.pipelines.layout,
            &buffers.iter().collect::<Vec<_>>(),
        );
        self.plan = Some(Plan {
            width,
            height,
            filter,
            buffers,
            main,
            emits: GroupCache::default(),
            groups: [gx, gy, channels as u32],
            still,
            stills: GroupCache::default(),
        });
        Ok(())
    }
}

impl crate::DeviceStage for SplitStage {
    fn describe(&self) -> String {
        let warm = if self.warm.is_some() {
            ", going on from the last frame's on a still one"
        } else {
            ""
        };
        format!(
            "{} on the device ({} split-solver steps{warm})",
            self.name, self.steps
        )
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
                "the split solver's plan was not made".into(),
            ));
        };
        let [frame, z, u, v, ax, c, start, state] = &plan.buffers;
        let need = z.size();
        crate::solver::check_frame_buffers("the split solver", input, output, need)?;
        let emit = plan.emits.get(output, || {
            bind(
                &self.device,
                "admm",
                &self.pipelines.layout,
                &[frame, z, u, v, ax, c, output, state],
            )
        });
        // Warm-started: is this frame the last one still? (The flag `start`
        // reads.)
        if let (Some((pipelines, _)), Some([still_frame, last, partials])) =
            (&self.warm, &plan.still)
        {
            let group = plan.stills.get(input, || {
                bind(
                    &self.device,
                    "still",
                    &pipelines.layout,
                    &[still_frame, input, last, partials, state],
                )
            });
            pipelines.record(encoder, &group, plan.groups);
        }
        // The data term and the start share the input's forward rows.
        plan.filter
            .record_sets(encoder, input, &[(c, 1), (start, 0)])?;
        let groups = plan.groups;
        let dispatch = |encoder: &mut wgpu::CommandEncoder,
                        pipeline: &wgpu::ComputePipeline,
                        group: &wgpu::BindGroup| {
            crate::solver::dispatch(encoder, "admm", pipeline, group, groups)
        };
        let p = &self.pipelines;
        dispatch(encoder, &p.start, &plan.main);
        for _ in 0..self.steps {
            plan.filter.record_set(encoder, v, ax, 2)?;
            dispatch(encoder, &p.step, &plan.main);
        }
        dispatch(encoder, &p.emit, &emit);
        Ok(())
    }
}
