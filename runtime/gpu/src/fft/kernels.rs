//! The FFT's pipelines and the dispatches they record: the shaders, the
//! per-length tables, the Stockham passes of a batched FFT and the layouts
//! of the DCT's real sequences and complex pairs. Apart from the filters
//! (`complex`, `dct`) that record them: this is the plumbing they share.

use super::{FftError, FftPath, checked, init_buffer, radices, storage};
use crate::workgroups;
use std::collections::HashMap;

pub(super) const FFT_SHADER: &str = include_str!("../../../../shaders/fft_pass.wgsl");

// The two share `dct_seqs.wgsl` (the `Seqs` block and its addressing), pasted in front.
pub(super) const PACK_SHADER: &str = concat!(
    include_str!("../../../../shaders/dct_seqs.wgsl"),
    include_str!("../../../../shaders/dct_pack.wgsl")
);

pub(super) const UNPACK_SHADER: &str = concat!(
    include_str!("../../../../shaders/dct_seqs.wgsl"),
    include_str!("../../../../shaders/dct_unpack.wgsl")
);

/// `fft_pass.wgsl`'s `Pass`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct PassParams {
    pub(super) n: u32,
    pub(super) ns: u32,
    pub(super) count: u32,
    pub(super) elem_stride: u32,
    pub(super) seq_stride: u32,
    pub(super) seq_fastest: u32,
    pub(super) tw_step: u32,
    pub(super) inverse: u32,
    pub(super) group: u32,
    pub(super) plane: u32,
}

/// `dct_pack.wgsl`'s and `dct_unpack.wgsl`'s `Seqs`.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct SeqParams {
    pub(super) n: u32,
    pub(super) count: u32,
    pub(super) pairs: u32,
    pub(super) group: u32,
    pub(super) plane: u32,
    pub(super) group_stride: u32,
    pub(super) elem_stride: u32,
    pub(super) pair_stride: u32,
    pub(super) celem_stride: u32,
    pub(super) pair_fastest: u32,
    pub(super) use_gain: u32,
    pub(super) pad: u32,
}

/// The pipelines, compiled once per device; an FFT pass's per radix, when
/// a length first needs it.
#[derive(Debug)]
pub struct FftKernels {
    pub(super) device: wgpu::Device,
    pub(super) fft_layout: wgpu::BindGroupLayout,
    pub(super) fft_pipeline_layout: wgpu::PipelineLayout,
    pub(super) fft_module: wgpu::ShaderModule,
    pub(super) fft: HashMap<u32, wgpu::ComputePipeline>,
    pub(super) pack_layout: wgpu::BindGroupLayout,
    pub(super) unpack_layout: wgpu::BindGroupLayout,
    pub(super) dct2_pack: wgpu::ComputePipeline,
    pub(super) dct3_pack: wgpu::ComputePipeline,
    pub(super) dct2_unpack: wgpu::ComputePipeline,
    pub(super) dct3_unpack: wgpu::ComputePipeline,
    /// The workgroup-memory kernels: one generated module per length,
    /// its pipelines per entry point, made on first use.
    pub(super) fused_layout: wgpu::BindGroupLayout,
    pub(super) fused_pipeline_layout: wgpu::PipelineLayout,
    /// By (length, sequences a workgroup, threads a workgroup, the
    /// appended kernels' name: "" for none, [`super::fused::RowEndsSpec`]).
    pub(super) fused_modules: HashMap<(usize, u32, u32, &'static str), wgpu::ShaderModule>,
    /// By the module's key and the entry point.
    pub(super) fused: HashMap<(usize, u32, u32, &'static str, &'static str), wgpu::ComputePipeline>,
    pub(super) path: FftPath,
    /// Threads a workgroup of the generated kernels at most.
    pub(super) max_threads: u32,
    /// The workgroup-memory kernels' shape, where not the heuristics'.
    pub(super) variant: FusedVariant,
    /// The adapter's tuned shapes by frame size ([`super::tuned`]).
    pub(super) tuned: super::tuned::TunedSizes,
}

/// How the workgroup-memory kernels are cut, where not by the heuristics
/// (`nedrt bench fft --fft-variants`, issue 56 item 3): `threads` a
/// workgroup (made a multiple of its sequences, at most the adapter's
/// limit), and at most `max_seqs` sequences (pairs of real ones) a
/// workgroup, rows and columns alike, as many as fit its memory (the
/// heuristics: rows 1, columns up to 4). A variant changes which thread
/// computes a butterfly, never its arithmetic: the output is the same bit
/// for bit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct FusedVariant {
    pub threads: Option<u32>,
    pub max_seqs: Option<u32>,
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
            let (fused_layout, fused_pipeline_layout) = fused_layout(device);
            Self {
                fused_layout,
                fused_pipeline_layout,
                fused_modules: HashMap::new(),
                fused: HashMap::new(),
                path: FftPath::Auto,
                variant: FusedVariant::default(),
                tuned: super::tuned::for_adapter(&device.adapter_info()),
                // lavapipe runs a workgroup's lanes as coroutines that switch
                // at every barrier: fewer of them is faster there.
                max_threads: if device.adapter_info().device_type == wgpu::DeviceType::Cpu {
                    64
                } else {
                    256
                },
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

    /// Which kernels the filters and transforms made from now on use.
    pub fn set_path(&mut self, path: FftPath) {
        self.path = path;
    }

    /// The workgroup-memory kernels' shape for the filters made from now
    /// on ([`FusedVariant`]; the default: the heuristics').
    pub fn set_fused_variant(&mut self, variant: FusedVariant) {
        self.variant = variant;
    }

    pub fn fused_variant(&self) -> FusedVariant {
        self.variant
    }

    /// The adapter's tuned shape for `width`×`height` filters, if its
    /// table has one ([`super::tuned`]); a filter of that size made
    /// without a [`FftKernels::set_fused_variant`] runs it.
    pub fn tuned_variant(&self, width: usize, height: usize) -> Option<FusedVariant> {
        self.tuned
            .iter()
            .find(|(size, _)| *size == (width, height))
            .map(|(_, v)| *v)
    }

    /// Forgets the adapter's tuned shapes: the filters made from now on
    /// run the heuristics' (the benchmarks' and the tuner's baseline).
    pub fn clear_tuned(&mut self) {
        self.tuned = Default::default();
    }

    pub fn path(&self) -> FftPath {
        self.path
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

/// Bind groups kept per cached input or output buffer.
pub(super) const BIND_GROUPS_KEPT: usize = 8;

/// The bindings of every generated module: `Seqs`, src, dst, twiddles,
/// quarter shifts, gain (`shaders/fft_fused.wgsl`).
pub(super) fn fused_layout(device: &wgpu::Device) -> (wgpu::BindGroupLayout, wgpu::PipelineLayout) {
    let l = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("fft_fused"),
        entries: &[
            storage(0, true),
            storage(1, true),
            storage(2, false),
            storage(3, true),
            storage(4, true),
            storage(5, true),
        ],
    });
    let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("fft_fused"),
        bind_group_layouts: &[Some(&l)],
        immediate_size: 0,
    });
    (l, pl)
}

