//! `nedrt bench fft`: the prefilters' transform on the device against the
//! CPU's in one run, at each frame size: the DCT filter of nedrt-gpu
//! (DCT-II · gain · DCT-III of the three planes, what the device Wiener and
//! each refinement step run) against nedrt-optics' Wiener plan on the CPU
//! (realfft and rustfft on the mirrored 2w×2h frame), and the filter's
//! bytes over the adapter's bandwidth (its floor); with `refine_steps`,
//! `refine:K` per frame with its steps fused into the filter's rows and
//! as kernels of their own, side by side. Performance is measured here,
//! never asserted in tests.

use std::fmt::Write as _;
use std::time::Instant;

use serde_json::json;

use super::AppError;
use super::bench::median;
use super::bench_inference::bench_frame;
use nedrt_gpu::fft::{DctFilter, FftKernels, FftPath, FusedVariant};
use nedrt_optics::Psf;
use nedrt_optics::sim::wiener::WienerFilter;

/// One frame's wall time and GPU time (none without timestamps), seconds.
type FrameTimes = (f64, Option<f64>);

/// What to time.
#[derive(Debug, Clone)]
pub struct FftBench {
    pub sizes: Vec<(usize, usize)>,
    pub repeat: usize,
    /// The adapter's memory bandwidth, GB/s, for the floor (none: not given).
    pub peak_gbps: Option<f64>,
    pub gpu: nedrt_gpu::GpuSettings,
    /// Also each dispatch's device time (timestamp queries) beside its bytes and floor.
    pub per_pass: bool,
    /// The device paths to time, side by side (the multi-pass fallback
    /// against the workgroup-memory kernels).
    pub paths: Vec<FftPath>,
    /// Shapes of the workgroup-memory kernels to time beside them (issue
    /// 56 item 3: threads and sequences a workgroup).
    pub variants: Vec<FusedVariant>,
    /// `refine:K` with K steps, fused and not, at each size (none: not timed).
    pub refine_steps: Option<usize>,
}

/// A variant's row label.
fn variant_label(v: &FusedVariant) -> String {
    let threads = v
        .threads
        .map_or("the heuristics' threads".into(), |t| format!("{t} threads"));
    let seqs = v
        .max_seqs
        .map_or("the heuristics' pairs".into(), |p| match p {
            1 => "1 pair".to_string(),
            p => format!("at most {p} pairs"),
        });
    format!("workgroup memory, {threads}, {seqs} a workgroup")
}

/// One PSF per channel (the filter's cost does not depend on the kernel;
/// its values are only realistic).
pub(crate) fn psfs() -> Vec<Psf> {
    [1.5, 2.0, 2.5]
        .iter()
        .map(|s| Psf::gaussian(*s, 0.0))
        .collect()
}

