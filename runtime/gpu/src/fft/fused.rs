//! The DCT filter in workgroup memory: three dispatches a frame (the rows'
//! DCT-II; the columns' DCT-II, gain and DCT-III; the rows' DCT-III), each
//! workgroup holding a pair of rows or columns in workgroup memory through
//! every pass of its FFT (`wgsl.rs` generates the kernels per length). Used
//! where both sides fit the adapter's workgroup memory; the multi-pass
//! filter (`dct.rs`) is the fallback.

use super::kernels::{BIND_GROUPS_KEPT, FftKernels, SeqParams, Tables, axis, entry};
use super::{FftError, checked, init_buffer, wgsl};
use crate::MAX_GROUPS_X;

/// Whether a length's sequence fits one workgroup's memory on `device`.
pub fn fits_workgroup(device: &wgpu::Device, n: usize) -> bool {
    let limits = device.limits();
    (n as u64) * 8 <= u64::from(limits.max_compute_workgroup_storage_size)
        && limits.max_compute_invocations_per_workgroup >= 64
        && limits.max_compute_workgroup_size_x >= 64
}

/// Sequences (or pairs) of length `n` a workgroup holds on the kernels'
/// device, for `count` of them, `strided` where they are columns: the
/// heuristics' ([`wgsl::seqs_per_workgroup`]), or under a variant's
/// `max_seqs` the most of 8, 4, 2 or 1 within it, the count and the
/// adapter's workgroup memory.
pub(super) fn seqs_for(kernels: &FftKernels, n: usize, count: u32, strided: bool) -> u32 {
    let memory = kernels.device.limits().max_compute_workgroup_storage_size;
    match kernels.variant.max_seqs {
        None => wgsl::seqs_per_workgroup(n, count, strided, memory),
        Some(max) => wgsl::most_seqs(n, count, memory, max),
    }
}

/// Kernels of a caller's own run in place of the filter's row passes (the
/// refinement's steps fused into them, issue 56 item 3): `source` is
/// appended to the rows' generated module (it sees `q`, `src`, `dst`, `sm`
/// and the helpers of `shaders/fft_fused.wgsl`) and defines `load`, run in
/// place of the rows' DCT-II (the same `src` and `dst`), and `store`, in
/// place of the rows' DCT-III; its own buffers are bind group 1, of
/// `layout`. `name` keys the compiled modules.
#[derive(Debug, Clone)]
pub struct RowEndsSpec {
    pub name: &'static str,
    pub source: &'static str,
    pub load: &'static str,
    pub store: &'static str,
    pub layout: wgpu::BindGroupLayout,
}

/// A [`RowEndsSpec`]'s pipelines for one filter.
#[derive(Debug, Clone)]
pub struct RowEnds {
    pub(super) load: wgpu::ComputePipeline,
    pub(super) store: wgpu::ComputePipeline,
    /// The rows' length and pairs a workgroup they were built for.
    pub(super) n: usize,
    pub(super) seqs: (u32, u32),
}

impl FftKernels {
    /// The generated pipeline of length `n`, `seqs` sequences a workgroup
    /// ([`seqs_for`]), `entry_point`, compiled on first use; the caller
    /// checked [`fits_workgroup`].
    pub(super) fn fused_pipeline(
        &mut self,
        n: usize,
        seqs: u32,
        entry_point: &'static str,
    ) -> Result<wgpu::ComputePipeline, FftError> {
        self.fused_pipeline_in(n, seqs, entry_point, None)
    }

