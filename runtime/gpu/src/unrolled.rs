//! The unrolled preprocessor on the device (docs/unrolled.md): the `lsq`
//! start, then per step the split solver's data step at that step's
//! penalty and relaxation, the step's correction (a network on 9 stacked
//! planes: the relaxed point, the dual and the objective's gradient, run by
//! a [`DeviceStage`] the caller gives, nedrt-infer's) and the clamp, all
//! recorded into the frame's encoder: nothing is uploaded, allocated or
//! read back per frame. The device twin of nedrt-optics' `SplitSteps`; the
//! per-pixel passes are `shaders/unrolled.wgsl`, the filters gain sets of
//! one [`DctFilter`] (the start, the gradient's two, and each step's
//! solve: its data step is one filter of b + ρ_k/L · (z − u), the frame's
//! own term b made once).

use crate::fft::{DctFilter, FftError, FftKernels, TermsError, init_buffer};
use crate::solver::{GroupCache, bind, pipelines};
use crate::{DeviceStage, GpuError};

const SHADER: &str = include_str!("../../../shaders/unrolled.wgsl");

/// The model's terms at one frame size (nedrt-optics' `UnrolledTerms`):
/// per channel in the DCT filter's layout, the `lsq` start, Σ_D A_Dᵀ t_D / L,
/// N / L, and per step the solve L / (N + ρ_k).
#[derive(Debug, Clone)]
pub struct UnrolledTerms {
    pub linear: Vec<Vec<f32>>,
    pub adjoint: Vec<Vec<f32>>,
    pub normal: Vec<Vec<f32>>,
    pub steps: Vec<UnrolledStepTerms>,
}

/// One step's gains per channel: the solve's, L / (N + ρ_k).
#[derive(Debug, Clone)]
pub struct UnrolledStepTerms {
    pub solve: Vec<Vec<f32>>,
}

/// The terms of a frame size, or why they cannot be made.
pub type UnrolledTermsFor =
    Box<dyn FnMut(usize, usize) -> Result<UnrolledTerms, TermsError> + Send>;

/// One step: its penalty's share ρ_k / L, its relaxation α and its
/// correction (none: a classical step), which maps 9 planes to 3 (its
/// [`DeviceStage::record`]'s input holds 9).
#[derive(Debug)]
pub struct UnrolledStep {
    pub rho_share: f32,
    pub relaxation: f32,
    pub correction: Option<Box<dyn DeviceStage>>,
}

/// `unrolled.wgsl`'s `Frame`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FrameParams {
    plane: u32,
    channels: u32,
    groups_x: u32,
    relaxation: f32,
    /// This step's ρ / L (the start's v), and the next one's (0 after the
    /// last), which the clamp's v is made for.
    share: f32,
    share_next: f32,
}

/// Gain sets of the plan's filter, in this order: start, gradient's
/// constant, gradient's operator, then each step's solve.
const LINEAR: usize = 0;
const ADJOINT: usize = 1;
const NORMAL: usize = 2;
fn solve_set(k: usize) -> usize {
    3 + k
}

#[derive(Debug)]
struct Pipelines {
    layout: wgpu::BindGroupLayout,
    start: wgpu::ComputePipeline,
    relax: wgpu::ComputePipeline,
    gradient: wgpu::ComputePipeline,
    constrain: wgpu::ComputePipeline,
    emit: wgpu::ComputePipeline,
}

/// Everything one frame size needs.
#[derive(Debug)]
struct Plan {
    width: usize,
    height: usize,
    filter: DctFilter,
    /// work (z, u, b), v, r, ax, c, the 9 planes, the correction, zeros.
    buffers: [wgpu::Buffer; 8],
    /// Per step: its bind group (its α; its correction or zeros).
    steps: Vec<wgpu::BindGroup>,
    emits: GroupCache,
    groups: [u32; 3],
    /// Each step's params (kept for the emit groups: the first's).
    params: Vec<wgpu::Buffer>,
}

/// The unrolled preprocessor as a [`DeviceStage`].
pub struct UnrolledStage {
    name: String,
    device: wgpu::Device,
    kernels: FftKernels,
    pipelines: Pipelines,
    terms_for: UnrolledTermsFor,
    steps: Vec<UnrolledStep>,
    plan: Option<Plan>,
}

impl std::fmt::Debug for UnrolledStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UnrolledStage")
            .field("name", &self.name)
            .field("steps", &self.steps.len())
            .finish()
    }
}

impl UnrolledStage {
    pub fn new(
        device: &wgpu::Device,
        name: String,
        steps: Vec<UnrolledStep>,
        terms_for: UnrolledTermsFor,
    ) -> Result<Self, FftError> {
        if steps.is_empty() {
            return Err(FftError::Gains("an unrolled model of no steps".into()));
        }
        let pipelines = crate::fft::checked(device, || {
            let (layout, mut p) = pipelines(
                device,
                "unrolled",
                SHADER,
                8,
                &[0, 4, 5],
                &["start", "relax", "gradient", "constrain", "emit"],
            );
            let [start, relax, gradient, constrain, emit] = [0; 5].map(|_| p.remove(0));
            Pipelines {
                layout,
                start,
                relax,
                gradient,
                constrain,
                emit,
            }
        })?;
        Ok(Self {
            name,
            device: device.clone(),
            kernels: FftKernels::new(device)?,
            pipelines,
            terms_for,
            steps,
            plan: None,
        })
    }