/// Times every size, handing each result to `on_record` (JSON), and
/// returns the Markdown table.
pub fn run(
    b: &FftBench,
    on_record: &mut dyn FnMut(&serde_json::Value),
) -> Result<String, AppError> {
    if let Some(v) = b.peak_gbps
        && !(v.is_finite() && v > 0.0)
    {
        return Err(AppError::option(
            format!("--peak-gbps {v}"),
            "must be a positive rate",
        ));
    }
    let (adapter, device, queue) = nedrt_gpu::open_device(&b.gpu, false)?;
    let adapter = adapter.get_info().name;
    let mut kernels = FftKernels::new(&device)?;
    // The paths' rows run the heuristics' shapes; the adapter's tuned
    // shape at a size (`nedrt bench tune`) gets a row of its own.
    let tuned: Vec<Option<FusedVariant>> = b
        .sizes
        .iter()
        .map(|&(w, h)| kernels.tuned_variant(w, h))
        .collect();
    kernels.clear_tuned();
    let filter = WienerFilter::new(&psfs(), 1e-2);
    let mut md = format!(
        "`nedrt bench fft`: the Wiener prefilter of three planes, median of {} after a warm-up, \
         the CPU and each path interleaved (the ratios: medians of each repetition's); \
         device: {adapter}; CPU: {} threads\n\n\
         wall: record, submit and wait; GPU: timestamps around the filter's passes\n\n\
         | frame | path | dispatches | wall ms | GPU ms | CPU ms | wall ÷ CPU | GPU ÷ CPU | device MB moved | floor ms (bytes ÷ bandwidth) | GPU × floor |\n\
         | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n",
        b.repeat.max(1),
        rayon::current_num_threads()
    );
    let mut refine_md = String::new();
    for (&(w, h), tuned_here) in b.sizes.iter().zip(tuned) {
        let input = bench_frame(w, h);
        // The CPU: the plan made once, then each frame (mirror, realfft,
        // gains, inverse, crop).
        let plan = filter.plan(w, h);
        let _ = filter.apply_unclamped(&input);
        // The device: the same gains, the frame already on the device
        // (the service's case); each frame one submission and a wait.
        let gains = plan.dct_gains()?;
        use wgpu::util::DeviceExt;
        let src = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("bench frame"),
            contents: bytemuck::cast_slice(input.data()),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let dst = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("bench output"),
            size: src.size(),
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let timer = nedrt_gpu::PassTimer::new(&device, &queue, 1);
        let mut filters = Vec::new();
        let mut labels = Vec::new();
        for &path in &b.paths {
            kernels.set_path(path);
            let mut dct = DctFilter::new(&mut kernels, w, h, &gains)?;
            frame(&device, &queue, &mut dct, &src, &dst, timer.as_ref())?;
            labels.push(
                if dct.in_workgroup_memory() {
                    "workgroup memory"
                } else {
                    "multi-pass"
                }
                .to_string(),
            );
            filters.push(dct);
        }
        for (v, is_tuned) in tuned_here
            .iter()
            .map(|v| (v, true))
            .chain(b.variants.iter().map(|v| (v, false)))
        {
            kernels.set_path(FftPath::Auto);
            kernels.set_fused_variant(*v);
            let mut dct = DctFilter::new(&mut kernels, w, h, &gains)?;
            kernels.set_fused_variant(FusedVariant::default());
            frame(&device, &queue, &mut dct, &src, &dst, timer.as_ref())?;
            labels.push(match (dct.in_workgroup_memory(), is_tuned) {
                (true, true) => format!("the adapter's tuned shape: {}", variant_label(v)),
                (true, false) => variant_label(v),
                (false, _) => "multi-pass (the sides do not fit workgroup memory)".into(),
            });
            filters.push(dct);
        }
        // Interleaved: each repetition one CPU frame, then one frame per
        // path, so that a machine shared with other work loads all sides
        // alike; the ratios are medians of each repetition's own.
        let mut cpu = Vec::new();
        let mut times: Vec<Vec<FrameTimes>> = vec![Vec::new(); filters.len()];
        for _ in 0..b.repeat.max(1) {
            let t = Instant::now();
            std::hint::black_box(filter.apply_unclamped(&input));
            cpu.push(t.elapsed().as_secs_f64());
            for (dct, out) in filters.iter_mut().zip(&mut times) {
                out.push(frame(&device, &queue, dct, &src, &dst, timer.as_ref())?);
            }
        }
        let c = median(cpu.clone());
        for ((dct, t), kind) in filters.iter_mut().zip(&times).zip(&labels) {
            let (wall, gpu) = medians(t);
            let ratio = |f: &dyn Fn(&FrameTimes) -> Option<f64>| {
                let r: Option<Vec<f64>> = t
                    .iter()
                    .zip(&cpu)
                    .map(|(x, c)| f(x).map(|v| v / c))
                    .collect();
                r.map(median)
            };
            let wall_ratio = ratio(&|x| Some(x.0)).unwrap_or(f64::NAN);
            let gpu_ratio = ratio(&|x| x.1);
            let bytes = dct.bytes_per_frame();
            let floor = b.peak_gbps.map(|bw| bytes as f64 / (bw * 1e9));
            let ms = |v: Option<f64>| v.map_or("–".into(), |v| format!("{:.2}", v * 1e3));
            let _ = writeln!(
                md,
                "| {w}×{h} | {kind} | {} | {:.2} | {} | {:.2} | {:.2} | {} | {:.0} | {} | {} |",
                dct.passes(0).len(),
                wall * 1e3,
                ms(gpu),
                c * 1e3,
                wall_ratio,
                gpu_ratio.map_or("–".into(), |g| format!("{g:.2}")),
                bytes as f64 / 1e6,
                floor.map_or("– (--peak-gbps)".into(), |f| format!("{:.3}", f * 1e3)),
                floor
                    .zip(gpu)
                    .map_or("–".into(), |(f, g)| format!("{:.1}", g / f)),
            );
            if b.per_pass {
                md += &per_pass(&device, &queue, dct, &src, &dst, b, (w, h), on_record)?;
            }
            on_record(&json!({
                "kind": "fft_filter", "width": w, "height": h, "device": adapter, "path": kind,
                "dispatches": dct.passes(0).len(),
                "device_median_s": wall, "gpu_median_s": gpu, "cpu_median_s": c,
                "device_over_cpu": wall_ratio, "gpu_over_cpu": gpu_ratio,
                "cpu_threads": rayon::current_num_threads(),
                "bytes_per_frame": bytes, "floor_s": floor, "repeat": b.repeat,
            }));
        }
        if let Some(steps) = b.refine_steps {
            let k = Refine {
                steps,
                gains: &gains,
                size: (w, h),
                repeat: b.repeat.max(1),
            };
            refine_md += &refine(&device, &queue, &k, &src, &dst, timer.as_ref(), on_record)?;
        }
    }
    if let Some(steps) = b.refine_steps {
        let _ = write!(
            md,
            "
`refine:{steps}` per frame (the two opening filters, {steps} steps, the output written), its \
             steps fused into the filter's rows (issue 56, item 3) and as kernels of their own, \
             interleaved, median of {}; ratios: medians of each repetition's\n\n\
             | frame | steps | dispatches a step | wall ms | GPU ms | wall ÷ own kernels' | GPU ÷ own kernels' |\n\
             | --- | --- | --- | --- | --- | --- | --- |\n{refine_md}",
            b.repeat.max(1)
        );
    }
    Ok(md)
}

