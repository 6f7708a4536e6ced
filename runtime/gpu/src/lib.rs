//! nedrt-gpu, layer 0 of nedrt: the wgpu plumbing the D-CNN backend and the
//! panel sinks share, one copy of each: opening a device on the default
//! adapter, waiting for a read-back, and timing a pass with timestamp
//! queries.
//!
//! Rule: depends on no other nedrt crate; its errors are typed
//! ([`GpuError`], the FFT's [`fft::FftError`]), and the caller wraps them in
//! its own error type.

pub mod adapter;
pub mod fft;
pub mod refine;
mod solver;
pub mod split;
pub mod unrolled;

/// How wgpu's instance is made: which backends it may use, its flags and
/// per-backend options. The binary fills it from wgpu's environment
/// variables (`WGPU_BACKEND`, …); the default is wgpu's primary backends
/// (Vulkan, Metal, DX12), not GL, whose wgpu 30 backend panics once two
/// devices are open (nedrt's settings.rs says more).
#[derive(Debug, Clone)]
pub struct GpuSettings {
    pub backends: wgpu::Backends,
    pub flags: wgpu::InstanceFlags,
    pub backend_options: wgpu::BackendOptions,
}

impl Default for GpuSettings {
    fn default() -> Self {
        Self {
            backends: wgpu::Backends::PRIMARY,
            flags: wgpu::InstanceFlags::default(),
            backend_options: wgpu::BackendOptions::default(),
        }
    }
}

impl GpuSettings {
    /// The instance descriptor, without a display handle.
    pub fn descriptor(&self) -> wgpu::InstanceDescriptor {
        wgpu::InstanceDescriptor {
            backends: self.backends,
            flags: self.flags,
            backend_options: self.backend_options.clone(),
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        }
    }
}

/// Why no device could be opened, or a device failed: a wait, a read-back,
/// a stage's recording. The messages name no command-line flag: the binary
/// adds what to do instead.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error(
        "no GPU adapter ({0}); on Linux without a GPU, Mesa's lavapipe \
         (`apt-get install mesa-vulkan-drivers`) provides one"
    )]
    NoAdapter(String),
    #[error("adapter '{adapter}' has no shader-f16 (half-precision shaders)")]
    NoShaderF16 { adapter: String },
    #[error("requesting a device: {0}")]
    RequestDevice(String),
    /// Waiting for the device failed, or it never answered.
    #[error("device lost ({0})")]
    DeviceLost(String),
    /// The device refused a command (wgpu validation): a size or a usage
    /// it does not take, or a bug.
    #[error("the device refused the work: {0}")]
    Validation(String),
    /// The device ran out of memory.
    #[error("the GPU is out of memory ({0})")]
    OutOfMemory(String),
    /// Mapping a buffer for reading, or reading it, failed.
    #[error("reading back from the GPU: {0}")]
    Map(String),
    /// A device stage's buffers do not fit the frame, or were not made.
    #[error("the stage's device buffers: {0}")]
    Buffers(String),
    /// The device FFT of a stage could not be made or recorded.
    #[error(transparent)]
    Fft(#[from] fft::FftError),
    /// A stage defined outside this crate failed (the D-CNN on the device):
    /// its own error.
    #[error("{0}")]
    Stage(#[source] Box<dyn std::error::Error + Send + Sync>),
}

impl From<wgpu::Error> for GpuError {
    fn from(e: wgpu::Error) -> Self {
        match e {
            wgpu::Error::OutOfMemory { .. } => GpuError::OutOfMemory(e.to_string()),
            wgpu::Error::Validation { description, .. } => GpuError::Validation(description),
            wgpu::Error::Internal { description, .. } => GpuError::DeviceLost(description),
        }
    }
}

/// The adapter `settings` select: the high-performance one, no surface.
pub fn request_adapter(settings: &GpuSettings) -> Result<wgpu::Adapter, GpuError> {
    let instance = wgpu::Instance::new(settings.descriptor());
    pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
        power_preference: wgpu::PowerPreference::HighPerformance,
        force_fallback_adapter: false,
        compatible_surface: None,
        apply_limit_buckets: false,
    }))
    .map_err(|e| GpuError::NoAdapter(e.to_string()))
}