/// One recorded dispatch.
#[derive(Debug)]
pub(super) struct Op {
    pub(super) pipeline: wgpu::ComputePipeline,
    pub(super) bind: wgpu::BindGroup,
    pub(super) groups: [u32; 2],
    /// For per-pass timings: what it does, and the bytes it reads and
    /// writes at least (each value once).
    pub(super) what: String,
    pub(super) bytes: u64,
}

pub(super) fn record_ops<'a>(
    pass: &mut wgpu::ComputePass<'_>,
    ops: impl IntoIterator<Item = &'a Op>,
) {
    for op in ops {
        pass.set_pipeline(&op.pipeline);
        pass.set_bind_group(0, &op.bind, &[]);
        pass.dispatch_workgroups(op.groups[0], op.groups[1], 1);
    }
}

pub(super) fn complex_table(n: usize, angle: impl Fn(usize) -> f64) -> Vec<f32> {
    (0..n)
        .flat_map(|m| {
            let a = angle(m);
            [a.cos() as f32, a.sin() as f32]
        })
        .collect()
}

/// The tables of one transform length: e^{−2πim/N} (the passes) and
/// e^{−iπk/(2N)} (the DCT's quarter-sample shift), m, k < N.
#[derive(Debug)]
pub(super) struct Tables {
    pub(super) n: usize,
    pub(super) radices: Vec<u32>,
    pub(super) twiddle: wgpu::Buffer,
    pub(super) quarter: wgpu::Buffer,
}

impl Tables {
    pub(super) fn new(device: &wgpu::Device, n: usize) -> Result<Self, FftError> {
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
pub(super) struct Layout {
    pub(super) count: u32,
    pub(super) elem_stride: u32,
    pub(super) seq_stride: u32,
    pub(super) group: u32,
    pub(super) plane: u32,
    pub(super) seq_fastest: bool,
}

/// The passes of a batched FFT ping-ponging `a` and `b` (input in `a`);
/// returns them and whether the result ends in `b`.
pub(super) fn fft_ops(
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

pub(super) fn entry(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: buffer.as_entire_binding(),
    }
}

pub(super) fn check_binding(device: &wgpu::Device, what: &str, bytes: u64) -> Result<(), FftError> {
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
pub(super) fn axis(
    width: usize,
    height: usize,
    channels: usize,
    columns: bool,
    use_gain: bool,
) -> SeqParams {
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
pub(super) fn io_bytes(q: &SeqParams, gain: bool) -> u64 {
    let real = 4 * u64::from(q.count) * u64::from(q.n);
    real * (1 + u64::from(gain)) + 8 * u64::from(q.pairs) * u64::from(q.n)
}

/// `ops` named for their axis ("rows: forward FFT pass, …").
pub(super) fn on_axis(ops: Vec<Op>, axis: &str) -> Vec<Op> {
    ops.into_iter()
        .map(|mut o| {
            o.what = format!("{axis}: {}", o.what);
            o
        })
        .collect()
}

/// The complex layout of an axis's pairs, for its FFT.
pub(super) fn pair_layout(q: &SeqParams) -> Layout {
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