/// The frames' median wall time, and their median GPU time where every
/// frame has one.
fn medians(t: &[FrameTimes]) -> (f64, Option<f64>) {
    let gpus: Vec<f64> = t.iter().filter_map(|x| x.1).collect();
    (
        median(t.iter().map(|x| x.0).collect()),
        (gpus.len() == t.len()).then(|| median(gpus)),
    )
}

/// What [`refine`] times.
struct Refine<'a> {
    steps: usize,
    /// The Wiener's DCT gains per channel: the terms' stand-in (the cost
    /// does not depend on them).
    gains: &'a [Vec<f32>],
    size: (usize, usize),
    repeat: usize,
}

/// `refine:K` with its steps fused into the filter's rows and with kernels
/// of their own, interleaved: the table's rows.
fn refine(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    k: &Refine,
    src: &wgpu::Buffer,
    dst: &wgpu::Buffer,
    timer: Option<&nedrt_gpu::PassTimer>,
    on_record: &mut dyn FnMut(&serde_json::Value),
) -> Result<String, AppError> {
    use nedrt_gpu::DeviceStage;
    use nedrt_gpu::refine::{RefineStage, RefineTerms};
    let (w, h) = k.size;
    let mut stages = Vec::new();
    for fuse in [true, false] {
        let gains = k.gains.to_vec();
        let terms = move |_: usize, _: usize| {
            let normal: Vec<Vec<f32>> = gains
                .iter()
                .map(|g| g.iter().map(|v| v * v).collect())
                .collect();
            Ok(RefineTerms {
                step: normal
                    .iter()
                    .map(|n| 1.0 / n.iter().copied().fold(f32::MIN_POSITIVE, f32::max))
                    .collect(),
                linear: gains.clone(),
                adjoint_target: gains.clone(),
                normal,
            })
        };
        let mut stage = RefineStage::new(device, "refine".into(), k.steps, Box::new(terms))?
            .with_fused_steps(fuse);
        // The heuristics' shapes, as the filter's rows above.
        stage.kernels_mut().clear_tuned();
        stage.prepare(w, h)?;
        stages.push(stage);
    }
    let mut times: Vec<Vec<FrameTimes>> = vec![Vec::new(); stages.len()];
    for rep in 0..=k.repeat {
        for (stage, out) in stages.iter_mut().zip(&mut times) {
            let t = timed(device, queue, timer, &mut |enc| {
                stage.record(enc, src, dst, w, h).map_err(AppError::from)
            })?;
            // The first: compiles and warms up.
            if rep > 0 {
                out.push(t);
            }
        }
    }
    let mut md = String::new();
    for (i, (stage, t)) in stages.iter().zip(&times).enumerate() {
        let fused = stage.steps_fused() == Some(true);
        let (wall, gpu) = medians(t);
        let ratio = |f: &dyn Fn(&FrameTimes) -> Option<f64>| -> Option<f64> {
            let r: Option<Vec<f64>> = t
                .iter()
                .zip(&times[1])
                .map(|(a, b)| f(a).zip(f(b)).map(|(a, b)| a / b))
                .collect();
            r.map(median)
        };
        let (wall_ratio, gpu_ratio) = (ratio(&|x| Some(x.0)), ratio(&|x| x.1));
        let show =
            |v: Option<f64>, scale: f64| v.map_or("–".into(), |v| format!("{:.2}", v * scale));
        let dispatches = stage.dispatches_per_step().unwrap_or(0);
        let _ = writeln!(
            md,
            "| {w}×{h} | {} | {dispatches} | {:.2} | {} | {} | {} |",
            if fused {
                "fused into the rows"
            } else if i == 0 {
                "kernels of their own (the filter runs by passes)"
            } else {
                "kernels of their own"
            },
            wall * 1e3,
            show(gpu, 1e3),
            show(wall_ratio, 1.0),
            show(gpu_ratio, 1.0),
        );
        on_record(&json!({
            "kind": "refine_steps", "width": w, "height": h, "steps": k.steps, "fused": fused,
            "dispatches_per_step": dispatches, "device_median_s": wall, "gpu_median_s": gpu,
            "over_own_kernels_wall": wall_ratio, "over_own_kernels_gpu": gpu_ratio,
            "repeat": k.repeat,
        }));
    }
    Ok(md)
}