/// Requests the default adapter of `settings` and a device with the
/// adapter's limits, timestamp queries where offered and, if `shader_f16`,
/// half-precision shaders.
pub fn open_device(
    settings: &GpuSettings,
    shader_f16: bool,
) -> Result<(wgpu::Adapter, wgpu::Device, wgpu::Queue), GpuError> {
    let adapter = request_adapter(settings)?;
    let mut features = adapter.features() & wgpu::Features::TIMESTAMP_QUERY;
    if shader_f16 {
        if !adapter.features().contains(wgpu::Features::SHADER_F16) {
            return Err(GpuError::NoShaderF16 {
                adapter: adapter.get_info().name,
            });
        }
        features |= wgpu::Features::SHADER_F16;
    }
    // The tensor cores: only half-precision kernels use them (the D-CNN's
    // cooperative-matrix path), and only where the adapter lists the shape
    // they use; so a device with the feature is one that has the shape.
    let coop = wgpu::Features::EXPERIMENTAL_COOPERATIVE_MATRIX | wgpu::Features::SUBGROUP;
    let experimental = if shader_f16
        && adapter.features().contains(coop)
        && lists_coop_shape(&adapter.cooperative_matrix_properties())
    {
        features |= coop;
        experimental_features()
    } else {
        wgpu::ExperimentalFeatures::disabled()
    };
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("nedrt"),
        required_features: features,
        required_limits: adapter.limits(),
        experimental_features: experimental,
        ..Default::default()
    }))
    .map_err(|e| GpuError::RequestDevice(e.to_string()))?;
    Ok((adapter, device, queue))
}

/// The cooperative-matrix shape nedrt's kernels use: M = N = K = 16, f16
/// inputs, f32 accumulators (the D-CNN's `shaders/conv_coop.wgsl`).
pub const COOP_SHAPE: (u32, u32, u32) = (16, 16, 16);

/// Whether `properties` (an adapter's) list [`COOP_SHAPE`] with f16 inputs
/// and f32 accumulators.
pub fn lists_coop_shape(properties: &[wgpu::wgt::CooperativeMatrixProperties]) -> bool {
    use wgpu::wgt::CooperativeScalarType as S;
    properties.iter().any(|p| {
        (p.m_size, p.n_size, p.k_size) == COOP_SHAPE && p.ab_type == S::F16 && p.cr_type == S::F32
    })
}

/// wgpu's token for its experimental features, here only cooperative
/// matrices.
#[allow(unsafe_code)]
fn experimental_features() -> wgpu::ExperimentalFeatures {
    // SAFETY: the token is the caller's acknowledgement that an experimental
    // feature may have bugs in wgpu; it touches no memory itself. The one
    // experimental feature requested with it, cooperative matrices, runs
    // only in kernels that naga validates (tests build every variant), on
    // shapes the adapter lists, and its results are checked against the
    // tiled kernels by the device check (docs/inference.md).
    unsafe { wgpu::ExperimentalFeatures::enabled() }
}

/// Maps `buffer` for reading and waits for the GPU, which also completes
/// any mapping requested before; `Err` says what failed.
pub fn map_and_wait(device: &wgpu::Device, buffer: &wgpu::Buffer) -> Result<(), GpuError> {
    let (tx, rx) = std::sync::mpsc::channel();
    buffer.slice(..).map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| GpuError::DeviceLost(format!("waiting for the GPU: {e}")))?;
    rx.recv()
        .map_err(|_| GpuError::DeviceLost("the GPU never answered".into()))?
        .map_err(|e| GpuError::Map(e.to_string()))
}

/// What a buffer mapped for reading holds (after [`map_and_wait`], or a
/// `map_async` and a wait), passed through `read`; then unmaps it, so the
/// buffer can be mapped again. `Err` if it is not mapped.
pub fn read_mapped<T>(buffer: &wgpu::Buffer, read: impl FnOnce(&[u8]) -> T) -> Result<T, GpuError> {
    let out = {
        let view = buffer
            .slice(..)
            .get_mapped_range()
            .map_err(|e| GpuError::Map(e.to_string()))?;
        read(&view)
    };
    buffer.unmap();
    Ok(out)
}

/// The device for a test that needs one: no adapter is a failure (such
/// tests are `#[ignore = "needs a GPU"]`, so they run only when asked for).
pub fn test_device(shader_f16: bool) -> (wgpu::Device, wgpu::Queue) {
    match open_device(&GpuSettings::default(), shader_f16) {
        Ok((_, d, q)) => (d, q),
        Err(e) => panic!("this test needs a GPU adapter and found none: {e}"),
    }
}

