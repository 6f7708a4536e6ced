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
use nedrt_core::{Image, Named};
use nedrt_gpu::GpuError;
use nedrt_gpu::adapter::{AdapterReport, describe_cooperative_matrices, scalar_name};
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
    /// The adapter's peak rates for the per-layer floors.
    pub peaks: Peaks,
}

/// The adapter's peak rates for the floors; `None`: not given (the best
/// any layer of the table reached stands in).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Peaks {
    /// The general (CUDA) cores' multiply-adds, GMAC/s.
    pub gmacs: Option<f64>,
    /// The tensor cores' (matrix units') multiply-adds at f16, GMAC/s.
    pub tensor_gmacs: Option<f64>,
    /// Memory bandwidth, GB/s (bytes read plus written).
    pub gbps: Option<f64>,
}

impl Peaks {
    /// Every given rate must be a positive number; the error names its flag.
    pub fn check(&self) -> Result<(), AppError> {
        for (flag, v) in [
            ("--peak-gmacs", self.gmacs),
            ("--peak-tensor-gmacs", self.tensor_gmacs),
            ("--peak-gbps", self.gbps),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && v > 0.0)
            {
                return Err(AppError::option(
                    format!("{flag} {v}"),
                    "must be a positive rate",
                ));
            }
        }
        Ok(())
    }
}

/// The trainer's 4-level U-Net of first-level `width`, random weights.
pub fn synth_model(name: &str, width: i64) -> Result<ModelFile, AppError> {
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

/// The adapter wgpu takes for the bench's settings, or why there is none.
pub(crate) fn adapter(common: &CommonOptions) -> Result<AdapterReport, GpuError> {
    nedrt_gpu::adapter::default_adapter(&common.dcnn.backend_options.gpu)
}

/// The bench's first line for the wgpu backend: the adapter wgpu takes,
/// the cooperative-matrix shapes it lists, and the convolution kernels
/// `--conv-path` lets the backend use (so that a run on a lent GPU records
/// what its tensor cores offered).
pub(crate) fn adapter_line(
    adapter: &Result<AdapterReport, GpuError>,
    common: &CommonOptions,
) -> String {
    let path = common.dcnn.backend_options.conv_path;
    let adapter = match adapter {
        Ok(a) => a.describe(),
        Err(e) => format!("none ({e})"),
    };
    format!(
        "wgpu adapter: {adapter}. Convolution kernels: --conv-path {} ({}).\n",
        path.name(),
        path.help()
    )
}

/// The adapter as a record for the JSON lines (`kind: "adapter"`).
fn adapter_record(
    adapter: &Result<AdapterReport, GpuError>,
    common: &CommonOptions,
) -> serde_json::Value {
    let conv_path = common.dcnn.backend_options.conv_path.name();
    match adapter {
        Ok(a) => json!({
            "kind": "adapter",
            "name": a.name,
            "cooperative_matrix_feature": a.cooperative_matrix_feature,
            "cooperative_matrices": a.cooperative_matrices.iter().map(|p| json!({
                "m": p.m_size,
                "n": p.n_size,
                "k": p.k_size,
                "ab": scalar_name(p.ab_type),
                "cr": scalar_name(p.cr_type),
                "saturating": p.saturating_accumulation,
            })).collect::<Vec<_>>(),
            "cooperative_matrices_text": describe_cooperative_matrices(&a.cooperative_matrices),
            "conv_path": conv_path,
        }),
        Err(e) => {
            json!({"kind": "adapter", "name": null, "error": e.to_string(), "conv_path": conv_path})
        }
    }
}

/// The table's head: what the wall and the GPU columns measure.
pub const TABLE_HEAD: &str = "Wall: each frame as the host sees it (the frame's upload, the \
network, its read-back and the host's checks); GPU: the network alone on the device, from \
timestamp queries around its pass (– where the engine measures none). Median and least of \
--repeat runs after a warm-up; GMAC/s over each.\n\n\
| model | backend | precision | frame | wall median ms | wall min ms | GPU median ms | GPU min ms | \
GMAC/s (wall) | GMAC/s (GPU) |\n\
| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";

/// Medians and least of a case's runs, seconds: wall always, GPU where
/// every run measured it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaseTimes {
    pub wall_median: f64,
    pub wall_min: f64,
    pub gpu: Option<(f64, f64)>,
}

