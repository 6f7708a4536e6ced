//! The FFT on the device, and the filter every FFT prefilter of nedrt is:
//! a frame mirrored to 2w×2h, transformed, multiplied by a spectrum that is
//! real and even (the PSFs are mirror-symmetric), transformed back and
//! cropped to its first quadrant. That is exactly a 2-D DCT-II of the w×h
//! frame, a product with the spectrum's first quadrant, and a 2-D DCT-III
//! (docs/gpu-fft.md), which this module runs with half the data and a
//! quarter of the transforms' work of the mirrored FFT:
//!
//! - `fft_pass.wgsl`: one Stockham pass of a batched complex FFT (radices
//!   2 and 4, and a generic odd DFT up to [`MAX_PRIME`]); the passes of a
//!   length's radices give its DFT in natural order;
//! - `dct_pack.wgsl` / `dct_unpack.wgsl`: real rows or columns to and from
//!   the FFT's input and output by Makhoul's reordering, two real sequences
//!   in one complex FFT, the spectrum's gain applied on the way.
//!
//! Twiddles come from tables computed in f64 on the host (WGSL's `sin` and
//! `cos` are only specified to 2⁻¹¹). Everything a frame size needs
//! (buffers, bind groups, the passes' parameters) is made once per size; a
//! frame records its dispatches and allocates nothing. CPU twins: rustfft
//! (the tests below) and the CPU prefilters (nedrt-optics' `WienerPlan`).

use std::collections::HashMap;

use crate::workgroups;

const FFT_SHADER: &str = include_str!("../../../shaders/fft_pass.wgsl");
// The two share `dct_seqs.wgsl` (the `Seqs` block and its addressing), pasted in front.
const PACK_SHADER: &str = concat!(
    include_str!("../../../shaders/dct_seqs.wgsl"),
    include_str!("../../../shaders/dct_pack.wgsl")
);
const UNPACK_SHADER: &str = concat!(
    include_str!("../../../shaders/dct_seqs.wgsl"),
    include_str!("../../../shaders/dct_unpack.wgsl")
);
/// The largest prime factor of a transform length the device FFT takes
/// (the generic DFT's registers grow with it; `fft_pass.wgsl`'s MAX_RADIX).
pub const MAX_PRIME: usize = 13;
/// Bind groups kept per cached input or output buffer.
const BIND_GROUPS_KEPT: usize = 8;

/// Why a device transform cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum FftError {
    #[error(
        "an FFT of length {n}: its prime factor {prime} is above {MAX_PRIME}, the largest radix of the device FFT"
    )]
    UnsupportedLength { n: usize, prime: usize },
    #[error("an FFT of length 0")]
    Empty,
    #[error("{what} needs {bytes} bytes in one binding; this adapter allows {limit}")]
    TooLarge {
        what: String,
        bytes: u64,
        limit: u64,
    },
    #[error("the filter's gains: {0}")]
    Gains(String),
    #[error("the device refused the FFT's pipelines: {0}")]
    Device(String),
}

/// The radices of a length, 4s first (fewest passes), then 2, 3, 5, 7, 11, 13.
pub fn radices(n: usize) -> Result<Vec<u32>, FftError> {
    if n == 0 {
        return Err(FftError::Empty);
    }
    let mut rest = n;
    let mut out = Vec::new();
    while rest.is_multiple_of(4) {
        out.push(4);
        rest /= 4;
    }
    for p in [2, 3, 5, 7, 11, 13] {
        while rest.is_multiple_of(p) {
            out.push(p as u32);
            rest /= p;
        }
    }
    if rest > 1 {
        let prime = (2..=rest).find(|d| rest.is_multiple_of(*d)).unwrap_or(rest);
        return Err(FftError::UnsupportedLength { n, prime });
    }
    Ok(out)
}

/// `fft_pass.wgsl`'s `Pass`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PassParams {
    n: u32,
    ns: u32,
    count: u32,
    elem_stride: u32,
    seq_stride: u32,
    seq_fastest: u32,
    tw_step: u32,
    inverse: u32,
    group: u32,
    plane: u32,
}

/// `dct_pack.wgsl`'s and `dct_unpack.wgsl`'s `Seqs`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SeqParams {
    n: u32,
    count: u32,
    pairs: u32,
    group: u32,
    plane: u32,
    group_stride: u32,
    elem_stride: u32,
    pair_stride: u32,
    celem_stride: u32,
    pair_fastest: u32,
    use_gain: u32,
    pad: u32,
}

/// The pipelines, compiled once per device; an FFT pass's per radix, when
/// a length first needs it.
#[derive(Debug)]
pub struct FftKernels {
    device: wgpu::Device,
    fft_layout: wgpu::BindGroupLayout,
    fft_pipeline_layout: wgpu::PipelineLayout,
    fft_module: wgpu::ShaderModule,
    fft: HashMap<u32, wgpu::ComputePipeline>,
    pack_layout: wgpu::BindGroupLayout,
    unpack_layout: wgpu::BindGroupLayout,
    dct2_pack: wgpu::ComputePipeline,
    dct3_pack: wgpu::ComputePipeline,
    dct2_unpack: wgpu::ComputePipeline,
    dct3_unpack: wgpu::ComputePipeline,
}