/// Preprocessing that runs on a wgpu device from one device buffer into
/// another, so that a frame need not leave the GPU between the client's
/// upload and the panel (the D-CNN on the wgpu backend). The service owns
/// both buffers and submits; a stage only records.
pub trait DeviceStage: Send + std::fmt::Debug {
    /// For reports: "D-CNN models/dcnn.onnx on wgpu f32 on …".
    fn describe(&self) -> String;
    /// Records into `encoder` the display image of the frame in `input`
    /// written to `output`. Both hold three f32 planes of `width`×`height`,
    /// row-major, planes `width * height` values apart; `output` need not be
    /// clamped (the encode clamps). Every buffer the stage needs per frame
    /// size is made on the first call for that size, none per frame.
    fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError>;

    /// Makes what [`DeviceStage::record`] makes on its first frame of this
    /// size between these buffers (pipelines compiled, buffers and bind
    /// groups), recording nothing, so that the first frame a client sends
    /// does not pay for it: a network's first frame took 1343 ms on the
    /// H200, the next ones 8–11 ms, and planned the frames after it seconds
    /// ahead (docs/service.md, "The warm-up"). Nothing, by default.
    fn warm_up(
        &mut self,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        let _ = (input, output, width, height);
        Ok(())
    }

    /// Whether the next frame would leave the stage unchanged (a ladder
    /// at its level of no work): the frame path then shows its input and
    /// records nothing for it, not even a copy. No, by default; a stage
    /// that wraps another answers for itself (a fault injection still
    /// counts its frames).
    fn passes_through(&self) -> bool {
        false
    }
}

/// Two device stages one after the other, through a buffer of the
/// frame's size made on the first frame of that size (the Wiener prefilter
/// in front of a network trained on its output).
#[derive(Debug)]
pub struct Chain {
    device: wgpu::Device,
    first: Box<dyn DeviceStage>,
    second: Box<dyn DeviceStage>,
    /// The middle buffer and the size it was made for.
    middle: Option<(usize, usize, wgpu::Buffer)>,
}

impl Chain {
    pub fn new(
        device: &wgpu::Device,
        first: Box<dyn DeviceStage>,
        second: Box<dyn DeviceStage>,
    ) -> Self {
        Self {
            device: device.clone(),
            first,
            second,
            middle: None,
        }
    }
}

impl DeviceStage for Chain {
    fn describe(&self) -> String {
        format!("{}, then {}", self.first.describe(), self.second.describe())
    }

    fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        let middle = self.middle(width, height);
        self.first.record(encoder, input, &middle, width, height)?;
        self.second.record(encoder, &middle, output, width, height)
    }

    fn warm_up(
        &mut self,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        let middle = self.middle(width, height);
        self.first.warm_up(input, &middle, width, height)?;
        self.second.warm_up(&middle, output, width, height)
    }
}

impl Chain {
    /// The middle buffer for a `width`×`height` frame, made on the first
    /// call for that size (a handle: the stages bind the same buffer).
    fn middle(&mut self, width: usize, height: usize) -> wgpu::Buffer {
        match &self.middle {
            Some((w, h, buffer)) if (*w, *h) == (width, height) => buffer.clone(),
            _ => {
                let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("chain middle"),
                    size: 3 * (width * height) as u64 * 4,
                    usage: wgpu::BufferUsages::STORAGE,
                    mapped_at_creation: false,
                });
                self.middle = Some((width, height, buffer.clone()));
                buffer
            }
        }
    }
}

/// Threads per workgroup of nedrt's one-dimensional kernels.
pub const WORKGROUP: u32 = 64;
/// The most workgroups a dispatch takes along x.
pub const MAX_GROUPS_X: u32 = 65535;

/// Workgroups of [`WORKGROUP`] threads for `threads` threads: rows of at
/// most [`MAX_GROUPS_X`] groups, as many rows as needed (a kernel's thread
/// is x + y·65535·64).
pub fn workgroups(threads: u64) -> [u32; 2] {
    let groups = threads.div_ceil(u64::from(WORKGROUP));
    if groups <= u64::from(MAX_GROUPS_X) {
        [groups as u32, 1]
    } else {
        [
            MAX_GROUPS_X,
            groups.div_ceil(u64::from(MAX_GROUPS_X)) as u32,
        ]
    }
}