impl CaseTimes {
    pub fn new(wall: &[f64], gpu: &[Option<f64>]) -> Self {
        let least = |v: &[f64]| v.iter().copied().fold(f64::MAX, f64::min);
        let gpu: Option<Vec<f64>> = gpu.iter().copied().collect();
        Self {
            wall_median: median(wall.to_vec()),
            wall_min: least(wall),
            gpu: gpu
                .filter(|g| !g.is_empty())
                .map(|g| (median(g.clone()), least(&g))),
        }
    }

    /// The row's time and rate cells after the frame's (`macs` per frame).
    pub fn cells(&self, macs: f64) -> String {
        let (gm, gl, gr) = match self.gpu {
            Some((m, l)) => (
                format!("{:.2}", m * 1e3),
                format!("{:.2}", l * 1e3),
                format!("{:.1}", macs / m / 1e9),
            ),
            None => ("–".into(), "–".into(), "–".into()),
        };
        format!(
            "{:.2} | {:.2} | {gm} | {gl} | {:.1} | {gr}",
            self.wall_median * 1e3,
            self.wall_min * 1e3,
            macs / self.wall_median / 1e9
        )
    }
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
    let mut table = String::new();
    if b.backends.contains(&BackendKind::Wgpu) {
        let adapter = adapter(common);
        on_record(&adapter_record(&adapter, common));
        table += &adapter_line(&adapter, common);
        table.push('\n');
    }
    table += TABLE_HEAD;
    // Where each wgpu network's convolutions run, after the table.
    let mut placements = String::new();
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
                            "| {name} | {} | {precision:?} | – | skipped: {e} | | | | | |",
                            kind.name()
                        );
                        bar.inc(b.sizes.len() as u64);
                        continue;
                    }
                };
                if kind == BackendKind::Wgpu {
                    placements += &conv_placements(name, &dcnn, &options, b.sizes.first());
                }
                let macs = dcnn.network.macs_per_pixel;
                let mut seconds_per_pixel: Option<f64> = None;
                for &(w, h) in &b.sizes {
                    let pixels = (w * h) as f64;
                    if let Some(spp) = seconds_per_pixel
                        && spp * pixels * (b.repeat + 1) as f64 > b.max_seconds
                    {
                        let _ = writeln!(
                            table,
                            "| {name} | {} | {precision:?} | {w}×{h} | skipped (≈ {:.0} s per frame) | | | | | |",
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
                    let (mut wall, mut gpu) = (Vec::new(), Vec::new());
                    for _ in 0..b.repeat.max(1) {
                        let t = Instant::now();
                        dcnn.run_frame(&frame)?;
                        wall.push(t.elapsed().as_secs_f64());
                        gpu.push(dcnn.last_gpu_ns().map(|ns| ns as f64 * 1e-9));
                    }
                    let times = CaseTimes::new(&wall, &gpu);
                    seconds_per_pixel = Some(times.wall_median / pixels);
                    let _ = writeln!(
                        table,
                        "| {name} | {} | {precision:?} | {w}×{h} | {} |",
                        dcnn.describe(),
                        times.cells(macs * pixels)
                    );
                    let gpu_field = |f: fn((f64, f64)) -> f64| times.gpu.map(f);
                    on_record(&json!({
                        "kind": "dcnn_latency",
                        "model": name,
                        "macs_per_pixel": macs,
                        "backend": kind.name(),
                        "device": dcnn.describe(),
                        "precision": format!("{precision:?}").to_lowercase(),
                        // With the f16 arithmetic where it is not the default.
                        "conv_path": (kind == BackendKind::Wgpu).then(|| {
                            match options.f16_math {
                                nedrt_infer::F16Math::Auto => options.conv_path.name().to_string(),
                                m => format!("{}, {} math", options.conv_path.name(), m.name()),
                            }
                        }),
                        "width": w,
                        "height": h,
                        "first_run_s": first,
                        "median_s": times.wall_median,
                        "min_s": times.wall_min,
                        "gpu_median_s": gpu_field(|g| g.0),
                        "gpu_min_s": gpu_field(|g| g.1),
                        "repeat": b.repeat,
                        "gmac_per_s": macs * pixels / times.wall_median / 1e9,
                        "gpu_gmac_per_s": gpu_field(|g| g.0).map(|s| macs * pixels / s / 1e9),
                    }));
                    bar.inc(1);
                }
            }
        }
    }
    bar.finish_and_clear();
    if !placements.is_empty() {
        table += "\nWhere each convolution runs (tiled kernels, or cooperative matrices on the \
                  tensor cores), and why:\n";
        table += &placements;
    }
    Ok(table)
}

