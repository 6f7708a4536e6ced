//! The DCT filter by separate passes through device memory: the fallback
//! of the workgroup-memory filter (`fused.rs`) where a side does not fit
//! workgroup memory, and the baseline its benchmark compares against.

use super::kernels::{
    BIND_GROUPS_KEPT, FftKernels, Op, SeqParams, Tables, axis, check_binding, entry, fft_ops,
    io_bytes, on_axis, pair_layout, record_ops,
};
use super::{FftError, init_buffer};
use crate::workgroups;

/// The filter of [`super::DctFilter`] by separate passes through device
/// memory (pack, each radix's Stockham pass, unpack; 32 dispatches at
/// 1080p): any length the radices take, at any workgroup-memory size. The
/// fallback of the workgroup-memory filter (`fused.rs`) and its
/// benchmark's baseline.
#[derive(Debug)]
pub(super) struct MultiPassFilter {
    width: usize,
    height: usize,
    channels: usize,
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
pub(super) struct SeqParamsBuffer(wgpu::Buffer);

impl MultiPassFilter {
    /// Gains checked by the caller (`filter.rs`): one or more sets of
    /// equally many channels of width·height finite values.
    pub(super) fn with_gain_sets(
        kernels: &mut FftKernels,
        width: usize,
        height: usize,
        sets: &[&[Vec<f32>]],
    ) -> Result<Self, FftError> {
        let device = kernels.device.clone();
        let channels = sets.first().map_or(0, |g| g.len());
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

    pub(super) fn sets(&self) -> usize {
        self.gain_ops.len()
    }

    /// Each dispatch of a frame with gain set `set`, in order: what it
    /// does and the bytes it moves at least.
    pub(super) fn passes(&self, set: usize) -> Vec<(String, u64)> {
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

    /// As [`MultiPassFilter::record_set`] with set 0, each dispatch in a compute pass of its own
    /// between two of `timer`'s timestamps (pair i for dispatch i of
    /// [`super::DctFilter::passes`]); the timer needs that many pairs.
    pub(super) fn record_timed(
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

    /// Records the filter with gain set `set` (checked by the caller).
    pub(super) fn record_set(
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