pub(crate) fn storage(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Runs `make` in a validation scope: a shader or pipeline the device
/// refuses is an error, not a panic later.
pub(crate) fn checked<T>(device: &wgpu::Device, make: impl FnOnce() -> T) -> Result<T, FftError> {
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let out = make();
    match pollster::block_on(scope.pop()) {
        Some(e) => Err(FftError::Device(e.to_string())),
        None => Ok(out),
    }
}

impl FftKernels {
    pub fn new(device: &wgpu::Device) -> Result<Self, FftError> {
        checked(device, || {
            let layout = |label, entries: &[wgpu::BindGroupLayoutEntry]| {
                device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some(label),
                    entries,
                })
            };
            let fft_layout = layout(
                "fft_pass",
                &[
                    storage(0, true),
                    storage(1, true),
                    storage(2, false),
                    storage(3, true),
                ],
            );
            let pack_layout = layout(
                "dct_pack",
                &[
                    storage(0, true),
                    storage(1, true),
                    storage(2, false),
                    storage(3, true),
                ],
            );
            let unpack_layout = layout(
                "dct_unpack",
                &[
                    storage(0, true),
                    storage(1, true),
                    storage(2, false),
                    storage(3, true),
                    storage(4, true),
                ],
            );
            let pipeline_layout = |label, l: &wgpu::BindGroupLayout| {
                device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some(label),
                    bind_group_layouts: &[Some(l)],
                    immediate_size: 0,
                })
            };
            let module = |label, source: &str| {
                device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(label),
                    source: wgpu::ShaderSource::Wgsl(source.into()),
                })
            };
            let pack = module("dct_pack", PACK_SHADER);
            let unpack = module("dct_unpack", UNPACK_SHADER);
            let pack_pl = pipeline_layout("dct_pack", &pack_layout);
            let unpack_pl = pipeline_layout("dct_unpack", &unpack_layout);
            let pipeline = |label, layout: &wgpu::PipelineLayout, m: &wgpu::ShaderModule| {
                device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(label),
                    layout: Some(layout),
                    module: m,
                    entry_point: Some(label),
                    compilation_options: Default::default(),
                    cache: None,
                })
            };
            Self {
                device: device.clone(),
                fft_pipeline_layout: pipeline_layout("fft_pass", &fft_layout),
                fft_layout,
                fft_module: module("fft_pass", FFT_SHADER),
                fft: HashMap::new(),
                dct2_pack: pipeline("dct2_pack", &pack_pl, &pack),
                dct3_pack: pipeline("dct3_pack", &pack_pl, &pack),
                dct2_unpack: pipeline("dct2_unpack", &unpack_pl, &unpack),
                dct3_unpack: pipeline("dct3_unpack", &unpack_pl, &unpack),
                pack_layout,
                unpack_layout,
            }
        })
    }

    /// The pass pipeline of `radix`, compiled on first use.
    fn fft_pipeline(&mut self, radix: u32) -> Result<wgpu::ComputePipeline, FftError> {
        if let Some(p) = self.fft.get(&radix) {
            return Ok(p.clone());
        }
        let constants = [("RADIX", f64::from(radix))];
        let p = checked(&self.device, || {
            self.device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some("fft_pass"),
                    layout: Some(&self.fft_pipeline_layout),
                    module: &self.fft_module,
                    entry_point: Some("main"),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants: &constants,
                        ..Default::default()
                    },
                    cache: None,
                })
        })?;
        self.fft.insert(radix, p.clone());
        Ok(p)
    }
}

/// One recorded dispatch.
#[derive(Debug)]
struct Op {
    pipeline: wgpu::ComputePipeline,
    bind: wgpu::BindGroup,
    groups: [u32; 2],
    /// For per-pass timings: what it does, and the bytes it reads and
    /// writes at least (each value once).
    what: String,
    bytes: u64,
}

fn record_ops<'a>(pass: &mut wgpu::ComputePass<'_>, ops: impl IntoIterator<Item = &'a Op>) {
    for op in ops {
        pass.set_pipeline(&op.pipeline);
        pass.set_bind_group(0, &op.bind, &[]);
        pass.dispatch_workgroups(op.groups[0], op.groups[1], 1);
    }
}

fn complex_table(n: usize, angle: impl Fn(usize) -> f64) -> Vec<f32> {
    (0..n)
        .flat_map(|m| {
            let a = angle(m);
            [a.cos() as f32, a.sin() as f32]
        })
        .collect()
}

pub(crate) fn init_buffer(device: &wgpu::Device, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: bytes,
        usage: wgpu::BufferUsages::STORAGE,
    })
}

/// The tables of one transform length: e^{−2πim/N} (the passes) and
/// e^{−iπk/(2N)} (the DCT's quarter-sample shift), m, k < N.
#[derive(Debug)]
struct Tables {
    n: usize,
    radices: Vec<u32>,
    twiddle: wgpu::Buffer,
    quarter: wgpu::Buffer,
}

impl Tables {
    fn new(device: &wgpu::Device, n: usize) -> Result<Self, FftError> {
        let radices = radices(n)?;
        let tau = std::f64::consts::TAU;
        let twiddle = complex_table(n, |m| -tau * m as f64 / n as f64);
        let quarter = complex_table(n, |k| -std::f64::consts::PI * k as f64 / (2 * n) as f64);
        Ok(Self {
            n,
            radices,
            twiddle: init_buffer(device, "fft twiddles", bytemuck::cast_slice(&twiddle)),
            quarter: init_buffer(device, "dct quarter shifts", bytemuck::cast_slice(&quarter)),
        })
    }
}

/// A batch of complex sequences in a buffer: sequence s, element j at
/// `(s / group)·plane + (s % group)·seq_stride + j·elem_stride` (complex
/// values).
#[derive(Debug, Clone, Copy)]
struct Layout {
    count: u32,
    elem_stride: u32,
    seq_stride: u32,
    group: u32,
    plane: u32,
    seq_fastest: bool,
}

/// The passes of a batched FFT ping-ponging `a` and `b` (input in `a`);
/// returns them and whether the result ends in `b`.
fn fft_ops(
    kernels: &mut FftKernels,
    tables: &Tables,
    layout: Layout,
    inverse: bool,
    a: &wgpu::Buffer,
    b: &wgpu::Buffer,
) -> Result<(Vec<Op>, bool), FftError> {
    let device = kernels.device.clone();
    let n = tables.n as u32;
    let mut ns = 1u32;
    let mut in_b = false;
    let mut ops = Vec::new();
    for &radix in &tables.radices {
        let params = PassParams {
            n,
            ns,
            count: layout.count,
            elem_stride: layout.elem_stride,
            seq_stride: layout.seq_stride,
            seq_fastest: u32::from(layout.seq_fastest),
            tw_step: n / (ns * radix),
            inverse: u32::from(inverse),
            group: layout.group,
            plane: layout.plane,
        };
        let params = init_buffer(&device, "fft pass", bytemuck::bytes_of(&params));
        let (src, dst) = if in_b { (b, a) } else { (a, b) };
        let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("fft_pass"),
            layout: &kernels.fft_layout,
            entries: &[
                entry(0, &params),
                entry(1, src),
                entry(2, dst),
                entry(3, &tables.twiddle),
            ],
        });
        ops.push(Op {
            pipeline: kernels.fft_pipeline(radix)?,
            bind,
            groups: workgroups(u64::from(n / radix) * u64::from(layout.count)),
            what: format!(
                "{} FFT pass, radix {radix}, {} sequences of {n}",
                if inverse { "inverse" } else { "forward" },
                layout.count
            ),
            bytes: 2 * 8 * u64::from(n) * u64::from(layout.count),
        });
        ns *= radix;
        in_b = !in_b;
    }
    Ok((ops, in_b))
}

fn entry(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: buffer.as_entire_binding(),
    }
}