/// Waits until the GPU has finished `submission` (no data is read back).
pub fn wait_for(device: &wgpu::Device, submission: wgpu::SubmissionIndex) -> Result<(), GpuError> {
    device
        .poll(wgpu::PollType::Wait {
            submission_index: Some(submission),
            timeout: None,
        })
        .map(|_| ())
        .map_err(|e| GpuError::DeviceLost(format!("waiting for the GPU: {e}")))
}

/// Timestamp query pairs (start, end) and the buffers that bring them back:
/// one pair per timed span. Where the device has no `TIMESTAMP_QUERY`,
/// [`PassTimer::new`] gives `None`.
#[derive(Debug)]
pub struct PassTimer {
    queries: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    readback: wgpu::Buffer,
    pairs: usize,
    period_ns: f64,
}

impl PassTimer {
    /// Bytes one pair brings back to the host.
    pub const BYTES_PER_PAIR: u64 = 16;

    /// `pairs` start/end pairs, where the device has timestamp queries.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue, pairs: usize) -> Option<Self> {
        if pairs == 0 || !device.features().contains(wgpu::Features::TIMESTAMP_QUERY) {
            return None;
        }
        let buffer = |label, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: pairs as u64 * Self::BYTES_PER_PAIR,
                usage,
                mapped_at_creation: false,
            })
        };
        Some(Self {
            queries: device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: (2 * pairs) as u32,
            }),
            resolve: buffer(
                "timestamps",
                wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            ),
            readback: buffer(
                "timestamps readback",
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            ),
            pairs,
            period_ns: queue.get_timestamp_period() as f64,
        })
    }

    /// A pass timed as pair `pair` from its start to its end.
    pub fn pass(&self, pair: usize) -> wgpu::ComputePassTimestampWrites<'_> {
        self.writes(Some(2 * pair), Some(2 * pair + 1))
    }

    /// A pass whose start begins pair `pair` (its end is another pass's).
    pub fn start(&self, pair: usize) -> wgpu::ComputePassTimestampWrites<'_> {
        self.writes(Some(2 * pair), None)
    }

    /// A pass whose end ends pair `pair`.
    pub fn end(&self, pair: usize) -> wgpu::ComputePassTimestampWrites<'_> {
        self.writes(None, Some(2 * pair + 1))
    }

    fn writes(
        &self,
        start: Option<usize>,
        end: Option<usize>,
    ) -> wgpu::ComputePassTimestampWrites<'_> {
        assert!(
            start.max(end) < Some(2 * self.pairs),
            "no such timestamp pair"
        );
        wgpu::ComputePassTimestampWrites {
            query_set: &self.queries,
            beginning_of_pass_write_index: start.map(|i| i as u32),
            end_of_pass_write_index: end.map(|i| i as u32),
        }
    }

    /// Records the copy of every pair towards the host, after the timed
    /// passes, and returns the bytes it brings back.
    pub fn resolve(&self, encoder: &mut wgpu::CommandEncoder) -> u64 {
        encoder.resolve_query_set(&self.queries, 0..(2 * self.pairs) as u32, &self.resolve, 0);
        let bytes = self.pairs as u64 * Self::BYTES_PER_PAIR;
        encoder.copy_buffer_to_buffer(&self.resolve, 0, &self.readback, 0, bytes);
        bytes
    }

    /// Asks for the pairs' mapping after the submission that resolved them:
    /// the next wait for the device completes it (no wait of its own).
    pub fn map(&self) {
        self.readback
            .slice(..)
            .map_async(wgpu::MapMode::Read, |_| {});
    }

    /// Maps the pairs and waits for the device.
    pub fn map_and_wait(&self, device: &wgpu::Device) -> Result<(), GpuError> {
        map_and_wait(device, &self.readback)
    }

    /// After [`PassTimer::map`] and a wait: each pair's span, ns (0 where
    /// the device's clock ran backwards); `Err` if they are not mapped.
    pub fn spans_ns(&self) -> Result<Vec<u64>, GpuError> {
        let stamps: Vec<u64> = read_mapped(&self.readback, |bytes| {
            bytemuck::pod_collect_to_vec(&bytes[..self.pairs * Self::BYTES_PER_PAIR as usize])
        })?;
        Ok(stamps
            .chunks_exact(2)
            .map(|p| (p[1].saturating_sub(p[0]) as f64 * self.period_ns) as u64)
            .collect())
    }
}
