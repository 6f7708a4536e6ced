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
        let proto = synth::unet(*width, 4, 1);
        let model = ModelFile::from_bytes(
            std::path::Path::new(&format!("synth-{name}.onnx")),
            synth::encode(&proto),
        )?;
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
                    let frame = Image::rgb(
                        w,
                        h,
                        (0..3 * w * h)
                            .map(|i| ((i * 7919) % 1000) as f32 / 1000.0)
                            .collect(),
                    );
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