/// A batched 2-D complex FFT of `rows`×`cols` arrays on the device: the
/// transform over each row, then over each column, in place between two
/// buffers of `batch`·rows·cols complex values (interleaved f32 pairs).
/// Tests and benchmarks hold it against rustfft; the prefilters use the
/// DCT filter below, which needs a quarter of its work.
#[derive(Debug)]
pub struct ComplexFft2d {
    forward: Vec<Op>,
    inverse: Vec<Op>,
    /// Whether each direction's result ends in the second buffer.
    forward_in_b: bool,
    inverse_in_b: bool,
}

impl ComplexFft2d {
    /// The passes over `a` (the data) and `b` (scratch), each at least
    /// `batch`·`rows`·`cols`·8 bytes.
    pub fn new(
        kernels: &mut FftKernels,
        cols: usize,
        rows: usize,
        batch: usize,
        a: &wgpu::Buffer,
        b: &wgpu::Buffer,
    ) -> Result<Self, FftError> {
        let device = kernels.device.clone();
        let bytes = (batch * rows * cols * 8) as u64;
        check_binding(&device, "the 2-D FFT's data", bytes)?;
        for buf in [a, b] {
            if buf.size() < bytes {
                return Err(FftError::TooLarge {
                    what: "the 2-D FFT's data".into(),
                    bytes,
                    limit: buf.size(),
                });
            }
        }
        let row_tables = Tables::new(&device, cols)?;
        let col_tables = Tables::new(&device, rows)?;
        let (r, c) = (rows as u32, cols as u32);
        let row_layout = Layout {
            count: batch as u32 * r,
            elem_stride: 1,
            seq_stride: c,
            group: batch as u32 * r,
            plane: 0,
            seq_fastest: false,
        };
        // Columns: sequence s = (array, column); adjacent threads take
        // adjacent columns, so their reads are contiguous.
        let col_layout = Layout {
            count: batch as u32 * c,
            elem_stride: c,
            seq_stride: 1,
            group: c,
            plane: r * c,
            seq_fastest: true,
        };
        let mut made = Vec::new();
        for inverse in [false, true] {
            let (mut ops, rows_in_b) = fft_ops(kernels, &row_tables, row_layout, inverse, a, b)?;
            let (first, second) = if rows_in_b { (b, a) } else { (a, b) };
            let (col_ops, in_second) =
                fft_ops(kernels, &col_tables, col_layout, inverse, first, second)?;
            ops.extend(col_ops);
            made.push((ops, rows_in_b != in_second));
        }
        let [(forward, forward_in_b), (inverse, inverse_in_b)]: [(Vec<Op>, bool); 2] = made
            .try_into()
            .map_err(|_| FftError::Device("two directions expected".into()))?;
        Ok(Self {
            forward,
            inverse,
            forward_in_b,
            inverse_in_b,
        })
    }

    /// Records the transform (`inverse`: e^{+…}, unscaled) of the data in
    /// `a`; returns whether the result is in `b`.
    pub fn record(&self, encoder: &mut wgpu::CommandEncoder, inverse: bool) -> bool {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("fft 2-D"),
            timestamp_writes: None,
        });
        if inverse {
            record_ops(&mut pass, &self.inverse);
            self.inverse_in_b
        } else {
            record_ops(&mut pass, &self.forward);
            self.forward_in_b
        }
    }
}

fn check_binding(device: &wgpu::Device, what: &str, bytes: u64) -> Result<(), FftError> {
    let limit = device
        .limits()
        .max_storage_buffer_binding_size
        .min(u64::from(u32::MAX));
    if bytes > limit {
        return Err(FftError::TooLarge {
            what: what.into(),
            bytes,
            limit,
        });
    }
    Ok(())
}

/// The real sequences of one axis of `channels` planes of `width`×`height`
/// values (planes `width·height` apart), and where their pairs go in the
/// complex buffer: rows in rows, columns with adjacent pairs adjacent.
fn axis(width: usize, height: usize, channels: usize, columns: bool, use_gain: bool) -> SeqParams {
    let (w, h, c) = (width as u32, height as u32, channels as u32);
    let plane = w * h;
    if columns {
        let count = c * w;
        let pairs = count.div_ceil(2);
        SeqParams {
            n: h,
            count,
            pairs,
            group: w,
            plane,
            group_stride: 1,
            elem_stride: w,
            pair_stride: 1,
            celem_stride: pairs,
            pair_fastest: 1,
            use_gain: u32::from(use_gain),
            pad: 0,
        }
    } else {
        let count = c * h;
        SeqParams {
            n: w,
            count,
            pairs: count.div_ceil(2),
            group: h,
            plane,
            group_stride: w,
            elem_stride: 1,
            pair_stride: w,
            celem_stride: 1,
            pair_fastest: 0,
            use_gain: u32::from(use_gain),
            pad: 0,
        }
    }
}

/// Bytes a pack or unpack moves at least: the real sequences and their
/// complex pairs once each (and the gain where applied).
fn io_bytes(q: &SeqParams, gain: bool) -> u64 {
    let real = 4 * u64::from(q.count) * u64::from(q.n);
    real * (1 + u64::from(gain)) + 8 * u64::from(q.pairs) * u64::from(q.n)
}

/// `ops` named for their axis ("rows: forward FFT pass, …").
fn on_axis(ops: Vec<Op>, axis: &str) -> Vec<Op> {
    ops.into_iter()
        .map(|mut o| {
            o.what = format!("{axis}: {}", o.what);
            o
        })
        .collect()
}

/// The complex layout of an axis's pairs, for its FFT.
fn pair_layout(q: &SeqParams) -> Layout {
    if q.pair_fastest == 1 {
        Layout {
            count: q.pairs,
            elem_stride: q.pairs,
            seq_stride: 1,
            group: q.pairs,
            plane: 0,
            seq_fastest: true,
        }
    } else {
        Layout {
            count: q.pairs,
            elem_stride: 1,
            seq_stride: q.n,
            group: q.pairs,
            plane: 0,
            seq_fastest: false,
        }
    }
}

