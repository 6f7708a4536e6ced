//! `nedrt bench inference --per-layer`: each layer of each model on the
//! wgpu backend, its GPU time (timestamp queries, each layer in a pass of
//! its own) against its floors: the CUDA-core floor (MACs over the general
//! cores' multiply-add rate, or bytes over the bandwidth, whichever is
//! larger) and, for a layer on cooperative matrices, the tensor-core floor
//! (MACs over the matrix units' rate). Beside them, the whole frame's wall
//! time and GPU time, so that the layers' sum can be read against both.
//! Performance is measured here, never asserted in tests.

use std::fmt::Write as _;
use std::time::Instant;

use super::AppError;
use super::bench::median;
use super::bench_inference::{
    InferenceBench, Peaks, adapter, adapter_line, bench_frame, synth_model,
};
use crate::CommonOptions;
use nedrt_infer::{BackendKind, BackendOptions, Dcnn, LayerTiming};

/// The rates one table's floors are taken from, and where each came from.
#[derive(Debug, Clone, PartialEq)]
pub struct Rates {
    pub gmacs: f64,
    /// Only where given or where some layer ran on the tensor cores.
    pub tensor_gmacs: Option<f64>,
    pub gbps: f64,
    pub whence: String,
}

fn secs(r: &LayerTiming) -> f64 {
    r.gpu_ns.max(1) as f64 * 1e-9
}

fn gmacs(r: &LayerTiming) -> f64 {
    r.macs as f64 / secs(r) / 1e9
}

fn gbps(r: &LayerTiming) -> f64 {
    r.bytes as f64 / secs(r) / 1e9
}

impl Rates {
    /// The given peaks, or the best the table's layers reached: the MAC
    /// rate of the layers on the general cores only, so a tensor-core
    /// layer does not raise their floor.
    pub fn new(peaks: &Peaks, rows: &[LayerTiming]) -> Self {
        let best = |f: fn(&LayerTiming) -> f64, tensor: Option<bool>| {
            rows.iter()
                .filter(|r| tensor.is_none_or(|t| r.tensor_cores == t))
                .map(f)
                .fold(0.0f64, f64::max)
                // A table without MACs (or bytes) still divides by a rate.
                .max(f64::MIN_POSITIVE)
        };
        let any_tensor = rows.iter().any(|r| r.tensor_cores);
        let whence = |given: Option<f64>, flag: &str| {
            if given.is_some() {
                format!("{flag} as given")
            } else {
                format!("{flag} not given: the best any layer reached here")
            }
        };
        let mut said = vec![whence(peaks.gmacs, "--peak-gmacs")];
        if peaks.tensor_gmacs.is_some() || any_tensor {
            said.push(whence(peaks.tensor_gmacs, "--peak-tensor-gmacs"));
        }
        said.push(whence(peaks.gbps, "--peak-gbps"));
        Self {
            gmacs: peaks.gmacs.unwrap_or_else(|| best(gmacs, Some(false))),
            tensor_gmacs: peaks
                .tensor_gmacs
                .or_else(|| any_tensor.then(|| best(gmacs, Some(true)))),
            gbps: peaks.gbps.unwrap_or_else(|| best(gbps, None)),
            whence: said.join("; "),
        }
    }

    /// max(MACs ÷ the general cores' rate, bytes ÷ bandwidth), seconds.
    pub fn cuda_floor_s(&self, r: &LayerTiming) -> f64 {
        (r.macs as f64 / (self.gmacs * 1e9)).max(r.bytes as f64 / (self.gbps * 1e9))
    }

    /// max(MACs ÷ the tensor cores' rate, bytes ÷ bandwidth), seconds, for
    /// a layer that ran on them.
    pub fn tensor_floor_s(&self, r: &LayerTiming) -> Option<f64> {
        let t = self.tensor_gmacs.filter(|_| r.tensor_cores)?;
        Some((r.macs as f64 / (t * 1e9)).max(r.bytes as f64 / (self.gbps * 1e9)))
    }

    /// The floor of the units the layer ran on.
    pub fn own_floor_s(&self, r: &LayerTiming) -> f64 {
        self.tensor_floor_s(r)
            .unwrap_or_else(|| self.cuda_floor_s(r))
    }
}

/// The whole frame timed as `bench inference` times it: wall and GPU
/// medians, seconds (GPU `None` where the backend measured none).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTimes {
    pub wall_s: f64,
    pub gpu_s: Option<f64>,
    pub runs: usize,
}