    /// As [`FftKernels::fused_pipeline`], from the module with `ends`'
    /// source appended where given (its entry points over two bind groups).
    pub(super) fn fused_pipeline_in(
        &mut self,
        n: usize,
        seqs: u32,
        entry_point: &'static str,
        ends: Option<&RowEndsSpec>,
    ) -> Result<wgpu::ComputePipeline, FftError> {
        let device = self.device.clone();
        let limits = device.limits();
        let most = limits
            .max_compute_invocations_per_workgroup
            .min(limits.max_compute_workgroup_size_x);
        let threads = match self.variant.threads {
            Some(t) => t.clamp(1, most),
            None => wgsl::workgroup_threads(n * seqs as usize, most.min(self.max_threads)),
        };
        // The kernels take a thread's sequence as lid % P: a multiple of P.
        let threads = (threads - threads % seqs).max(seqs);
        let name = ends.map_or("", |e| e.name);
        if let Some(p) = self.fused.get(&(n, seqs, threads, name, entry_point)) {
            return Ok(p.clone());
        }
        let module = match self.fused_modules.entry((n, seqs, threads, name)) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => {
                let mut source = wgsl::module_source(n, &wgsl::fused_radices(n)?, threads, seqs);
                if let Some(ends) = ends {
                    source += ends.source;
                }
                e.insert(checked(&device, || {
                    device.create_shader_module(wgpu::ShaderModuleDescriptor {
                        label: Some("fft_fused"),
                        source: wgpu::ShaderSource::Wgsl(source.into()),
                    })
                })?)
            }
        };
        let two_groups = ends.map(|e| {
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(e.name),
                bind_group_layouts: &[Some(&self.fused_layout), Some(&e.layout)],
                immediate_size: 0,
            })
        });
        let p = checked(&device, || {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry_point),
                layout: Some(two_groups.as_ref().unwrap_or(&self.fused_pipeline_layout)),
                module,
                entry_point: Some(entry_point),
                compilation_options: Default::default(),
                cache: None,
            })
        })?;
        self.fused
            .insert((n, seqs, threads, name, entry_point), p.clone());
        Ok(p)
    }
}

/// Workgroups for `count` workgroups' worth of sequences: rows of at most
/// 65,535 (the kernels' `group_index`).
pub(super) fn groups(count: u32) -> [u32; 2] {
    if count <= MAX_GROUPS_X {
        [count.max(1), 1]
    } else {
        [MAX_GROUPS_X, count.div_ceil(MAX_GROUPS_X)]
    }
}

/// One dispatch of a generated kernel and its bind group's fixed parts.
#[derive(Debug)]
struct Kernel {
    pipeline: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    groups: [u32; 2],
    bytes: u64,
    /// Sequences (pairs) a workgroup holds ([`seqs_for`]).
    seqs: u32,
}

/// How a dispatch's workgroups are filled, for its label.
pub(super) fn per_workgroup(seqs: u32, what: &str) -> String {
    if seqs == 1 {
        "workgroup memory".into()
    } else {
        format!("workgroup memory, {seqs} {what} a workgroup")
    }
}

/// The three-dispatch filter (see the module).
#[derive(Debug)]
pub(super) struct FusedFilter {
    device: wgpu::Device,
    layout: wgpu::BindGroupLayout,
    rows_fwd: Kernel,
    cols: Kernel,
    rows_inv: Kernel,
    /// The rows' tables (the columns' live in their bind groups).
    rows: Tables,
    /// The column kernels' bind groups, one per gain set (tmp → tmp2).
    col_binds: Vec<wgpu::BindGroup>,
    dummy_gain: wgpu::Buffer,
    /// The rows' DCT-II (input → tmp) and the columns' result (tmp2).
    tmp: wgpu::Buffer,
    tmp2: wgpu::Buffer,
    inputs: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
    outputs: Vec<(wgpu::Buffer, wgpu::BindGroup)>,
}