/// A real, even spectrum applied to `channels` planes of one frame size:
/// out = DCT-III(gain · DCT-II(in)) per plane (both unnormalised; the
/// inverse carries 1/(w·h)), i.e. the mirrored frame's circular
/// convolution with the spectrum's kernel, cropped. `gains` holds one
/// plane of `height` rows of `width` values per channel, indexed by the
/// DCT's (ky, kx): the mirrored 2w×2h grid's spectrum at (ky, kx).
#[derive(Debug)]
pub struct DctFilter {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    /// Between the input's rows transform and the output's: up to the
    /// gain, the gain (one op per set), after it.
    before_gain: Vec<Op>,
    gain_ops: Vec<Op>,
    middle: Vec<Op>,
    /// The first dispatch reads the input, the last writes the output:
    /// their bind groups per buffer (the service's pool holds a few).
    first: (wgpu::ComputePipeline, SeqParamsBuffer, [u32; 2], u64),
    last: (wgpu::ComputePipeline, SeqParamsBuffer, [u32; 2], u64),
    row_inverse: Vec<Op>,
    inputs: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
    outputs: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
    pack_layout: wgpu::BindGroupLayout,
    unpack_layout: wgpu::BindGroupLayout,
    device: wgpu::Device,
    /// The rows' complex result (forward) and input (inverse), and the
    /// rows' quarter table, for the input's and output's bind groups.
    rows_a: wgpu::Buffer,
    rows_out: wgpu::Buffer,
    row_quarter: wgpu::Buffer,
    dummy_gain: wgpu::Buffer,
}

/// A `Seqs` block on the device.
#[derive(Debug, Clone)]
struct SeqParamsBuffer(wgpu::Buffer);

impl DctFilter {
    /// Prepares the filter for `width`×`height` frames of `channels`
    /// planes, with `gains` (see the type).
    pub fn new(
        kernels: &mut FftKernels,
        width: usize,
        height: usize,
        gains: &[Vec<f32>],
    ) -> Result<Self, FftError> {
        Self::with_gain_sets(kernels, width, height, &[gains])
    }