/// Each layer of each model on the wgpu backend at each size: GPU time,
/// work, rates, and how far from its floors.
pub fn per_layer(b: &InferenceBench, common: &CommonOptions) -> Result<String, AppError> {
    b.peaks.check()?;
    let mut md = adapter_line(&adapter(common), common);
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
                match time_layers(&mut dcnn, &frame, b.repeat) {
                    Ok((rows, whole)) => {
                        md += &layer_table(
                            &format!("{name} on {}, {w}×{h}", dcnn.describe()),
                            &rows,
                            &whole,
                            &Rates::new(&b.peaks, &rows),
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

/// The best of `repeat` per-layer timings after one that prepares the
/// plan, and the whole frame's median wall and GPU time.
fn time_layers(
    dcnn: &mut Dcnn,
    frame: &nedrt_core::Image,
    repeat: usize,
) -> Result<(Vec<LayerTiming>, FrameTimes), AppError> {
    let mut best = dcnn.layer_timings(frame)?;
    for _ in 0..repeat.max(1) {
        let next = dcnn.layer_timings(frame)?;
        for (a, n) in best.iter_mut().zip(next) {
            a.gpu_ns = a.gpu_ns.min(n.gpu_ns);
        }
    }
    dcnn.run_frame(frame)?;
    let (mut wall, mut gpu) = (Vec::new(), Vec::new());
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        dcnn.run_frame(frame)?;
        wall.push(t.elapsed().as_secs_f64());
        gpu.push(dcnn.last_gpu_ns().map(|ns| ns as f64 * 1e-9));
    }
    let runs = wall.len();
    let gpu: Option<Vec<f64>> = gpu.into_iter().collect();
    Ok((
        best,
        FrameTimes {
            wall_s: median(wall),
            gpu_s: gpu.map(median),
            runs,
        },
    ))
}

fn ms(v: Option<f64>) -> String {
    v.map_or("–".into(), |s| format!("{:.3}", s * 1e3))
}

fn times(v: Option<f64>) -> String {
    v.map_or("–".into(), |x| format!("{x:.1}"))
}

/// One run's per-layer table, the whole frame's times and the layers
/// furthest from their floors.
pub fn layer_table(title: &str, rows: &[LayerTiming], whole: &FrameTimes, f: &Rates) -> String {
    let total: f64 = rows.iter().map(secs).sum();
    let tensor = match f.tensor_gmacs {
        Some(t) => format!(
            "tensor-core floor = max(MACs ÷ {t:.2} GMAC/s, bytes ÷ {:.2} GB/s) for the layers on \
             cooperative matrices ({} of {} here)",
            f.gbps,
            rows.iter().filter(|r| r.tensor_cores).count(),
            rows.len()
        ),
        None => "no layer ran on the tensor cores (cooperative matrices), so none has a \
                 tensor-core floor"
            .into(),
    };
    let mut md = format!(
        "\n### {title}\n\n\
         The whole frame: {} ms wall (the host's view: upload, the network, read-back and the \
         host's checks), {} ms GPU (the network's one pass, timestamp queries); medians of {}. \
         Each layer below in a pass of its own, GPU time (timestamps): {:.3} ms in all.\n\n\
         CUDA-core floor = max(MACs ÷ {:.2} GMAC/s, bytes ÷ {:.2} GB/s) for every layer; {tensor}; \
         {}.\n\n\
         | # | layer | cores | output C×H×W | MMAC | MB | GPU ms | share | GMAC/s | GB/s | \
         CUDA-core floor ms | × it | tensor-core floor ms | × it |\n\
         | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n",
        ms(Some(whole.wall_s)),
        ms(whole.gpu_s),
        whole.runs,
        total * 1e3,
        f.gmacs,
        f.gbps,
        f.whence,
    );
    for r in rows {
        let tf = f.tensor_floor_s(r);
        let _ = writeln!(
            md,
            "| {} | {} | {} | {}×{}×{} | {:.1} | {:.1} | {:.3} | {:.1} % | {:.2} | {:.2} | {} | {} | {} | {} |",
            r.layer,
            r.kind,
            if r.tensor_cores { "tensor" } else { "CUDA" },
            r.output[0],
            r.output[1],
            r.output[2],
            r.macs as f64 / 1e6,
            r.bytes as f64 / 1e6,
            secs(r) * 1e3,
            100.0 * secs(r) / total,
            gmacs(r),
            gbps(r),
            ms(Some(f.cuda_floor_s(r))),
            times(Some(secs(r) / f.cuda_floor_s(r))),
            ms(tf),
            times(tf.map(|t| secs(r) / t)),
        );
    }
    let mut order: Vec<&LayerTiming> = rows.iter().collect();
    // Furthest from the floor of the cores it ran on, weighted by the time
    // it costs: the layers whose tuning would pay most.
    let above = |r: &LayerTiming| secs(r) - f.own_floor_s(r);
    order.sort_by(|a, b| above(b).total_cmp(&above(a)));
    let worst: Vec<String> = order
        .iter()
        .take(3)
        .map(|r| {
            format!(
                "#{} {} ({:.1}× its {} floor, {:.2} ms above it)",
                r.layer,
                r.kind,
                secs(r) / f.own_floor_s(r),
                if f.tensor_floor_s(r).is_some() {
                    "tensor-core"
                } else {
                    "CUDA-core"
                },
                above(r) * 1e3
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

#[cfg(test)]
mod tests {
    use super::*;

    fn row(layer: usize, macs: u64, bytes: u64, gpu_ns: u64, tensor_cores: bool) -> LayerTiming {
        LayerTiming {
            layer,
            kind: if tensor_cores {
                "conv 3×3 (coop)"
            } else {
                "conv 3×3"
            }
            .into(),
            output: [8, 4, 4],
            macs,
            bytes,
            gpu_ns,
            tensor_cores,
        }
    }

    #[test]
    fn floors_take_the_larger_of_work_and_traffic_on_the_cores_used() {
        let peaks = Peaks {
            gmacs: Some(1000.0),
            tensor_gmacs: Some(10_000.0),
            gbps: Some(100.0),
        };
        // 1e9 MACs, 1e8 bytes: 1 ms of MACs on the CUDA cores, 0.1 ms on
        // the tensor cores, 1 ms of bytes.
        let general = row(0, 1_000_000_000, 100_000_000, 3_000_000, false);
        let matrix = row(1, 1_000_000_000, 10_000_000, 500_000, true);
        let f = Rates::new(&peaks, &[general.clone(), matrix.clone()]);
        assert!((f.cuda_floor_s(&general) - 1e-3).abs() < 1e-12);
        assert_eq!(f.tensor_floor_s(&general), None);
        assert!((f.tensor_floor_s(&matrix).unwrap() - 1e-4).abs() < 1e-12);
        assert!((f.own_floor_s(&matrix) - 1e-4).abs() < 1e-12);
        assert!((f.own_floor_s(&general) - 1e-3).abs() < 1e-12);
        assert!(f.whence.contains("--peak-tensor-gmacs as given"));
    }

    #[test]
    fn missing_peaks_are_the_best_rates_of_the_cores_that_ran() {
        // The general layer reaches 100 GMAC/s, the tensor layer 1000: the
        // CUDA-core rate must not be raised by the tensor layer.
        let rows = [
            row(0, 100_000_000, 1000, 1_000_000, false),
            row(1, 1_000_000_000, 1000, 1_000_000, true),
        ];
        let f = Rates::new(&Peaks::default(), &rows);
        assert!((f.gmacs - 100.0).abs() < 1e-9);
        assert!((f.tensor_gmacs.unwrap() - 1000.0).abs() < 1e-9);
        // Without tensor layers nor the flag there is no tensor rate.
        let f = Rates::new(&Peaks::default(), &rows[..1]);
        assert_eq!(f.tensor_gmacs, None);
        assert!(!f.whence.contains("tensor"));
        // A table of pools (no MACs) still has a finite CUDA-core floor.
        let f = Rates::new(&Peaks::default(), &[row(0, 0, 1000, 1000, false)]);
        assert!(f.cuda_floor_s(&row(0, 0, 1000, 1000, false)).is_finite());
    }

    #[test]
    fn a_bad_peak_is_refused_naming_its_flag() {
        for (peaks, flag) in [
            (
                Peaks {
                    gmacs: Some(0.0),
                    ..Peaks::default()
                },
                "--peak-gmacs 0",
            ),
            (
                Peaks {
                    tensor_gmacs: Some(f64::NAN),
                    ..Peaks::default()
                },
                "--peak-tensor-gmacs NaN",
            ),
            (
                Peaks {
                    gbps: Some(-1.0),
                    ..Peaks::default()
                },
                "--peak-gbps -1",
            ),
        ] {
            let e = peaks.check().unwrap_err().to_string();
            assert!(e.starts_with(flag), "{e}");
        }
        assert!(Peaks::default().check().is_ok());
    }

    #[test]
    fn the_table_says_which_time_is_which_and_marks_tensor_layers() {
        let rows = [
            row(0, 1_000_000_000, 100_000_000, 3_000_000, false),
            row(1, 1_000_000_000, 10_000_000, 500_000, true),
        ];
        let peaks = Peaks {
            gmacs: Some(1000.0),
            tensor_gmacs: Some(10_000.0),
            gbps: Some(100.0),
        };
        let whole = FrameTimes {
            wall_s: 0.010,
            gpu_s: Some(0.004),
            runs: 3,
        };
        let md = layer_table("t", &rows, &whole, &Rates::new(&peaks, &rows));
        assert!(md.contains("10.000 ms wall"), "{md}");
        assert!(md.contains("4.000 ms GPU"), "{md}");
        assert!(md.contains("3.500 ms in all"), "{md}");
        assert!(md.contains("| 0 | conv 3×3 | CUDA |"), "{md}");
        // 3 ms against a 1 ms CUDA-core floor; no tensor-core floor.
        assert!(md.contains("| 1.000 | 3.0 | – | – |"), "{md}");
        // 0.5 ms against 1 ms CUDA-core, 0.1 ms tensor-core floor.
        assert!(md.contains("| tensor |"), "{md}");
        assert!(md.contains("| 1.000 | 0.5 | 0.100 | 5.0 |"), "{md}");
        assert!(md.contains("#0 conv 3×3 (3.0× its CUDA-core floor, 2.00 ms above it)"));
        let none = FrameTimes {
            gpu_s: None,
            ..whole
        };
        let md = layer_table(
            "t",
            &rows[..1],
            &none,
            &Rates::new(&Peaks::default(), &rows[..1]),
        );
        assert!(md.contains("– ms GPU"), "{md}");
        assert!(md.contains("no layer ran on the tensor cores"), "{md}");
    }
}