/// One wgpu network's convolution placements, a line each; where some
/// layer runs on cooperative matrices, the whole network against the same
/// network all tiled on one frame of `size` (rounded up to the network's
/// multiple): the check that the tensor-core kernels compute what the
/// tiled ones do, on the machines that have them.
fn conv_placements(
    name: &str,
    dcnn: &Dcnn,
    options: &BackendOptions,
    size: Option<&(usize, usize)>,
) -> String {
    let mut s = format!("\n{name}, {}:\n", dcnn.describe());
    let paths = dcnn.conv_paths();
    for line in &paths {
        let _ = writeln!(s, "- {line}");
    }
    if let Some(&(w, h)) = size
        && paths.iter().any(|l| l.contains(": cooperative matrix"))
    {
        let m = dcnn.network.multiple.max(1);
        let (w, h) = (w.div_ceil(m) * m, h.div_ceil(m) * m);
        let frame = bench_frame(w, h);
        let _ = match nedrt_infer::gpu::cooperative_against_tiled(&dcnn.network, options, &frame) {
            Ok(Some(d)) => writeln!(
                s,
                "- cooperative against tiled at {w}×{h}: max |Δ| = {d:.2e} (f16's tolerance: 2e-2)"
            ),
            Ok(None) => Ok(()),
            Err(e) => writeln!(s, "- cooperative against tiled at {w}×{h}: failed: {e}"),
        };
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gpu_time_is_shown_only_where_every_run_measured_it() {
        let t = CaseTimes::new(
            &[0.003, 0.001, 0.002],
            &[Some(0.0015), Some(0.0005), Some(0.001)],
        );
        assert_eq!(t.wall_median, 0.002);
        assert_eq!(t.wall_min, 0.001);
        assert_eq!(t.gpu, Some((0.001, 0.0005)));
        // 2e9 MACs a frame: 1000 GMAC/s on the wall median, 2000 on the GPU's.
        assert_eq!(t.cells(2e9), "2.00 | 1.00 | 1.00 | 0.50 | 1000.0 | 2000.0");
        let host = CaseTimes::new(&[0.002], &[None]);
        assert_eq!(host.gpu, None);
        assert_eq!(host.cells(2e9), "2.00 | 2.00 | – | – | 1000.0 | –");
        let partly = CaseTimes::new(&[0.002, 0.002], &[Some(0.001), None]);
        assert_eq!(partly.gpu, None);
    }

    #[test]
    fn the_head_names_the_wall_and_the_gpu_columns() {
        let cells = TABLE_HEAD
            .lines()
            .find(|l| l.starts_with("| model"))
            .unwrap();
        assert_eq!(cells.matches('|').count(), 11);
        assert!(TABLE_HEAD.contains("GPU: the network alone on the device, from timestamp"));
        assert!(TABLE_HEAD.contains("Wall: each frame as the host sees it"));
    }
}
