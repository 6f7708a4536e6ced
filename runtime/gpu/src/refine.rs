//! `refine:K` on the device: the linear least-squares prefilter, then K
//! projected-gradient steps with momentum and gradient restart, per channel,
//! on the bounded least-squares problem of the display's optics
//! (nedrt-optics' `optimal.rs`, docs/optimal.md): the same operator, step
//! 1/L, restart rule and step count as the CPU, the operator applied by the
//! DCT filter ([`crate::fft::DctFilter`], three gain sets sharing its
//! buffers) and the steps by `shaders/fista.wgsl`. Where the filter runs in
//! workgroup memory, a step's momentum and projection run inside its row
//! passes (`shaders/fista_fused.wgsl`: four dispatches a step instead of
//! six, and the gradient Ay never written). A frame records its
//! dispatches; nothing is allocated or read back. Warm-started
//! ([`RefineStage::warm_started`]), a still frame goes on from where the
//! last frame's steps stopped (`shaders/still.wgsl` decides on the device,
//! as the host's `SolvedPrefilter::warm_started` does).

use crate::GpuError;
use crate::fft::{
    DctFilter, FftError, FftKernels, RowEnds, RowEndsSpec, TermsError, init_buffer, storage,
};
use crate::solver::{GroupCache, StillPipelines, bind, pipelines};

