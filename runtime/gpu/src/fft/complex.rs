//! The batched 2-D complex FFT: a reference for the tests and benchmarks,
//! apart from the DCT filter the prefilters run.

use super::fused::{self, fits_workgroup};
use super::kernels::{
    FftKernels, Layout, Op, SeqParams, Tables, check_binding, fft_ops, record_ops,
};
use super::{FftError, FftPath, init_buffer};

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
    /// Whether each axis is one dispatch in workgroup memory.
    pub fn in_workgroup_memory(&self) -> bool {
        self.forward.len() == 2 && self.forward.iter().all(|o| o.what.contains("workgroup"))
    }
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
        if kernels.path == FftPath::Auto
            && fits_workgroup(&device, cols)
            && fits_workgroup(&device, rows)
        {
            return Self::fused_axes(kernels, cols, rows, batch, a, b);
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

    /// One dispatch per axis, each sequence in workgroup memory: rows
    /// a → b, columns b → a.
    fn fused_axes(
        kernels: &mut FftKernels,
        cols: usize,
        rows: usize,
        batch: usize,
        a: &wgpu::Buffer,
        b: &wgpu::Buffer,
    ) -> Result<Self, FftError> {
        let device = kernels.device.clone();
        let (r, c) = (rows as u32, cols as u32);
        let seqs = |n: u32, count: u32, group, plane, group_stride, elem_stride| SeqParams {
            n,
            count,
            pairs: count,
            group,
            plane,
            group_stride,
            elem_stride,
            pair_stride: 0,
            celem_stride: 0,
            pair_fastest: 0,
            use_gain: 0,
            pad: 0,
        };
        let row_q = seqs(c, batch as u32 * r, batch as u32 * r, 0, c, 1);
        let col_q = seqs(r, batch as u32 * c, c, r * c, 1, c);
        let (row_tables, col_tables) = (Tables::new(&device, cols)?, Tables::new(&device, rows)?);
        let dummy = init_buffer(&device, "no gains", &[0u8; 16]);
        let bytes = 16 * (batch * rows * cols) as u64;
        let mut made = Vec::new();
        for entry_point in ["fft_forward", "fft_inverse"] {
            let mut ops = Vec::new();
            for (q, n, tables, src, dst, axis, strided) in [
                (&row_q, cols, &row_tables, a, b, "rows", false),
                (&col_q, rows, &col_tables, b, a, "columns", true),
            ] {
                let params = init_buffer(&device, "fft_fused axis", bytemuck::bytes_of(q));
                let seqs = fused::seqs_for(kernels, n, q.count, strided);
                ops.push(Op {
                    pipeline: kernels.fused_pipeline(n, seqs, entry_point)?,
                    bind: fused::bind(
                        &device,
                        &kernels.fused_layout,
                        [&params, src, dst, &tables.twiddle, &tables.quarter, &dummy],
                    ),
                    groups: fused::groups(q.count.div_ceil(seqs)),
                    what: format!(
                        "{axis}: {entry_point} ({})",
                        fused::per_workgroup(seqs, "sequences")
                    ),
                    bytes,
                });
            }
            made.push(ops);
        }
        let inverse = made.pop().unwrap_or_default();
        let forward = made.pop().unwrap_or_default();
        Ok(Self {
            forward,
            inverse,
            forward_in_b: false,
            inverse_in_b: false,
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