    /// Makes the plan of `width`×`height` frames now (the terms computed
    /// and uploaded), as the first frame of that size would.
    pub fn prepare(&mut self, width: usize, height: usize) -> Result<(), FftError> {
        if matches!(&self.plan, Some(p) if (p.width, p.height) == (width, height)) {
            return Ok(());
        }
        let terms = (self.terms_for)(width, height).map_err(|e| FftError::Gains(e.to_string()))?;
        let channels = terms.linear.len();
        if channels == 0
            || terms.adjoint.len() != channels
            || terms.normal.len() != channels
            || terms.steps.len() != self.steps.len()
        {
            return Err(FftError::Gains(format!(
                "unrolled terms of {channels} channels and {} steps for a model of {} steps",
                terms.steps.len(),
                self.steps.len()
            )));
        }
        let mut sets: Vec<&[Vec<f32>]> = vec![&terms.linear, &terms.adjoint, &terms.normal];
        for step in &terms.steps {
            sets.push(&step.solve);
        }
        let filter = DctFilter::with_gain_sets(&mut self.kernels, width, height, &sets)?;
        let device = &self.device;
        let plane = (width * height) as u32;
        let bytes = u64::from(plane) * channels as u64 * 4;
        let buffer = |label, planes: u64| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes * planes,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            })
        };
        let zeros = buffer("unrolled no correction", 1);
        let buffers = [
            buffer("unrolled z, u, b", 3),
            buffer("unrolled v", 1),
            buffer("unrolled r", 1),
            buffer("unrolled ax", 1),
            buffer("unrolled c", 1),
            buffer("unrolled planes", 3),
            buffer("unrolled correction", 1),
            zeros,
        ];
        let [gx, gy] = crate::workgroups(u64::from(plane));
        let params: Vec<wgpu::Buffer> = self
            .steps
            .iter()
            .enumerate()
            .map(|(k, s)| {
                init_buffer(
                    device,
                    "unrolled frame",
                    bytemuck::bytes_of(&FrameParams {
                        plane,
                        channels: channels as u32,
                        groups_x: gx,
                        relaxation: s.relaxation,
                        share: s.rho_share,
                        share_next: self.steps.get(k + 1).map_or(0.0, |n| n.rho_share),
                    }),
                )
            })
            .collect();
        let [work, v, r, ax, c, planes, correction, zeros] = &buffers;
        let steps = self
            .steps
            .iter()
            .zip(&params)
            .map(|(s, p)| {
                let aux = if s.correction.is_some() {
                    correction
                } else {
                    zeros
                };
                bind(
                    device,
                    "unrolled",
                    &self.pipelines.layout,
                    &[p, work, v, r, ax, c, planes, aux],
                )
            })
            .collect();
        self.plan = Some(Plan {
            width,
            height,
            filter,
            buffers,
            steps,
            emits: GroupCache::default(),
            groups: [gx, gy, channels as u32],
            params,
        });
        Ok(())
    }
}

impl DeviceStage for UnrolledStage {
    fn describe(&self) -> String {
        let learned = self.steps.iter().filter(|s| s.correction.is_some()).count();
        format!(
            "{} on the device ({} split-solver steps, {learned} with a learned correction)",
            self.name,
            self.steps.len()
        )
    }

    fn warm_up(
        &mut self,
        _input: &wgpu::Buffer,
        _output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        self.prepare(width, height).map_err(GpuError::from)?;
        let Some(plan) = &self.plan else {
            return Ok(());
        };
        let [_, _, _, _, _, planes, correction, _] = &plan.buffers;
        for s in &mut self.steps {
            if let Some(net) = s.correction.as_mut() {
                net.warm_up(planes, correction, width, height)?;
            }
        }
        Ok(())
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
                "the unrolled model's plan was not made".into(),
            ));
        };
        let [work, v, r, ax, c, planes, correction, _] = &plan.buffers;
        let need = v.size();
        crate::solver::check_frame_buffers("the unrolled model", input, output, need)?;
        let emit = plan.emits.get(output, || {
            bind(
                &self.device,
                "unrolled",
                &self.pipelines.layout,
                &[&plan.params[0], work, v, r, ax, c, planes, output],
            )
        });
        let groups = plan.groups;
        let dispatch = |encoder: &mut wgpu::CommandEncoder,
                        pipeline: &wgpu::ComputePipeline,
                        group: &wgpu::BindGroup| {
            crate::solver::dispatch(encoder, "unrolled", pipeline, group, groups)
        };
        let p = &self.pipelines;
        plan.filter
            .record_sets(encoder, input, &[(ax, LINEAR), (c, ADJOINT)])?;
        dispatch(encoder, &p.start, &plan.steps[0]);
        for (k, step) in self.steps.iter_mut().enumerate() {
            let group = &plan.steps[k];
            plan.filter.record_set(encoder, v, ax, solve_set(k))?;
            dispatch(encoder, &p.relax, group);
            if let Some(net) = step.correction.as_mut() {
                plan.filter.record_set(encoder, r, ax, NORMAL)?;
                dispatch(encoder, &p.gradient, group);
                net.record(encoder, planes, correction, width, height)?;
            }
            dispatch(encoder, &p.constrain, group);
        }
        dispatch(encoder, &p.emit, &emit);
        Ok(())
    }
}
