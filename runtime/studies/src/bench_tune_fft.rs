//! `nedrt bench tune`'s DCT filter (issue 56, item 4; docs/tuning.md): at
//! each frame size, the prefilters' filter of three planes timed at the
//! heuristics' workgroup shape and at each candidate on this adapter; the
//! fastest goes into the adapter's table (`[[fft]]`), which every
//! prefilter on the device then follows at that size
//! (`nedrt_gpu::fft::tuned`). A shape only moves butterflies between
//! threads: each candidate's output is checked against the heuristics'
//! bit for bit before it may win (one that differs is named in the report
//! and passed over).

use std::fmt::Write as _;

use super::AppError;
use super::bench_fft::{frame, psfs};
use super::bench_inference::bench_frame;
use nedrt_gpu::fft::{DctFilter, FftKernels, FusedVariant};
use nedrt_infer::gpu::tuning::TunedFft;
use nedrt_optics::sim::wiener::WienerFilter;

/// The shapes timed beside the heuristics' (threads a workgroup, at most
/// that many pairs a workgroup): the device check's `--fft-variants`.
pub const CANDIDATES: [(u32, u32); 6] =
    [(128, 4), (512, 4), (1024, 4), (256, 2), (512, 2), (256, 1)];

/// What a run measured: the entries, and the report's table.
#[derive(Debug, Clone)]
pub struct FftTuning {
    pub entries: Vec<TunedFft>,
    pub report: String,
}

fn shape(v: &FusedVariant) -> String {
    match (v.threads, v.max_seqs) {
        (None, None) => "the heuristics'".into(),
        (t, p) => format!(
            "{} threads, at most {} pairs",
            t.map_or("the heuristics'".into(), |t| t.to_string()),
            p.map_or("the heuristics'".into(), |p| p.to_string())
        ),
    }
}

/// Tunes the filter at each of `sizes` on `device`: each shape's best of
/// `repeat` frames after a warm-up (GPU time where the adapter has
/// timestamps, else wall time).
pub fn tune(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    sizes: &[(usize, usize)],
    repeat: usize,
) -> Result<FftTuning, AppError> {
    let mut kernels = FftKernels::new(device)?;
    // Against the heuristics, not the table being rewritten.
    kernels.clear_tuned();
    let limits = device.limits();
    let most = limits
        .max_compute_invocations_per_workgroup
        .min(limits.max_compute_workgroup_size_x);
    // Threads beyond the adapter's limit are clamped to it: time each
    // shape the kernels can build once.
    let mut candidates: Vec<FusedVariant> = Vec::new();
    for (t, p) in CANDIDATES {
        let v = FusedVariant {
            threads: Some(t.min(most)),
            max_seqs: Some(p),
        };
        if !candidates.contains(&v) {
            candidates.push(v);
        }
    }
    let wiener = WienerFilter::new(&psfs(), 1e-2);
    let timer = nedrt_gpu::PassTimer::new(device, queue, 1);
    let mut md = format!(
        "\n### The DCT filter (three planes), {} shapes besides the heuristics'\n\n\
         | frame | heuristic µs | tuned shape | µs | heuristic / tuned |\n| --- | ---: | --- | ---: | ---: |\n",
        candidates.len()
    );
    let mut entries = Vec::new();
    for &(w, h) in sizes {
        // A side the device FFT does not take keeps its filter on the host.
        if let Err(e) = nedrt_gpu::fft::radices(w).and(nedrt_gpu::fft::radices(h)) {
            let _ = writeln!(md, "| {w}×{h} | – | not tuned: {e} | – | – |");
            continue;
        }
        let gains = wiener.plan(w, h).dct_gains()?;
        let input = bench_frame(w, h);
        use wgpu::util::DeviceExt;
        let src = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("tune frame"),
            contents: bytemuck::cast_slice(input.data()),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let dst = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("tune output"),
            size: src.size(),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let time = |dct: &mut DctFilter| -> Result<(u64, Vec<f32>), AppError> {
            let mut best = u64::MAX;
            for rep in 0..=repeat.max(1) {
                let (wall, gpu) = frame(device, queue, dct, &src, &dst, timer.as_ref())?;
                if rep > 0 {
                    best = best.min((gpu.unwrap_or(wall) * 1e9).round().max(1.0) as u64);
                }
            }
            Ok((best, read(device, queue, &dst)?))
        };
        let mut heuristic = DctFilter::new(&mut kernels, w, h, &gains)?;
        if !heuristic.in_workgroup_memory() {
            let _ = writeln!(
                md,
                "| {w}×{h} | – | the multi-pass filter (a side does not fit workgroup memory): nothing to tune | – | – |"
            );
            continue;
        }
        let (heuristic_ns, reference) = time(&mut heuristic)?;
        let mut best = (heuristic_ns, FusedVariant::default());
        let mut differ = Vec::new();
        for v in &candidates {
            kernels.set_fused_variant(*v);
            let made = DctFilter::new(&mut kernels, w, h, &gains);
            kernels.set_fused_variant(FusedVariant::default());
            let mut dct = made?;
            if !dct.in_workgroup_memory() {
                continue;
            }
            let (ns, out) = time(&mut dct)?;
            // Not eligible (and said): a shape should change no bit.
            if out
                .iter()
                .zip(&reference)
                .any(|(a, b)| a.to_bits() != b.to_bits())
            {
                differ.push(shape(v));
                continue;
            }
            if ns < best.0 {
                best = (ns, *v);
            }
        }
        let _ = writeln!(
            md,
            "| {w}×{h} | {:.1} | {}{} | {:.1} | {:.2} |",
            heuristic_ns as f64 * 1e-3,
            shape(&best.1),
            if differ.is_empty() {
                String::new()
            } else {
                format!(
                    " (not eligible, their output differs from the heuristics': {})",
                    differ.join("; ")
                )
            },
            best.0 as f64 * 1e-3,
            heuristic_ns as f64 / best.0 as f64
        );
        entries.push(TunedFft {
            width: w,
            height: h,
            threads: best.1.threads,
            pairs: best.1.max_seqs,
            tuned_ns: best.0,
            heuristic_ns,
        });
    }
    Ok(FftTuning {
        entries,
        report: md,
    })
}

/// The filter's output, read back.
fn read(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    buffer: &wgpu::Buffer,
) -> Result<Vec<f32>, AppError> {
    let host = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("tune read-back"),
        size: buffer.size(),
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = device.create_command_encoder(&Default::default());
    enc.copy_buffer_to_buffer(buffer, 0, &host, 0, buffer.size());
    queue.submit([enc.finish()]);
    nedrt_gpu::map_and_wait(device, &host)?;
    Ok(nedrt_gpu::read_mapped(&host, |b| {
        bytemuck::cast_slice::<u8, f32>(b).to_vec()
    })?)
}