    /// The same with several sets of gains sharing the buffers and passes:
    /// [`DctFilter::record_set`] picks one per recording (the refinement's
    /// three operators).
    pub fn with_gain_sets(
        kernels: &mut FftKernels,
        width: usize,
        height: usize,
        sets: &[&[Vec<f32>]],
    ) -> Result<Self, FftError> {
        let device = kernels.device.clone();
        let Some(gains) = sets.first() else {
            return Err(FftError::Gains("no gains".into()));
        };
        let channels = gains.len();
        if sets.iter().any(|g| g.len() != channels) {
            return Err(FftError::Gains(
                "gain sets of different channel counts".into(),
            ));
        }
        if channels == 0 || width == 0 || height == 0 {
            return Err(FftError::Gains(format!(
                "{channels} channels of {width}×{height}: nothing to filter"
            )));
        }
        if let Some((c, g)) = sets
            .iter()
            .flat_map(|g| g.iter())
            .enumerate()
            .find(|(_, g)| g.len() != width * height)
        {
            return Err(FftError::Gains(format!(
                "channel {c} has {} values, a {width}×{height} frame needs {}",
                g.len(),
                width * height
            )));
        }
        if sets
            .iter()
            .flat_map(|g| g.iter())
            .flatten()
            .any(|v| !v.is_finite())
        {
            return Err(FftError::Gains("a gain is not finite".into()));
        }
        let real_bytes = (channels * width * height * 4) as u64;
        let rows_q = axis(width, height, channels, false, false);
        let cols_q = axis(width, height, channels, true, false);
        let cplx_bytes = 8 * u64::from((rows_q.pairs * rows_q.n).max(cols_q.pairs * cols_q.n));
        check_binding(&device, "the DCT filter's complex data", cplx_bytes)?;
        check_binding(&device, "the frame's planes", real_bytes)?;
        let storage_buffer = |label, size| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            })
        };
        let cx_a = storage_buffer("dct complex a", cplx_bytes);
        let cx_b = storage_buffer("dct complex b", cplx_bytes);
        let tmp = storage_buffer("dct planes", real_bytes);
        let gains: Vec<wgpu::Buffer> = sets
            .iter()
            .map(|g| {
                let flat: Vec<f32> = g.iter().flatten().copied().collect();
                init_buffer(&device, "dct gains", bytemuck::cast_slice(&flat))
            })
            .collect();
        let dummy_gain = init_buffer(&device, "no gains", &[0u8; 16]);
        let row_tables = Tables::new(&device, width)?;
        let col_tables = Tables::new(&device, height)?;
        let params = |q: SeqParams| {
            SeqParamsBuffer(init_buffer(&device, "dct axis", bytemuck::bytes_of(&q)))
        };
        let groups = |q: &SeqParams| workgroups(u64::from(q.pairs) * u64::from(q.n));
        let (pack_layout, unpack_layout) =
            (kernels.pack_layout.clone(), kernels.unpack_layout.clone());
        let (dct2_pack, dct3_pack) = (kernels.dct2_pack.clone(), kernels.dct3_pack.clone());
        let (dct2_unpack, dct3_unpack) = (kernels.dct2_unpack.clone(), kernels.dct3_unpack.clone());
        let pack = |q: &SeqParamsBuffer,
                    real: &wgpu::Buffer,
                    cx: &wgpu::Buffer,
                    quarter: &wgpu::Buffer| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("dct_pack"),
                layout: &pack_layout,
                entries: &[
                    entry(0, &q.0),
                    entry(1, real),
                    entry(2, cx),
                    entry(3, quarter),
                ],
            })
        };
        let unpack = |q: &SeqParamsBuffer,
                      cx: &wgpu::Buffer,
                      real: &wgpu::Buffer,
                      quarter: &wgpu::Buffer,
                      gain: &wgpu::Buffer| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("dct_unpack"),
                layout: &unpack_layout,
                entries: &[
                    entry(0, &q.0),
                    entry(1, cx),
                    entry(2, real),
                    entry(3, quarter),
                    entry(4, gain),
                ],
            })
        };
        let rows_p = params(rows_q);
        let cols_p = params(cols_q);
        let cols_gain_p = params(axis(width, height, channels, true, true));
        // Rows, forward: (input →) cx_a → FFT → unpack → tmp.
        let (row_fwd, in_b) = fft_ops(
            kernels,
            &row_tables,
            pair_layout(&rows_q),
            false,
            &cx_a,
            &cx_b,
        )?;
        let row_fwd = on_axis(row_fwd, "rows");
        let rows_out = if in_b { cx_b.clone() } else { cx_a.clone() };
        let mut middle = row_fwd;
        middle.push(Op {
            pipeline: dct2_unpack.clone(),
            bind: unpack(&rows_p, &rows_out, &tmp, &row_tables.quarter, &dummy_gain),
            groups: groups(&rows_q),
            what: "rows: DCT-II unpack".into(),
            bytes: io_bytes(&rows_q, false),
        });
        // Columns, forward with the gain, then inverse: tmp → tmp.
        middle.push(Op {
            pipeline: dct2_pack.clone(),
            bind: pack(&cols_p, &tmp, &cx_a, &col_tables.quarter),
            groups: groups(&cols_q),
            what: "columns: DCT-II pack".into(),
            bytes: io_bytes(&cols_q, false),
        });
        let (col_fwd, in_b) = fft_ops(
            kernels,
            &col_tables,
            pair_layout(&cols_q),
            false,
            &cx_a,
            &cx_b,
        )?;
        let col_fwd = on_axis(col_fwd, "columns");
        middle.extend(col_fwd);
        let gain_ops = gains
            .iter()
            .map(|gain| Op {
                pipeline: dct2_unpack.clone(),
                bind: unpack(
                    &cols_gain_p,
                    if in_b { &cx_b } else { &cx_a },
                    &tmp,
                    &col_tables.quarter,
                    gain,
                ),
                groups: groups(&cols_q),
                what: "columns: DCT-II unpack × gain".into(),
                bytes: io_bytes(&cols_q, true),
            })
            .collect();
        let before_gain = std::mem::take(&mut middle);
        middle.push(Op {
            pipeline: dct3_pack.clone(),
            bind: pack(&cols_p, &tmp, &cx_a, &col_tables.quarter),
            groups: groups(&cols_q),
            what: "columns: DCT-III pack".into(),
            bytes: io_bytes(&cols_q, false),
        });
        let (col_inv, in_b) = fft_ops(
            kernels,
            &col_tables,
            pair_layout(&cols_q),
            true,
            &cx_a,
            &cx_b,
        )?;
        let col_inv = on_axis(col_inv, "columns");
        middle.extend(col_inv);
        middle.push(Op {
            pipeline: dct3_unpack.clone(),
            bind: unpack(
                &cols_p,
                if in_b { &cx_b } else { &cx_a },
                &tmp,
                &col_tables.quarter,
                &dummy_gain,
            ),
            groups: groups(&cols_q),
            what: "columns: DCT-III unpack".into(),
            bytes: io_bytes(&cols_q, false),
        });
        // Rows, inverse: tmp → cx_a → IFFT → (unpack → output).
        middle.push(Op {
            pipeline: dct3_pack.clone(),
            bind: pack(&rows_p, &tmp, &cx_a, &row_tables.quarter),
            groups: groups(&rows_q),
            what: "rows: DCT-III pack".into(),
            bytes: io_bytes(&rows_q, false),
        });
        let (row_inv, in_b) = fft_ops(
            kernels,
            &row_tables,
            pair_layout(&rows_q),
            true,
            &cx_a,
            &cx_b,
        )?;
        let row_inv = on_axis(row_inv, "rows");
        let rows_back = if in_b { cx_b.clone() } else { cx_a.clone() };
        Ok(Self {
            width,
            height,
            channels,
            before_gain,
            gain_ops,
            middle,
            first: (
                dct2_pack,
                rows_p.clone(),
                groups(&rows_q),
                io_bytes(&rows_q, false),
            ),
            last: (
                dct3_unpack,
                rows_p,
                groups(&rows_q),
                io_bytes(&rows_q, false),
            ),
            row_inverse: row_inv,
            inputs: Vec::new(),
            outputs: Vec::new(),
            pack_layout,
            unpack_layout,
            device,
            rows_a: cx_a,
            rows_out: rows_back,
            row_quarter: row_tables.quarter,
            dummy_gain,
        })
    }

    /// Bytes the filter moves through device memory per frame at least:
    /// every dispatch reads and writes its data once (the floor of
    /// docs/benchmarks.md's bytes-over-bandwidth).
    pub fn bytes_per_frame(&self) -> u64 {
        self.passes(0).iter().map(|(_, b)| b).sum()
    }

    /// Each dispatch of a frame with gain set `set`, in order: what it
    /// does and the bytes it moves at least.
    pub fn passes(&self, set: usize) -> Vec<(String, u64)> {
        let first = ("rows: DCT-II pack (the input)".to_string(), self.first.3);
        let last = ("rows: DCT-III unpack (the output)".to_string(), self.last.3);
        std::iter::once(first)
            .chain(
                self.before_gain
                    .iter()
                    .chain(self.gain_ops.get(set))
                    .chain(&self.middle)
                    .chain(&self.row_inverse)
                    .map(|o| (o.what.clone(), o.bytes)),
            )
            .chain(std::iter::once(last))
            .collect()
    }

    /// As [`DctFilter::record`], each dispatch in a compute pass of its own
    /// between two of `timer`'s timestamps (pair i for dispatch i of
    /// [`DctFilter::passes`]); the timer needs that many pairs.
    pub fn record_timed(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        timer: &crate::PassTimer,
    ) -> Result<(), FftError> {
        let first = self.input_bind(input);
        let last = self.output_bind(output);
        let mut steps: Vec<(&wgpu::ComputePipeline, &wgpu::BindGroup, [u32; 2])> =
            vec![(&self.first.0, &first, self.first.2)];
        steps.extend(
            self.before_gain
                .iter()
                .chain(self.gain_ops.first())
                .chain(&self.middle)
                .chain(&self.row_inverse)
                .map(|o| (&o.pipeline, &o.bind, o.groups)),
        );
        steps.push((&self.last.0, &last, self.last.2));
        for (i, (pipeline, bind, groups)) in steps.into_iter().enumerate() {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("dct filter pass"),
                timestamp_writes: Some(timer.pass(i)),
            });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, bind, &[]);
            pass.dispatch_workgroups(groups[0], groups[1], 1);
        }
        Ok(())
    }

    /// Records the filter of the frame in `input` into `output` (each
    /// `channels` planes of width·height f32, planes width·height apart).
    pub fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
    ) -> Result<(), FftError> {
        self.record_set(encoder, input, output, 0)
    }

    /// As [`DctFilter::record`], with gain set `set`.
    pub fn record_set(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        set: usize,
    ) -> Result<(), FftError> {
        if set >= self.gain_ops.len() {
            return Err(FftError::Gains(format!("no gain set {set}")));
        }
        let need = (self.channels * self.width * self.height * 4) as u64;
        for (what, b) in [("input", input), ("output", output)] {
            if b.size() < need {
                return Err(FftError::TooLarge {
                    what: format!("the filter's {what} buffer"),
                    bytes: need,
                    limit: b.size(),
                });
            }
        }
        let first = self.input_bind(input);
        let last = self.output_bind(output);
        let gain_op = &self.gain_ops[set];
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("dct filter"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.first.0);
        pass.set_bind_group(0, &first, &[]);
        pass.dispatch_workgroups(self.first.2[0], self.first.2[1], 1);
        record_ops(
            &mut pass,
            self.before_gain
                .iter()
                .chain(std::iter::once(gain_op))
                .chain(&self.middle)
                .chain(&self.row_inverse),
        );
        pass.set_pipeline(&self.last.0);
        pass.set_bind_group(0, &last, &[]);
        pass.dispatch_workgroups(self.last.2[0], self.last.2[1], 1);
        Ok(())
    }

    fn input_bind(&mut self, input: &wgpu::Buffer) -> wgpu::BindGroup {
        if let Some((_, g)) = self.inputs.iter().find(|(b, _)| b == input) {
            return g.clone();
        }
        let g = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("dct_pack input"),
            layout: &self.pack_layout,
            entries: &[
                entry(0, &self.first.1.0),
                entry(1, input),
                entry(2, &self.rows_a),
                entry(3, &self.row_quarter),
            ],
        });
        if self.inputs.len() == BIND_GROUPS_KEPT {
            self.inputs.remove(0);
        }
        self.inputs.push((input.clone(), g.clone()));
        g
    }

    fn output_bind(&mut self, output: &wgpu::Buffer) -> wgpu::BindGroup {
        if let Some((_, g)) = self.outputs.iter().find(|(b, _)| b == output) {
            return g.clone();
        }
        let g = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("dct_unpack output"),
            layout: &self.unpack_layout,
            entries: &[
                entry(0, &self.last.1.0),
                entry(1, &self.rows_out),
                entry(2, output),
                entry(3, &self.row_quarter),
                entry(4, &self.dummy_gain),
            ],
        });
        if self.outputs.len() == BIND_GROUPS_KEPT {
            self.outputs.remove(0);
        }
        self.outputs.push((output.clone(), g.clone()));
        g
    }
}