/// One frame of the filter: its wall time (record, submit, wait) and its
/// GPU time (timestamps around its passes, where the adapter has them).
pub(crate) fn frame(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    dct: &mut DctFilter,
    src: &wgpu::Buffer,
    dst: &wgpu::Buffer,
    timer: Option<&nedrt_gpu::PassTimer>,
) -> Result<FrameTimes, AppError> {
    timed(device, queue, timer, &mut |enc| {
        dct.record(enc, src, dst).map_err(AppError::from)
    })
}

/// One submission of what `record` records: its wall time (record, submit,
/// wait) and its GPU time (timestamps around it, where the adapter has them).
fn timed(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    timer: Option<&nedrt_gpu::PassTimer>,
    record: &mut dyn FnMut(&mut wgpu::CommandEncoder) -> Result<(), AppError>,
) -> Result<FrameTimes, AppError> {
    let t = Instant::now();
    let mut enc = device.create_command_encoder(&Default::default());
    // Empty passes carry the timestamps: the filter records its own.
    if let Some(timer) = timer {
        drop(enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("bench start"),
            timestamp_writes: Some(timer.start(0)),
        }));
    }
    record(&mut enc)?;
    if let Some(timer) = timer {
        drop(enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("bench end"),
            timestamp_writes: Some(timer.end(0)),
        }));
        timer.resolve(&mut enc);
    }
    let s = queue.submit([enc.finish()]);
    nedrt_gpu::wait_for(device, s)?;
    let wall = t.elapsed().as_secs_f64();
    let gpu = match timer {
        Some(timer) => {
            timer.map_and_wait(device)?;
            timer.spans_ns()?.first().map(|ns| *ns as f64 * 1e-9)
        }
        None => None,
    };
    Ok((wall, gpu))
}

/// Each dispatch of the filter in a pass of its own between timestamps
/// (the best of `repeat` runs per dispatch): its time, bytes, bandwidth
/// and how far above its floor.
#[allow(clippy::too_many_arguments)]
fn per_pass(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    dct: &mut DctFilter,
    src: &wgpu::Buffer,
    dst: &wgpu::Buffer,
    b: &FftBench,
    (w, h): (usize, usize),
    on_record: &mut dyn FnMut(&serde_json::Value),
) -> Result<String, AppError> {
    let passes = dct.passes(0);
    let Some(timer) = nedrt_gpu::PassTimer::new(device, queue, passes.len()) else {
        return Ok(format!(
            "\n{w}×{h}: this adapter has no timestamp queries; no per-pass times\n"
        ));
    };
    let mut best = vec![u64::MAX; passes.len()];
    for _ in 0..b.repeat.max(1) + 1 {
        let mut enc = device.create_command_encoder(&Default::default());
        dct.record_timed(&mut enc, src, dst, &timer)?;
        timer.resolve(&mut enc);
        queue.submit([enc.finish()]);
        timer.map_and_wait(device)?;
        for (b, ns) in best.iter_mut().zip(timer.spans_ns()?) {
            *b = (*b).min(ns.max(1));
        }
    }
    let total: f64 = best.iter().map(|ns| *ns as f64 * 1e-6).sum();
    let mut md = format!(
        "\n{w}×{h}, each dispatch in a pass of its own (best of {}): {total:.2} ms in all; floor = bytes ÷ {}\n\n\
         | # | dispatch | MB | ms | GB/s | × floor |\n| --- | --- | --- | --- | --- | --- |\n",
        b.repeat.max(1) + 1,
        b.peak_gbps
            .map_or("the best bandwidth any pass reached".into(), |v| format!(
                "{v:.0} GB/s"
            )),
    );
    let gbps: Vec<f64> = passes
        .iter()
        .zip(&best)
        .map(|((_, bytes), ns)| *bytes as f64 / *ns as f64)
        .collect();
    let peak = b
        .peak_gbps
        .unwrap_or_else(|| gbps.iter().copied().fold(0.0, f64::max));
    for (i, (((what, bytes), ns), rate)) in passes.iter().zip(&best).zip(&gbps).enumerate() {
        let floor_ns = *bytes as f64 / peak;
        md += &format!(
            "| {i} | {what} | {:.1} | {:.3} | {rate:.1} | {:.1} |\n",
            *bytes as f64 / 1e6,
            *ns as f64 * 1e-6,
            *ns as f64 / floor_ns
        );
        on_record(
            &json!({"kind": "fft_pass", "width": w, "height": h, "index": i, "what": what,
                          "bytes": bytes, "gpu_ns": ns, "gbps": rate}),
        );
    }
    Ok(md)
}