const SHADER: &str = include_str!("../../../shaders/fista.wgsl");
const FUSED_SHADER: &str = include_str!("../../../shaders/fista_fused.wgsl");

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
    /// `fista_fused.wgsl`'s kernels for the filter's rows (their bind group 1).
    ends: RowEndsSpec,
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
        // fista_fused.wgsl's group 1: state, y, x, b, the rows' partial sums.
        let ends_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("fista fused"),
            entries: &[0, 1, 2, 3, 4].map(|b| storage(b, matches!(b, 0 | 3))),
        });
        Self {
            start,
            project,
            reduce,
            advance,
            emit,
            layout,
            ends: RowEndsSpec {
                name: "fista_fused",
                source: FUSED_SHADER,
                load: "dct2_advance",
                store: "dct3_project",
                layout: ends_layout,
            },
        }
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
    /// fista.wgsl's frame, state, x, partial sums, and still.wgsl's frame
    /// (its sums always per workgroup of 64 pixels).
    buffers: [wgpu::Buffer; 5],
    main: wgpu::BindGroup,
    emits: GroupCache,
    groups: [u32; 3],
    /// Warm-started: the last frame's planes, and the still test's bind
    /// groups by input buffer.
    last: Option<wgpu::Buffer>,
    stills: GroupCache,
    /// The steps fused into the filter's rows: their kernels and bind group 1.
    ends: Option<(RowEnds, wgpu::BindGroup)>,
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
    /// Fuse the steps into the filter's rows where it runs in workgroup memory.
    fuse_steps: bool,
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
            fuse_steps: true,
        })
    }

    /// Whether the steps run inside the filter's row passes where it runs
    /// in workgroup memory (the default), or as kernels of their own (the
    /// comparison's twin; the multi-pass filter always has them so).
    pub fn with_fused_steps(mut self, fuse: bool) -> Self {
        self.fuse_steps = fuse;
        self.plan = None;
        self
    }

    /// The kernels the transforms use ([`FftKernels::set_path`], the
    /// variants), for the plans made from now on.
    pub fn kernels_mut(&mut self) -> &mut FftKernels {
        self.plan = None;
        &mut self.kernels
    }

    /// Whether the prepared plan's steps run inside the filter's rows
    /// (none before [`RefineStage::prepare`]).
    pub fn steps_fused(&self) -> Option<bool> {
        self.plan.as_ref().map(|p| p.ends.is_some())
    }

    /// Dispatches a step of the prepared plan: the filter's, then reduce
    /// fused, or project, reduce and advance (none before
    /// [`RefineStage::prepare`]).
    pub fn dispatches_per_step(&self) -> Option<usize> {
        self.plan
            .as_ref()
            .map(|p| p.filter.passes(2).len() + if p.ends.is_some() { 1 } else { 3 })
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
        // A driver that refuses the fused kernels (a limit wgpu does not
        // report) still runs the steps: their own kernels.
        let ends = match self.fuse_steps {
            true => match filter.row_ends(&mut self.kernels, &self.pipelines.ends) {
                Err(FftError::Device(_)) => None,
                other => other?,
            },
            false => None,
        };
        let [gx, gy] = crate::workgroups(u64::from(plane));
        // The restart test's partial sums: one per workgroup of `project`,
        // or, fused, one per row (`fista_fused.wgsl`).
        let sums_per_plane = if ends.is_some() {
            height as u32
        } else {
            gx * gy
        };
        let params = FrameParams {
            plane,
            channels: channels as u32,
            groups_per_plane: sums_per_plane,
            groups_x: gx,
        };
        let init = |label, contents: &[u8]| init_buffer(device, label, contents);
        let frame = init("fista frame", bytemuck::bytes_of(&params));
        let still_frame = init(
            "still frame",
            bytemuck::bytes_of(&FrameParams {
                groups_per_plane: gx * gy,
                ..params
            }),
        );
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
            size: u64::from(sums_per_plane.max(gx * gy)) * channels as u64 * 4,
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
        let ends = ends.map(|e| {
            let group = bind(
                device,
                "fista fused",
                &self.pipelines.ends.layout,
                &[&state, &y, &x, &b, &partials],
            );
            (e, group)
        });
        self.plan = Some(Plan {
            width,
            height,
            filter,
            y,
            xn,
            ay,
            b,
            buffers: [frame, state, x, partials, still_frame],
            main,
            emits: GroupCache::default(),
            groups: [gx, gy, channels as u32],
            last: self.warm.is_some().then(|| buffer("fista last frame")),
            stills: GroupCache::default(),
            ends,
        });
        Ok(())
    }
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
        crate::solver::check_frame_buffers("the refinement", input, output, need)?;
        let [frame, state, x, partials, still_frame] = &plan.buffers;
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
                    &[still_frame, input, last, partials, state],
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
        let warm = plan.last.is_some();
        match &plan.ends {
            Some((ends, group)) if self.steps > 0 => {
                // Step k: (advance of step k − 1 and) the rows' DCT-II, the
                // columns, the rows' DCT-III and project, then reduce. The
                // last step projects straight into the output, so no emit;
                // its advance runs only warm-started, where the next frame
                // goes on from its y and x (the emit group's x⁺ is the output).
                for k in 0..self.steps {
                    let (input, load) = if k == 0 {
                        (&plan.y, false)
                    } else {
                        (&plan.xn, true)
                    };
                    let to = if k + 1 == self.steps {
                        output
                    } else {
                        &plan.xn
                    };
                    plan.filter
                        .record_with_ends(encoder, ends, group, input, to, 2, load)?;
                    dispatch(encoder, &[(&p.reduce, [1, 1, c])], &plan.main);
                }
                if warm {
                    dispatch(encoder, &[(&p.advance, [gx, gy, c])], &emit);
                }
            }
            _ => {
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
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DeviceStage;
    use crate::fft::{FftPath, FusedVariant};
    use wgpu::util::DeviceExt;

    /// A three-channel problem: a Gaussian-like blur per channel (wider in
    /// blue), its normal operator g², the target's term g, the linear
    /// prefilter g/(g² + 0.01), the step 1/max g².
    fn terms(w: usize, h: usize) -> RefineTerms {
        let gains: Vec<Vec<f32>> = (0..3)
            .map(|c| {
                (0..w * h)
                    .map(|i| {
                        let (fy, fx) = ((i / w) as f32 / h as f32, (i % w) as f32 / w as f32);
                        0.05 + 0.95 * (-(2.0 + c as f32) * (fy * fy + fx * fx)).exp()
                    })
                    .collect()
            })
            .collect();
        let map = |f: &dyn Fn(f32) -> f32| -> Vec<Vec<f32>> {
            gains
                .iter()
                .map(|g| g.iter().map(|v| f(*v)).collect())
                .collect()
        };
        let normal = map(&|g| g * g);
        RefineTerms {
            linear: map(&|g| g / (g * g + 0.01)),
            adjoint_target: map(&|g| g),
            step: normal
                .iter()
                .map(|n| 1.0 / n.iter().copied().fold(0.0, f32::max))
                .collect(),
            normal,
        }
    }

    /// A frame of three planes in [0, 1] with edges, so the clamp and the
    /// restart test both act.
    fn frame(w: usize, h: usize, shift: usize) -> Vec<f32> {
        (0..3 * w * h)
            .map(|i| {
                let (x, y) = ((i % w + shift) as f32, ((i / w) % h) as f32);
                let edge = if (x / 7.0).floor() as i32 % 2 == 0 {
                    0.9
                } else {
                    0.05
                };
                (edge + 0.1 * (0.3 * x + 0.2 * y).sin()).clamp(0.0, 1.0)
            })
            .collect()
    }

    /// Each frame through `stage` (one submission a frame), read back.
    fn run(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        stage: &mut RefineStage,
        (w, h): (usize, usize),
        frames: &[Vec<f32>],
    ) -> Vec<Vec<f32>> {
        let bytes = (3 * w * h * 4) as u64;
        let output = device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let host = device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        frames
            .iter()
            .map(|f| {
                let input = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: None,
                    contents: bytemuck::cast_slice(f),
                    usage: wgpu::BufferUsages::STORAGE,
                });
                let mut enc = device.create_command_encoder(&Default::default());
                stage
                    .record(&mut enc, &input, &output, w, h)
                    .expect("record");
                enc.copy_buffer_to_buffer(&output, 0, &host, 0, bytes);
                queue.submit([enc.finish()]);
                crate::map_and_wait(device, &host).expect("read-back");
                crate::read_mapped(&host, |b| bytemuck::cast_slice::<u8, f32>(b).to_vec())
                    .expect("mapped")
            })
            .collect()
    }

    fn stage(device: &wgpu::Device, steps: usize, fuse: bool, path: FftPath) -> RefineStage {
        let mut s = RefineStage::new(
            device,
            "test".into(),
            steps,
            Box::new(|w, h| Ok(terms(w, h))),
        )
        .expect("stage")
        .with_fused_steps(fuse);
        s.kernels_mut().set_path(path);
        s
    }

    fn worst(a: &[f32], b: &[f32]) -> f32 {
        a.iter()
            .zip(b)
            .map(|(x, y)| {
                if (x - y).is_nan() {
                    f32::INFINITY
                } else {
                    (x - y).abs()
                }
            })
            .fold(0.0, f32::max)
    }

    // Named for the hardware stage's filter (`--ignored needs_`).
    mod needs_gpu {
        use super::*;

        /// The steps fused into the filter's rows (issue 56, item 3) are the
        /// unfused steps on the same filter bit for bit: every pixel's
        /// arithmetic is theirs, and the restart test's sum, added in another
        /// order, is only read for its sign. The multi-pass filter's steps
        /// agree within rounding. Odd sides put a row pair across two channels
        /// and leave the last row unpaired; the long runs restart (they fail
        /// with the rows' sums written as −1, that is never restarting).
        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn the_steps_fused_into_the_rows_are_the_unfused_steps() {
            let (device, queue) = crate::test_device(false);
            for (w, h, steps) in [
                (63, 45, 6),
                (40, 27, 1),
                (16, 9, 10),
                (64, 40, 3),
                (40, 27, 40),
                (63, 45, 25),
            ] {
                let frames = [frame(w, h, 0)];
                let mut fused = stage(&device, steps, true, FftPath::Auto);
                fused.prepare(w, h).expect("prepare");
                assert_eq!(fused.steps_fused(), Some(true), "{w}×{h} fused on lavapipe");
                let got = run(&device, &queue, &mut fused, (w, h), &frames);
                let mut twins = Vec::new();
                for (fuse, path) in [(false, FftPath::Auto), (true, FftPath::MultiPass)] {
                    let mut s = stage(&device, steps, fuse, path);
                    s.prepare(w, h).expect("prepare");
                    assert_eq!(s.steps_fused(), Some(false), "{w}×{h} {path:?}");
                    twins.push(run(&device, &queue, &mut s, (w, h), &frames));
                }
                // Two row pairs a workgroup on 32 threads: a row pair's terms
                // summed over threads holding several pixels each.
                let mut shaped = stage(&device, steps, true, FftPath::Auto);
                shaped.kernels_mut().set_fused_variant(FusedVariant {
                    threads: Some(32),
                    max_seqs: Some(2),
                });
                let reshaped = run(&device, &queue, &mut shaped, (w, h), &frames);
                assert!(
                    reshaped[0]
                        .iter()
                        .zip(&got[0])
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "refine:{steps} {w}×{h}: 32 threads, 2 pairs a workgroup"
                );
                let start = run(
                    &device,
                    &queue,
                    &mut stage(&device, 0, true, FftPath::Auto),
                    (w, h),
                    &frames,
                );
                let moved = worst(&got[0], &start[0]);
                let unfused = worst(&got[0], &twins[0][0]);
                let passes = worst(&got[0], &twins[1][0]);
                eprintln!(
                    "refine:{steps} {w}×{h}: fused {unfused:e} from the unfused, {passes:e} from the multi-pass; the steps moved it {moved}"
                );
                assert!(
                    got[0]
                        .iter()
                        .zip(&twins[0][0])
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "refine:{steps} {w}×{h}: {unfused} off the unfused steps"
                );
                assert!(
                    passes <= 1e-4,
                    "refine:{steps} {w}×{h}: {passes} off the multi-pass"
                );
                assert!(moved > 1e-2, "the steps did something: {moved}");
            }
        }

        /// Warm-started, the fused steps go on over still frames and start
        /// afresh on a changed one as the unfused steps do: the last step's
        /// advance leaves the y and x the next frame goes on from.
        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn warm_fused_steps_go_on_as_the_unfused_steps_do() {
            let (device, queue) = crate::test_device(false);
            let (w, h) = (40, 27);
            let (still, moved) = (frame(w, h, 0), frame(w, h, 3));
            let frames = [still.clone(), still.clone(), still, moved.clone(), moved];
            let shown: Vec<Vec<Vec<f32>>> = [true, false]
                .map(|fuse| {
                    let mut s = stage(&device, 2, fuse, FftPath::Auto)
                        .warm_started(1e-3)
                        .expect("warm");
                    run(&device, &queue, &mut s, (w, h), &frames)
                })
                .into();
            for (t, (a, b)) in shown[0].iter().zip(&shown[1]).enumerate() {
                assert_eq!(worst(a, b), 0.0, "frame {t}");
            }
            assert!(
                worst(&shown[0][2], &shown[0][0]) > 1e-3,
                "still frames went on"
            );
            assert!(worst(&shown[0][3], &shown[0][0]) > 1e-3, "a changed frame");
        }
    }
}