/// Why a stage's host-side terms (gains, refinement terms) could not be
/// made: the caller's own error, boxed.
pub type TermsError = Box<dyn std::error::Error + Send + Sync>;

/// The gains of a frame size: `channels` planes of height×width (see
/// [`DctFilter`]), or why they cannot be made.
pub type GainsFor = Box<dyn FnMut(usize, usize) -> Result<Vec<Vec<f32>>, TermsError> + Send>;

/// A [`DctFilter`] as a [`crate::DeviceStage`]: the gains of each frame size
/// computed on the host once (`gains_for`), uploaded once; a frame records
/// the filter. The linear prefilters (the Wiener of every method and
/// design, the linear least-squares prefilter) on the device.
pub struct SpectralStage {
    name: String,
    kernels: FftKernels,
    gains_for: GainsFor,
    /// Filters of the sizes seen last, newest at the end.
    filters: Vec<DctFilter>,
}

impl std::fmt::Debug for SpectralStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SpectralStage")
            .field("name", &self.name)
            .field(
                "sizes",
                &self
                    .filters
                    .iter()
                    .map(|f| (f.width, f.height))
                    .collect::<Vec<_>>(),
            )
            .finish()
    }
}

/// Frame sizes whose filters a stage keeps (the service runs one).
const FILTERS_KEPT: usize = 2;

impl SpectralStage {
    /// `name` for reports ("the Wiener prefilter of doe+wiener (K = …)").
    pub fn new(device: &wgpu::Device, name: String, gains_for: GainsFor) -> Result<Self, FftError> {
        Ok(Self {
            name,
            kernels: FftKernels::new(device)?,
            gains_for,
            filters: Vec::new(),
        })
    }

    /// The filter for `width`×`height`, made on first use.
    pub fn filter(&mut self, width: usize, height: usize) -> Result<&mut DctFilter, FftError> {
        if let Some(i) = self
            .filters
            .iter()
            .position(|f| (f.width, f.height) == (width, height))
        {
            let f = self.filters.remove(i);
            self.filters.push(f);
        } else {
            let gains =
                (self.gains_for)(width, height).map_err(|e| FftError::Gains(e.to_string()))?;
            let f = DctFilter::new(&mut self.kernels, width, height, &gains)?;
            if self.filters.len() == FILTERS_KEPT {
                self.filters.remove(0);
            }
            self.filters.push(f);
        }
        self.filters
            .last_mut()
            .ok_or_else(|| FftError::Device("no filter".into()))
    }
}

impl crate::DeviceStage for SpectralStage {
    fn describe(&self) -> String {
        format!("{} on the device (DCT-II · gain · DCT-III)", self.name)
    }

