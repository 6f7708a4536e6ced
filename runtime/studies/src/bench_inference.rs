//! `nedrt bench inference`: D-CNN latency per backend, model size, precision
//! and frame size, in one run so the ratios are comparable. The models are
//! the trainer's U-Net built with random weights (latency does not depend on
//! the weights' values): `full` is 32–256 channels, `half` 16–128.
//! Performance is measured here, never asserted in tests.

use std::fmt::Write as _;
use std::time::Instant;

use serde_json::json;

use super::AppError;
use super::bench::median;
use crate::CommonOptions;
use nedrt_core::Image;
use nedrt_infer::{BackendKind, BackendOptions, Dcnn, ModelFile, synth};

/// What to time.
#[derive(Debug, Clone)]
pub struct InferenceBench {
    pub backends: Vec<BackendKind>,
    /// (width, height) of the frames.
    pub sizes: Vec<(usize, usize)>,
    /// (name, width of the first level).
    pub models: Vec<(String, i64)>,
    pub repeat: usize,
    /// Skip a case whose estimated time (from the previous size) exceeds this.
    pub max_seconds: f64,
    pub threads: usize,
    /// Time each layer on the wgpu backend instead (timestamp queries).
    pub per_layer: bool,
    /// The adapter's peak rates for the per-layer floor (GMAC/s, GB/s);
    /// `None`: the best any layer reached in the run.
    pub peak_gmacs: Option<f64>,
    pub peak_gbps: Option<f64>,
}

/// Each layer of each model on the wgpu backend at each size: device time,
/// work, rates, and how far from the floor (MACs over the peak rate or
/// bytes over the peak bandwidth, whichever is larger).
pub fn per_layer(b: &InferenceBench, common: &CommonOptions) -> Result<String, AppError> {
    for (flag, v) in [("--peak-gmacs", b.peak_gmacs), ("--peak-gbps", b.peak_gbps)] {
        if let Some(v) = v
            && !(v.is_finite() && v > 0.0)
        {
            return Err(AppError::option(
                format!("{flag} {v}"),
                "must be a positive rate",
            ));
        }
    }
    let mut md = String::new();
    for (name, width) in &b.models {
        let model = synth_model(name, *width)?;
        for &precision in BackendKind::Wgpu.precisions() {
            let options = BackendOptions {
                precision,
                ..common.dcnn.backend_options.clone()
            };
            let mut dcnn = match Dcnn::from_model(model.clone(), BackendKind::Wgpu, &options) {
                Ok(d) => d,
                Err(e) => {
                    let _ = writeln!(md, "\n{name} wgpu {precision:?}: skipped: {e}");
                    continue;
                }
            };
            for &(w, h) in &b.sizes {
                let frame = bench_frame(w, h);
                // The first run prepares the plan; the best of `repeat` after it.
                let mut best = dcnn.layer_timings(&frame);
                for _ in 0..b.repeat.max(1) {
                    let Ok(prev) = &best else { break };
                    best = dcnn.layer_timings(&frame).map(|next| {
                        prev.iter()
                            .zip(next)
                            .map(|(a, mut n)| {
                                n.gpu_ns = n.gpu_ns.min(a.gpu_ns);
                                n
                            })
                            .collect()
                    });
                }
                match best {
                    Ok(rows) => {
                        md += &layer_table(
                            &format!("{name} on {}, {w}×{h}", dcnn.describe()),
                            &rows,
                            b.peak_gmacs,
                            b.peak_gbps,
                        )
                    }
                    Err(e) => {
                        let _ = writeln!(md, "\n{name} {}, {w}×{h}: skipped: {e}", dcnn.describe());
                    }
                }
            }
        }
    }
    Ok(md)
}

/// One run's per-layer table and the layers furthest from the floor.
fn layer_table(
    title: &str,
    rows: &[nedrt_infer::LayerTiming],
    peak_gmacs: Option<f64>,
    peak_gbps: Option<f64>,
) -> String {
    let secs = |r: &nedrt_infer::LayerTiming| (r.gpu_ns.max(1)) as f64 * 1e-9;
    let gmacs = |r: &nedrt_infer::LayerTiming| r.macs as f64 / secs(r) / 1e9;
    let gbps = |r: &nedrt_infer::LayerTiming| r.bytes as f64 / secs(r) / 1e9;
    let best =
        |f: &dyn Fn(&nedrt_infer::LayerTiming) -> f64| rows.iter().map(f).fold(0.0f64, f64::max);
    let whence = |given: Option<f64>| {
        if given.is_some() {
            "as given"
        } else {
            "the best any layer reached here"
        }
    };
    let (pm, pb) = (
        peak_gmacs.unwrap_or_else(|| best(&gmacs)),
        peak_gbps.unwrap_or_else(|| best(&gbps)),
    );
    let whence = format!(
        "MAC rate {}, bandwidth {}{}",
        whence(peak_gmacs),
        whence(peak_gbps),
        if peak_gmacs.is_some() && peak_gbps.is_some() {
            ""
        } else {
            " (--peak-gmacs and --peak-gbps give the adapter's own)"
        }
    );
    let floor_s = |r: &nedrt_infer::LayerTiming| {
        (r.macs as f64 / (pm * 1e9)).max(r.bytes as f64 / (pb * 1e9))
    };
    let total: f64 = rows.iter().map(secs).sum();
    let mut md = format!(
        "\n### {title}\n\nFloor = max(MACs / {pm:.2} GMAC/s, bytes / {pb:.2} GB/s); {whence}. \
         Layers in passes of their own: {:.2} ms in all.\n\n\
         | # | layer | output C×H×W | MMAC | MB | ms | share | GMAC/s | GB/s | × floor |\n\
         | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n",
        total * 1e3
    );
    for r in rows {
        let _ = writeln!(
            md,
            "| {} | {} | {}×{}×{} | {:.1} | {:.1} | {:.3} | {:.1} % | {:.2} | {:.2} | {:.1} |",
            r.layer,
            r.kind,
            r.output[0],
            r.output[1],
            r.output[2],
            r.macs as f64 / 1e6,
            r.bytes as f64 / 1e6,
            secs(r) * 1e3,
            100.0 * secs(r) / total,
            gmacs(r),
            gbps(r),
            secs(r) / floor_s(r)
        );
    }
    let mut order: Vec<&nedrt_infer::LayerTiming> = rows.iter().collect();
    // Furthest from the floor, weighted by the time it costs: the layers
    // whose tuning would pay most.
    order.sort_by(|a, b| (secs(b) - floor_s(b)).total_cmp(&(secs(a) - floor_s(a))));
    let worst: Vec<String> = order
        .iter()
        .take(3)
        .map(|r| {
            format!(
                "#{} {} ({:.1}× its floor, {:.2} ms above it)",
                r.layer,
                r.kind,
                secs(r) / floor_s(r),
                (secs(r) - floor_s(r)) * 1e3
            )
        })
        .collect();
    let _ = writeln!(
        md,
        "\nFurthest from the floor (time above it): {}.",
        worst.join("; ")
    );
    md
}