impl FusedFilter {
    /// `gains` checked by the caller (`filter.rs`).
    pub(super) fn new(
        kernels: &mut FftKernels,
        width: usize,
        height: usize,
        sets: &[&[Vec<f32>]],
    ) -> Result<Self, FftError> {
        let device = kernels.device.clone();
        let channels = sets.first().map_or(0, |g| g.len());
        let real_bytes = (channels * width * height * 4) as u64;
        let rows_q = axis(width, height, channels, false, false);
        // The column kernel applies the gain itself, before its DCT-III (no use_gain).
        let cols_q = axis(width, height, channels, true, false);
        let kernel = |kernels: &mut FftKernels, n, strided, entry_point, q: &SeqParams, bytes| {
            let seqs = seqs_for(kernels, n, q.pairs, strided);
            Ok::<_, FftError>(Kernel {
                pipeline: kernels.fused_pipeline(n, seqs, entry_point)?,
                params: init_buffer(&device, "fft_fused axis", bytemuck::bytes_of(q)),
                groups: groups(q.pairs.div_ceil(seqs)),
                bytes,
                seqs,
            })
        };
        let rows_fwd = kernel(
            kernels,
            width,
            false,
            "dct2",
            &rows_q,
            io_real(&rows_q, false),
        )?;
        let cols = kernel(
            kernels,
            height,
            true,
            "dct_filter",
            &cols_q,
            io_real(&cols_q, true),
        )?;
        let rows_inv = kernel(
            kernels,
            width,
            false,
            "dct3",
            &rows_q,
            io_real(&rows_q, false),
        )?;
        let plane = |label| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: real_bytes,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            })
        };
        let (tmp, tmp2) = (plane("dct rows"), plane("dct columns"));
        let rows = Tables::new(&device, width)?;
        let columns = Tables::new(&device, height)?;
        let layout = kernels.fused_layout.clone();
        let col_binds = sets
            .iter()
            .map(|g| {
                let flat: Vec<f32> = g.iter().flatten().copied().collect();
                let gain = init_buffer(&device, "dct gains", bytemuck::cast_slice(&flat));
                bind(
                    &device,
                    &layout,
                    [
                        &cols.params,
                        &tmp,
                        &tmp2,
                        &columns.twiddle,
                        &columns.quarter,
                        &gain,
                    ],
                )
            })
            .collect();
        Ok(Self {
            dummy_gain: init_buffer(&device, "no gains", &[0u8; 16]),
            device,
            layout,
            rows_fwd,
            cols,
            rows_inv,
            rows,
            col_binds,
            tmp,
            tmp2,
            inputs: Vec::new(),
            outputs: Vec::new(),
        })
    }

    pub(super) fn sets(&self) -> usize {
        self.col_binds.len()
    }

    /// The dispatches of a frame: what each does and the bytes it moves at
    /// least.
    pub(super) fn passes(&self) -> Vec<(String, u64)> {
        vec![
            (
                format!(
                    "rows: DCT-II ({})",
                    per_workgroup(self.rows_fwd.seqs, "row pairs")
                ),
                self.rows_fwd.bytes,
            ),
            (
                format!(
                    "columns: DCT-II × gain, DCT-III ({})",
                    per_workgroup(self.cols.seqs, "column pairs")
                ),
                self.cols.bytes,
            ),
            (
                format!(
                    "rows: DCT-III ({})",
                    per_workgroup(self.rows_inv.seqs, "row pairs")
                ),
                self.rows_inv.bytes,
            ),
        ]
    }

    /// The frame's dispatches for `input` and each (output, gain set):
    /// the rows' forward transform once, shared by every output.
    pub(super) fn steps(
        &mut self,
        input: &wgpu::Buffer,
        outs: &[(&wgpu::Buffer, usize)],
    ) -> Vec<(wgpu::ComputePipeline, wgpu::BindGroup, [u32; 2])> {
        let first = self.input_bind(input);
        let mut steps = vec![(self.rows_fwd.pipeline.clone(), first, self.rows_fwd.groups)];
        for &(output, set) in outs {
            let last = self.output_bind(output);
            steps.push((
                self.cols.pipeline.clone(),
                self.col_binds[set].clone(),
                self.cols.groups,
            ));
            steps.push((self.rows_inv.pipeline.clone(), last, self.rows_inv.groups));
        }
        steps
    }

    /// `ends`' pipelines for this filter's rows.
    pub(super) fn row_ends(
        &self,
        kernels: &mut FftKernels,
        spec: &RowEndsSpec,
    ) -> Result<RowEnds, FftError> {
        let n = self.rows.n;
        Ok(RowEnds {
            load: kernels.fused_pipeline_in(n, self.rows_fwd.seqs, spec.load, Some(spec))?,
            store: kernels.fused_pipeline_in(n, self.rows_inv.seqs, spec.store, Some(spec))?,
            n,
            seqs: (self.rows_fwd.seqs, self.rows_inv.seqs),
        })
    }

    /// Whether `ends` were built for this filter's rows.
    pub(super) fn fits(&self, ends: &RowEnds) -> bool {
        ends.n == self.rows.n && ends.seqs == (self.rows_fwd.seqs, self.rows_inv.seqs)
    }

    /// The dispatches of one filter with gain set `set` from `input` to
    /// `output`, `ends`' store in place of the rows' DCT-III and, where
    /// `load`, its load in place of the rows' DCT-II: each with whether it
    /// is one of the ends (they take bind group 1).
    pub(super) fn steps_with_ends(
        &mut self,
        ends: &RowEnds,
        input: &wgpu::Buffer,
        output: &wgpu::Buffer,
        set: usize,
        load: bool,
    ) -> Vec<(wgpu::ComputePipeline, wgpu::BindGroup, [u32; 2], bool)> {
        let first = self.input_bind(input);
        let last = self.output_bind(output);
        let load_pipeline = if load {
            ends.load.clone()
        } else {
            self.rows_fwd.pipeline.clone()
        };
        vec![
            (load_pipeline, first, self.rows_fwd.groups, load),
            (
                self.cols.pipeline.clone(),
                self.col_binds[set].clone(),
                self.cols.groups,
                false,
            ),
            (ends.store.clone(), last, self.rows_inv.groups, true),
        ]
    }

    fn input_bind(&mut self, input: &wgpu::Buffer) -> wgpu::BindGroup {
        let (params, tmp) = (&self.rows_fwd.params, &self.tmp);
        let (tw, qu, g) = (&self.rows.twiddle, &self.rows.quarter, &self.dummy_gain);
        cached(&mut self.inputs, input, |input| {
            bind(&self.device, &self.layout, [params, input, tmp, tw, qu, g])
        })
    }

    fn output_bind(&mut self, output: &wgpu::Buffer) -> wgpu::BindGroup {
        let (params, tmp2) = (&self.rows_inv.params, &self.tmp2);
        let (tw, qu, g) = (&self.rows.twiddle, &self.rows.quarter, &self.dummy_gain);
        cached(&mut self.outputs, output, |output| {
            bind(
                &self.device,
                &self.layout,
                [params, tmp2, output, tw, qu, g],
            )
        })
    }
}

/// The bind group kept for `buffer`, made by `make` on first use (a few
/// kept: the service's pool of frame buffers).
fn cached(
    kept: &mut Vec<(wgpu::Buffer, wgpu::BindGroup)>,
    buffer: &wgpu::Buffer,
    make: impl FnOnce(&wgpu::Buffer) -> wgpu::BindGroup,
) -> wgpu::BindGroup {
    if let Some((_, g)) = kept.iter().find(|(b, _)| b == buffer) {
        return g.clone();
    }
    let g = make(buffer);
    if kept.len() == BIND_GROUPS_KEPT {
        kept.remove(0);
    }
    kept.push((buffer.clone(), g.clone()));
    g
}

pub(super) fn bind(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    buffers: [&wgpu::Buffer; 6],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| entry(i as u32, b))
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("fft_fused"),
        layout,
        entries: &entries,
    })
}

/// Bytes a fused axis moves at least: the real sequences read and
/// written once each (and the gain read where applied); nothing complex
/// leaves workgroup memory.
fn io_real(q: &SeqParams, gain: bool) -> u64 {
    4 * u64::from(q.count) * u64::from(q.n) * (2 + u64::from(gain))
}