    fn record(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<(), crate::GpuError> {
        self.filter(width, height)
            .and_then(|f| f.record(encoder, input, output))
            .map_err(crate::GpuError::from)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lengths_factor_into_the_kernels_radices_or_are_refused_by_name() {
        assert_eq!(radices(3840).ok(), Some(vec![4, 4, 4, 4, 3, 5]));
        assert_eq!(radices(1080).ok(), Some(vec![4, 2, 3, 3, 3, 5]));
        assert_eq!(radices(1).ok(), Some(vec![]));
        assert_eq!(radices(7 * 8).ok(), Some(vec![4, 2, 7]));
        for (n, p) in [(17, 17), (2 * 1031, 1031), (3 * 19 * 19, 19)] {
            match radices(n) {
                Err(FftError::UnsupportedLength { n: m, prime }) => assert_eq!((m, prime), (n, p)),
                other => panic!("{n}: {other:?}"),
            }
        }
        assert!(matches!(radices(0), Err(FftError::Empty)));
        let e = radices(34).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(e.contains("34") && e.contains("17"), "{e}");
    }

    /// The field names of a WGSL struct, in order.
    fn wgsl_fields(source: &str, name: &str) -> Vec<String> {
        let start = source.find(&format!("struct {name} {{")).expect("struct");
        source[start..]
            .lines()
            .skip(1)
            .map(|l| l.split("//").next().unwrap_or("").trim())
            .take_while(|l| *l != "}")
            .filter_map(|l| l.split_once(':').map(|(f, _)| f.trim().to_string()))
            .collect()
    }

    #[test]
    fn the_shaders_parameter_blocks_are_the_rust_structs() {
        // Field for field, u32 each: a field added on one side only fails here.
        let pass = [
            "n",
            "ns",
            "count",
            "elem_stride",
            "seq_stride",
            "seq_fastest",
            "tw_step",
            "inverse",
            "group",
            "plane",
        ];
        assert_eq!(wgsl_fields(FFT_SHADER, "Pass"), pass);
        assert_eq!(std::mem::size_of::<PassParams>(), 4 * pass.len());
        let seqs = [
            "n",
            "count",
            "pairs",
            "group",
            "plane",
            "group_stride",
            "elem_stride",
            "pair_stride",
            "celem_stride",
            "pair_fastest",
            "use_gain",
            "pad",
        ];
        for shader in [PACK_SHADER, UNPACK_SHADER] {
            assert_eq!(wgsl_fields(shader, "Seqs"), seqs);
        }
        assert_eq!(std::mem::size_of::<SeqParams>(), 4 * seqs.len());
        // The Rust side, by a value with every field distinct.
        let q = SeqParams {
            n: 0,
            count: 1,
            pairs: 2,
            group: 3,
            plane: 4,
            group_stride: 5,
            elem_stride: 6,
            pair_stride: 7,
            celem_stride: 8,
            pair_fastest: 9,
            use_gain: 10,
            pad: 11,
        };
        assert_eq!(
            bytemuck::cast::<SeqParams, [u32; 12]>(q),
            [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]
        );
        let p = PassParams {
            n: 0,
            ns: 1,
            count: 2,
            elem_stride: 3,
            seq_stride: 4,
            seq_fastest: 5,
            tw_step: 6,
            inverse: 7,
            group: 8,
            plane: 9,
        };
        assert_eq!(
            bytemuck::cast::<PassParams, [u32; 10]>(p),
            [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
        );
    }

    mod needs_gpu {
        use super::super::*;
        use num_complex::Complex32 as c32;
        use rustfft::FftPlanner;
        use wgpu::util::DeviceExt;

        /// A deterministic, non-trivial signal (no zeros, no symmetry).
        fn signal(n: usize, seed: u64) -> Vec<f32> {
            let mut x = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (0..n)
                .map(|_| {
                    x = x
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    ((x >> 40) as f32 / (1u64 << 24) as f32) - 0.5
                })
                .collect()
        }

        fn read(
            device: &wgpu::Device,
            queue: &wgpu::Queue,
            buf: &wgpu::Buffer,
            bytes: u64,
        ) -> Vec<f32> {
            let host = device.create_buffer(&wgpu::BufferDescriptor {
                label: None,
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut enc = device.create_command_encoder(&Default::default());
            enc.copy_buffer_to_buffer(buf, 0, &host, 0, bytes);
            queue.submit([enc.finish()]);
            crate::map_and_wait(device, &host).expect("read-back");
            crate::read_mapped(&host, |b| bytemuck::cast_slice::<u8, f32>(b).to_vec())
                .expect("mapped")
        }

        fn data_buffer(
            device: &wgpu::Device,
            data: &[f32],
            extra: wgpu::BufferUsages,
        ) -> wgpu::Buffer {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: None,
                contents: bytemuck::cast_slice(data),
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | extra,
            })
        }

        /// rustfft's 2-D transform of row-major `rows`×`cols` complex data.
        fn cpu_fft2(data: &[c32], cols: usize, rows: usize, inverse: bool) -> Vec<c32> {
            let mut planner = FftPlanner::<f32>::new();
            let (rf, cf) = if inverse {
                (
                    planner.plan_fft_inverse(cols),
                    planner.plan_fft_inverse(rows),
                )
            } else {
                (
                    planner.plan_fft_forward(cols),
                    planner.plan_fft_forward(rows),
                )
            };
            let mut out = data.to_vec();
            for row in out.chunks_mut(cols) {
                rf.process(row);
            }
            let mut col = vec![c32::new(0.0, 0.0); rows];
            for x in 0..cols {
                for y in 0..rows {
                    col[y] = out[y * cols + x];
                }
                cf.process(&mut col);
                for y in 0..rows {
                    out[y * cols + x] = col[y];
                }
            }
            out
        }

        /// The device 2-D FFT of one random array against rustfft, both
        /// directions: the largest error over the largest magnitude.
        fn fft2_error(cols: usize, rows: usize) -> f32 {
            let (device, queue) = crate::test_device(false);
            let mut kernels = FftKernels::new(&device).expect("kernels");
            let data = signal(2 * cols * rows, (cols * 31 + rows) as u64);
            let a = data_buffer(&device, &data, wgpu::BufferUsages::COPY_DST);
            let b = data_buffer(
                &device,
                &vec![f32::NAN; data.len()],
                wgpu::BufferUsages::empty(),
            );
            let fft = ComplexFft2d::new(&mut kernels, cols, rows, 1, &a, &b).expect("plan");
            let host: Vec<c32> = data.chunks(2).map(|p| c32::new(p[0], p[1])).collect();
            let mut worst = 0.0f32;
            for inverse in [false, true] {
                let mut enc = device.create_command_encoder(&Default::default());
                // Each direction from the same input: restore it first.
                let src = data_buffer(&device, &data, wgpu::BufferUsages::empty());
                enc.copy_buffer_to_buffer(&src, 0, &a, 0, a.size());
                queue.submit([enc.finish()]);
                let mut enc = device.create_command_encoder(&Default::default());
                let in_b = fft.record(&mut enc, inverse);
                queue.submit([enc.finish()]);
                let got = read(&device, &queue, if in_b { &b } else { &a }, a.size());
                let want = cpu_fft2(&host, cols, rows, inverse);
                let peak = want.iter().map(|v| v.norm()).fold(0.0f32, f32::max);
                let err = got
                    .chunks(2)
                    .zip(&want)
                    .map(|(g, w)| (c32::new(g[0], g[1]) - w).norm())
                    .fold(
                        0.0f32,
                        |m, e| if e.is_nan() { f32::INFINITY } else { m.max(e) },
                    );
                worst = worst.max(err / peak);
            }
            worst
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn the_device_fft_equals_rustfft_at_the_prefilters_sizes() {
            // The mirrored grids of 1080p (both orientations) and 1080p
            // itself; radices 2, 3, 4, 5 and the generic 7, 11, 13.
            for (cols, rows) in [
                (3840, 2160),
                (1920, 1080),
                (2160, 3840),
                (7 * 16, 11 * 13),
                (98, 45),
            ] {
                let e = fft2_error(cols, rows);
                eprintln!(
                    "device FFT {cols}×{rows}: largest error {e:.2e} of the largest magnitude"
                );
                assert!(
                    e <= 1e-5,
                    "{cols}×{rows}: error {e:e} of the largest magnitude"
                );
            }
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn a_length_with_a_large_prime_is_refused_not_transformed() {
            let (device, _) = crate::test_device(false);
            let mut kernels = FftKernels::new(&device).expect("kernels");
            let a = data_buffer(&device, &[0.0; 2 * 17 * 8], wgpu::BufferUsages::empty());
            let b = data_buffer(&device, &[0.0; 2 * 17 * 8], wgpu::BufferUsages::empty());
            let e = ComplexFft2d::new(&mut kernels, 17, 8, 1, &a, &b).err();
            assert!(
                matches!(e, Some(FftError::UnsupportedLength { n: 17, prime: 17 })),
                "{e:?}"
            );
            let gains = vec![vec![1.0; 17 * 8]; 3];
            let e = DctFilter::new(&mut kernels, 17, 8, &gains).err();
            assert!(
                matches!(e, Some(FftError::UnsupportedLength { n: 17, prime: 17 })),
                "{e:?}"
            );
        }

        /// The mirrored-grid filter the CPU prefilters run, by rustfft:
        /// mirror each plane to 2w×2h, multiply the spectrum by the even
        /// extension of `gain`, transform back, keep the first quadrant.
        fn cpu_mirrored_filter(plane: &[f32], gain: &[f32], w: usize, h: usize) -> Vec<f32> {
            let (w2, h2) = (2 * w, 2 * h);
            let at = |x: usize, n: usize| if x < n { x } else { 2 * n - 1 - x };
            let mirrored: Vec<c32> = (0..h2 * w2)
                .map(|i| c32::new(plane[at(i / w2, h) * w + at(i % w2, w)], 0.0))
                .collect();
            let mut spec = cpu_fft2(&mirrored, w2, h2, false);
            let even = |k: usize, n: usize| if k <= n { k } else { 2 * n - k };
            for (i, s) in spec.iter_mut().enumerate() {
                let (ky, kx) = (even(i / w2, h), even(i % w2, w));
                // The Nyquist bins (k = n) meet a zero coefficient of the
                // mirrored signal; any gain does.
                let g = if ky == h || kx == w {
                    0.0
                } else {
                    gain[ky * w + kx]
                };
                *s *= g;
            }
            let back = cpu_fft2(&spec, w2, h2, true);
            let scale = 1.0 / (w2 * h2) as f32;
            (0..h * w)
                .map(|i| back[(i / w) * w2 + i % w].re * scale)
                .collect()
        }

        fn filter_error(w: usize, h: usize, channels: usize) -> f32 {
            let (device, queue) = crate::test_device(false);
            let mut kernels = FftKernels::new(&device).expect("kernels");
            let frame = signal(channels * w * h, (w * 7 + h) as u64);
            // A smooth low-pass with a sharpening bump, different per channel.
            let gains: Vec<Vec<f32>> = (0..channels)
                .map(|c| {
                    (0..w * h)
                        .map(|i| {
                            let (fy, fx) = ((i / w) as f32 / h as f32, (i % w) as f32 / w as f32);
                            let r2 = fy * fy + fx * fx;
                            (1.0 + 0.5 * c as f32 * r2) * (-3.0 * r2).exp()
                        })
                        .collect()
                })
                .collect();
            let input = data_buffer(&device, &frame, wgpu::BufferUsages::empty());
            let output = data_buffer(
                &device,
                &vec![f32::NAN; frame.len()],
                wgpu::BufferUsages::empty(),
            );
            let mut filter = DctFilter::new(&mut kernels, w, h, &gains).expect("filter");
            let mut enc = device.create_command_encoder(&Default::default());
            filter.record(&mut enc, &input, &output).expect("record");
            queue.submit([enc.finish()]);
            let got = read(&device, &queue, &output, output.size());
            let mut worst = 0.0f32;
            for c in 0..channels {
                let plane = &frame[c * w * h..(c + 1) * w * h];
                let want = cpu_mirrored_filter(plane, &gains[c], w, h);
                let peak = want.iter().map(|v| v.abs()).fold(0.0f32, f32::max);
                for (g, v) in got[c * w * h..(c + 1) * w * h].iter().zip(&want) {
                    let e = (g - v).abs();
                    worst = worst.max(if e.is_nan() { f32::INFINITY } else { e / peak });
                }
            }
            worst
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn the_dct_filter_is_the_mirrored_grid_filter() {
            // Odd and even sides, an odd number of sequences (a pair
            // with one sequence), one channel and three.
            for (w, h, c) in [(16, 12, 3), (15, 9, 1), (40, 27, 3), (7, 5, 3)] {
                let e = filter_error(w, h, c);
                eprintln!("DCT filter {w}×{h}×{c}: largest error {e:.2e} of the largest value");
                assert!(e <= 1e-5, "{w}×{h}×{c}: error {e:e} of the largest value");
            }
        }

        #[test]
        #[ignore = "needs a GPU adapter (run: scripts/test.sh, or cargo test -- --include-ignored)"]
        fn unit_gains_give_the_frame_back_and_bad_gains_are_refused() {
            let (device, queue) = crate::test_device(false);
            let mut kernels = FftKernels::new(&device).expect("kernels");
            let (w, h) = (30, 20);
            let frame = signal(3 * w * h, 9);
            let input = data_buffer(&device, &frame, wgpu::BufferUsages::empty());
            let output = data_buffer(
                &device,
                &vec![f32::NAN; frame.len()],
                wgpu::BufferUsages::empty(),
            );
            let mut filter =
                DctFilter::new(&mut kernels, w, h, &vec![vec![1.0; w * h]; 3]).expect("filter");
            let mut enc = device.create_command_encoder(&Default::default());
            filter.record(&mut enc, &input, &output).expect("record");
            queue.submit([enc.finish()]);
            let got = read(&device, &queue, &output, output.size());
            let err = got
                .iter()
                .zip(&frame)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(err < 1e-6, "{err}");
            let short = vec![vec![1.0; w * h - 1]; 3];
            assert!(matches!(
                DctFilter::new(&mut kernels, w, h, &short),
                Err(FftError::Gains(_))
            ));
            let nan = vec![vec![f32::NAN; w * h]; 3];
            assert!(matches!(
                DctFilter::new(&mut kernels, w, h, &nan),
                Err(FftError::Gains(_))
            ));
            let small = data_buffer(&device, &[0.0; 4], wgpu::BufferUsages::empty());
            let mut enc = device.create_command_encoder(&Default::default());
            assert!(matches!(
                filter.record(&mut enc, &small, &output),
                Err(FftError::TooLarge { .. })
            ));
        }
    }
}