/// The trainer's 4-level U-Net of first-level `width`, random weights.
fn synth_model(name: &str, width: i64) -> Result<ModelFile, AppError> {
    Ok(ModelFile::from_bytes(
        std::path::Path::new(&format!("synth-{name}.onnx")),
        synth::encode(&synth::unet(width, 4, 1)),
    )?)
}

/// The frame every case runs: a deterministic ramp pattern.
pub(crate) fn bench_frame(w: usize, h: usize) -> Image {
    Image::rgb(
        w,
        h,
        (0..3 * w * h)
            .map(|i| ((i * 7919) % 1000) as f32 / 1000.0)
            .collect(),
    )
}

/// Runs every case, handing each result to `on_record` as it is measured
/// (JSON), and returns the Markdown table.
pub fn run(
    b: &InferenceBench,
    common: &CommonOptions,
    on_record: &mut dyn FnMut(&serde_json::Value),
) -> Result<String, AppError> {
    let bar = common.phase("cases");
    let variants: usize = b.backends.iter().map(|&k| k.precisions().len()).sum();
    bar.set_length((b.models.len() * variants * b.sizes.len()) as u64);
    let mut table = String::from(
        "| model | backend | precision | frame | median ms | min ms | GMAC/s |\n| --- | --- | --- | --- | --- | --- | --- |\n",
    );
    for (name, width) in &b.models {
        let model = synth_model(name, *width)?;
        for &kind in &b.backends {
            for &precision in kind.precisions() {
                let options = BackendOptions {
                    threads: b.threads,
                    precision,
                    ..common.dcnn.backend_options.clone()
                };
                let mut dcnn = match Dcnn::from_model(model.clone(), kind, &options) {
                    Ok(d) => d,
                    Err(e) => {
                        tracing::warn!("{name} {} {precision:?}: skipped: {e}", kind.name());
                        let _ = writeln!(
                            table,
                            "| {name} | {} | {precision:?} | – | skipped: {e} | | |",
                            kind.name()
                        );
                        bar.inc(b.sizes.len() as u64);
                        continue;
                    }
                };
                let macs = dcnn.network.macs_per_pixel;
                let mut seconds_per_pixel: Option<f64> = None;
                for &(w, h) in &b.sizes {
                    let pixels = (w * h) as f64;
                    if let Some(spp) = seconds_per_pixel
                        && spp * pixels * (b.repeat + 1) as f64 > b.max_seconds
                    {
                        let _ = writeln!(
                            table,
                            "| {name} | {} | {precision:?} | {w}×{h} | skipped (≈ {:.0} s per frame) | | |",
                            kind.name(),
                            spp * pixels
                        );
                        bar.inc(1);
                        continue;
                    }
                    let frame = bench_frame(w, h);
                    // The first run prepares per-size state (plans, buffers).
                    let t = Instant::now();
                    dcnn.run_frame(&frame)?;
                    let first = t.elapsed().as_secs_f64();
                    let mut times = Vec::new();
                    for _ in 0..b.repeat.max(1) {
                        let t = Instant::now();
                        dcnn.run_frame(&frame)?;
                        times.push(t.elapsed().as_secs_f64());
                    }
                    let med = median(times.clone());
                    let min = times.iter().copied().fold(f64::MAX, f64::min);
                    seconds_per_pixel = Some(med / pixels);
                    let gmacs = macs * pixels / med / 1e9;
                    let _ = writeln!(
                        table,
                        "| {name} | {} | {precision:?} | {w}×{h} | {:.1} | {:.1} | {gmacs:.1} |",
                        dcnn.describe(),
                        med * 1e3,
                        min * 1e3
                    );
                    on_record(&json!({
                        "kind": "dcnn_latency",
                        "model": name,
                        "macs_per_pixel": macs,
                        "backend": kind.name(),
                        "device": dcnn.describe(),
                        "precision": format!("{precision:?}").to_lowercase(),
                        "width": w,
                        "height": h,
                        "first_run_s": first,
                        "median_s": med,
                        "min_s": min,
                        "repeat": b.repeat,
                        "gmac_per_s": gmacs,
                    }));
                    bar.inc(1);
                }
            }
        }
    }
    bar.finish_and_clear();
    Ok(table)
}
