//! nedrt's generated WGSL against burn's wgpu backend: the same ONNX model, the
//! same frame sizes, the same adapter, in one run. For each model and size it
//! checks that the two contenders agree on a deterministic random input, then
//! times both, interleaved (ABBA order) after warm-up runs, each doing the same
//! work: a host f32 CHW tensor in, the network, a host f32 tensor out.
//! README.md says how to build and run it.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail, ensure};
use burn::tensor::{Device, Tensor};
use nedrt_infer::gpu::GpuBackend;
use nedrt_infer::{ModelFile, Precision};
use serde_json::json;

mod args;
mod machine;
mod measure;
use args::{Contender, parse_args};
use machine::{adapter_json, describe, loadavg, nedrt_commit};
use measure::{Timings, agreement, macs, random_input, run_burn, run_nedrt, stats};

/// The models burn-onnx generated in build.rs.
#[allow(clippy::all, unused, missing_debug_implementations)]
mod imported {
    pub mod dcnn {
        include!(concat!(env!("OUT_DIR"), "/model/dcnn.rs"));
    }
    pub mod dcnn_w32 {
        include!(concat!(env!("OUT_DIR"), "/model/dcnn_w32.rs"));
    }
}

/// One of the imported burn models.
enum BurnNet {
    Dcnn(imported::dcnn::Model),
    DcnnW32(imported::dcnn_w32::Model),
}

impl BurnNet {
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        match self {
            BurnNet::Dcnn(m) => m.forward(x),
            BurnNet::DcnnW32(m) => m.forward(x),
        }
    }
}

/// A model both contenders run: nedrt reads `onnx` at run time; burn runs the
/// code build.rs generated from the same file (checked by `fnv`).
struct ModelSpec {
    name: &'static str,
    what: &'static str,
    onnx: PathBuf,
    /// FNV-1a of the ONNX file burn was built from.
    fnv: &'static str,
    load: fn(&Device) -> BurnNet,
}

fn models() -> Vec<ModelSpec> {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    vec![
        ModelSpec {
            name: "dcnn",
            what: "shipped models/dcnn.onnx: U-Net width 16, 4 levels, trained",
            onnx: here.join("../../models/dcnn.onnx"),
            fnv: env!("NEDRT_BENCH_FNV_DCNN"),
            load: |d| BurnNet::Dcnn(imported::dcnn::Model::from_embedded(d)),
        },
        ModelSpec {
            name: "dcnn_w32",
            what: "full-width architecture: U-Net width 32, 4 levels, random weights",
            onnx: here.join("models/dcnn_w32.onnx"),
            fnv: env!("NEDRT_BENCH_FNV_DCNN_W32"),
            load: |d| BurnNet::DcnnW32(imported::dcnn_w32::Model::from_embedded(d)),
        },
    ]
}

/// FNV-1a, 64 bits: the same function as build.rs's.
fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

fn main() -> Result<()> {
    let mut args = parse_args()?;
    // burn's runtime (cubecl) finds its configuration, cubecl.toml, from the
    // working directory: run from this crate's folder, whatever the caller's.
    if let Some(json) = &args.json {
        args.json = Some(std::path::absolute(json)?);
    }
    std::env::set_current_dir(env!("CARGO_MANIFEST_DIR"))
        .context("cannot enter the benchmark's folder")?;
    let all = models();
    let mut chosen = Vec::new();
    for name in &args.models {
        let Some(m) = all.iter().find(|m| m.name == name) else {
            bail!(
                "unknown model '{name}' (known: {})",
                all.iter().map(|m| m.name).collect::<Vec<_>>().join(", ")
            );
        };
        // Read and checked before any device opens: a missing or changed
        // file is said at once.
        let bytes = std::fs::read(&m.onnx).with_context(|| {
            format!(
                "cannot read {} (the full-width model is made by bench/burn/make-models.sh)",
                m.onnx.display()
            )
        })?;
        let hash = format!("{:016x}", fnv1a64(&bytes));
        ensure!(
            hash == m.fnv,
            "{} changed since burn imported it at build time (hash {hash}, built from {}): \
             rebuild (cargo build --release) so both contenders run the same model",
            m.onnx.display(),
            m.fnv
        );
        chosen.push((m, bytes, hash));
    }

    let burn_version = env!("NEDRT_BENCH_BURN_VERSION");
    let commit = nedrt_commit();
    println!("# nedrt vs burn (wgpu), f32, one process\n");
    println!("- nedrt: {commit} (nedrt-infer, generated WGSL)");
    println!(
        "- burn: {burn_version} (burn-onnx {}, wgpu backend: autotune and fusion on, its defaults), wgpu {}",
        env!("NEDRT_BENCH_BURN_ONNX_VERSION"),
        env!("NEDRT_BENCH_WGPU_VERSION")
    );

    // Every adapter wgpu sees, on every backend.
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends: wgpu::Backends::all(),
        ..wgpu::InstanceDescriptor::new_without_display_handle()
    });
    let adapters: Vec<wgpu::AdapterInfo> =
        pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()))
            .iter()
            .map(|a| a.get_info())
            .collect();
    drop(instance);
    println!("- adapters wgpu lists:");
    for a in &adapters {
        println!("  - {}", describe(a));
    }

    // nedrt: one device for both models, opened as the runtime opens it:
    // wgpu's primary backends (nedrt's default), or WGPU_BACKEND's.
    let mut settings = nedrt_gpu::GpuSettings::default();
    if let Some(backends) = wgpu::Backends::from_env() {
        settings.backends = backends;
    }
    let n_gpu = match args.only {
        Some(Contender::Burn) => None,
        _ => Some(
            nedrt_infer::gpu::open_device(&settings, Precision::F32).context("nedrt's device")?,
        ),
    };
    let n_info = n_gpu.as_ref().map(|(a, _, _)| a.get_info());
    let n_timestamps = n_gpu
        .as_ref()
        .is_some_and(|(_, d, _)| d.features().contains(wgpu::Features::TIMESTAMP_QUERY));
    if let Some(info) = &n_info {
        println!(
            "- nedrt's adapter: {} (timestamp queries: {})",
            describe(info),
            if n_timestamps { "yes" } else { "no" }
        );
    }

    // burn: its own device on the adapter its default selection picks; the
    // setup it returns says which.
    let b_gpu = match args.only {
        Some(Contender::Nedrt) => None,
        _ => Some(
            Device::wgpu_options()
                .init_with_setup()
                .map_err(|e| anyhow::anyhow!("burn's wgpu device: {e:?}"))?,
        ),
    };
    let b_info = b_gpu.as_ref().map(|(_, s)| s.adapter.get_info());
    let same = match (&n_info, &b_info) {
        (Some(n), Some(b)) => Some(
            b.name == n.name
                && b.backend == n.backend
                && b.driver == n.driver
                && b.driver_info == n.driver_info,
        ),
        _ => None,
    };
    let b_features = b_gpu
        .as_ref()
        .map(|(_, s)| format!("{:?}", s.device.features()));
    if let (Some(info), Some((_, setup))) = (&b_info, &b_gpu) {
        println!(
            "- burn's adapter: {} (wgpu backend {:?}; same adapter as nedrt: {})",
            describe(info),
            setup.backend,
            match same {
                Some(true) => "yes",
                Some(false) => "NO",
                None => "n/a",
            }
        );
        println!(
            "- burn's device features: {}",
            b_features.as_deref().unwrap_or_default()
        );
    }
    if let Some(e) = args.only {
        println!("- only {} runs (--only): no comparison", e.name());
    }
    println!(
        "- timing: {} warm-up run(s) per contender (the first is cold: pipelines, burn's autotune), \
         then interleaved (ABBA) timed runs until {:.0} s are spent per model and size \
         (min {} iterations, max {}){}",
        args.warmup,
        args.budget_s,
        args.min_iters,
        args.max_iters,
        args.iters
            .map(|n| format!(", fixed at {n} by --iters"))
            .unwrap_or_default()
    );
    println!();

    let load_start = loadavg();
    let started = Instant::now();
    let mut rows = Vec::new();
    let mut table = String::from(
        "| model | size | GMAC | iters | nedrt median ms | nedrt p90 ms | nedrt device ms | burn median ms | burn p90 ms | nedrt : burn | max abs diff (÷ branch) | first run ms nedrt / burn | GMAC/s nedrt / burn |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let ms = |v: Option<f64>, digits: usize| v.map_or("n/a".into(), |v| format!("{v:.digits$}"));
    for (mi, (spec, bytes, hash)) in chosen.into_iter().enumerate() {
        let model = ModelFile::from_bytes(&spec.onnx, bytes)?;
        let network = model.lower()?;
        let mut nedrt = match &n_gpu {
            Some((_, device, queue)) => Some(GpuBackend::new(
                device,
                queue,
                n_info.as_ref().map(|i| i.name.clone()).unwrap_or_default(),
                &network,
                Precision::F32,
            )?),
            None => None,
        };
        let burn = b_gpu.as_ref().map(|(d, _)| ((spec.load)(d), d));
        eprintln!("{}: {}", spec.name, spec.what);

        for &size in &args.sizes {
            ensure!(
                size % network.multiple == 0,
                "{size} is not a multiple of {}, the network's multiple",
                network.multiple
            );
            let bands = match &nedrt {
                Some(be) => Some(size.div_ceil(be.window_rows(size, size)?)),
                None => None,
            };
            let input = random_input(3 * size * size, 0x5eed ^ ((size as u64) << 8) ^ mi as u64);
            let (mut n_t, mut b_t) = (Timings::default(), Timings::default());
            let mut run = |engine: Contender,
                           n_t: &mut Timings,
                           b_t: &mut Timings|
             -> Result<Option<Vec<f32>>> {
                Ok(match engine {
                    Contender::Nedrt => match &mut nedrt {
                        Some(be) => {
                            let (ms, dev, out) = run_nedrt(be, &input, size)?;
                            n_t.push(ms, dev);
                            Some(out)
                        }
                        None => None,
                    },
                    Contender::Burn => match &burn {
                        Some((net, device)) => {
                            let (ms, out) = run_burn(net, device, &input, size)?;
                            b_t.push(ms, None);
                            Some(out)
                        }
                        None => None,
                    },
                })
            };

            // Warm-up: compiles pipelines (and runs burn's autotune) for this size.
            let mut outs = (None, None);
            for _ in 0..args.warmup {
                outs = (
                    run(Contender::Nedrt, &mut n_t, &mut b_t)?,
                    run(Contender::Burn, &mut n_t, &mut b_t)?,
                );
            }
            let (n_first, b_first) = (n_t.ms.first().copied(), b_t.ms.first().copied());
            let agree = match &outs {
                (Some(n), Some(b)) => {
                    let a = agreement(&input, n, b)?;
                    ensure!(
                        a.non_finite == 0,
                        "{} {size}²: {} non-finite outputs",
                        spec.name,
                        a.non_finite
                    );
                    Some(a)
                }
                _ => None,
            };
            eprintln!(
                "  {size}×{size}: first runs {} / {} ms, last warm-up {} / {} ms (nedrt / burn); \
                 max abs diff {}",
                ms(n_first, 0),
                ms(b_first, 0),
                ms(n_t.ms.last().copied(), 1),
                ms(b_t.ms.last().copied(), 1),
                agree
                    .as_ref()
                    .map_or("n/a".into(), |a| format!("{:.2e}", a.max_abs))
            );
            n_t.reset();
            b_t.reset();

            // Timed runs: a fixed count, or until the budget is spent (at
            // least `min_iters`, at most `max_iters`, a whole ABBA block).
            let clock = Instant::now();
            let more = |i: usize| match args.iters {
                Some(n) => i < n,
                None => {
                    i < args.max_iters
                        && (i < args.min_iters
                            || i % 2 == 1
                            || clock.elapsed().as_secs_f64() < args.budget_s)
                }
            };
            let mut iters = 0;
            while more(iters) {
                // ABBA: each contender goes first in half the pairs.
                let order = if iters % 2 == 0 {
                    [Contender::Nedrt, Contender::Burn]
                } else {
                    [Contender::Burn, Contender::Nedrt]
                };
                for e in order {
                    run(e, &mut n_t, &mut b_t)?;
                }
                iters += 1;
            }
            eprintln!(
                "    timed {iters} iterations each in {:.0} s",
                clock.elapsed().as_secs_f64()
            );
            let gmac = macs(&network, size) as f64 / 1e9;
            let n_s = stats(&n_t.ms);
            let b_s = stats(&b_t.ms);
            let dev_med = stats(&n_t.dev).map(|s| s.0);
            let ratio = n_s.zip(b_s).map(|(n, b)| n.0 / b.0);
            let rel = agree
                .as_ref()
                .map(|a| a.max_abs / a.max_abs_branch.max(f64::MIN_POSITIVE));
            table.push_str(&format!(
                "| {} | {size}×{size} | {gmac:.2} | {iters} | {} | {} | {} | {} | {} | {} | {} | {} / {} | {} / {} |\n",
                spec.name,
                ms(n_s.map(|s| s.0), 2),
                ms(n_s.map(|s| s.1), 2),
                ms(dev_med, 2),
                ms(b_s.map(|s| s.0), 2),
                ms(b_s.map(|s| s.1), 2),
                ms(ratio, 2),
                agree.as_ref().zip(rel).map_or("n/a".into(), |(a, r)| format!(
                    "{:.2e} ({r:.1e})",
                    a.max_abs
                )),
                ms(n_first, 0),
                ms(b_first, 0),
                ms(n_s.map(|s| gmac / s.0 * 1e3), 2),
                ms(b_s.map(|s| gmac / s.0 * 1e3), 2),
            ));
            let summary = |s: Option<(f64, f64, f64)>, first: Option<f64>, runs: &[f64]| {
                s.map(|(median, p90, min)| {
                    json!({"median": median, "p90": p90, "min": min, "first_run": first, "runs": runs})
                })
            };
            rows.push(json!({
                "model": spec.name,
                "model_description": spec.what,
                "onnx": spec.onnx.display().to_string(),
                "onnx_fnv1a64": hash,
                "size": [size, size],
                "input_shape": [1, 3, size, size],
                "gmac": gmac,
                "iterations": iters,
                "warmup_runs": args.warmup,
                "nedrt_bands": bands,
                "nedrt_ms": summary(n_s, n_first, &n_t.ms),
                "nedrt_device_ms_median": dev_med,
                "burn_ms": summary(b_s, b_first, &b_t.ms),
                "ratio_nedrt_to_burn_median": ratio,
                "max_abs_diff": agree.as_ref().map(|a| a.max_abs),
                "max_abs_output": agree.as_ref().map(|a| a.max_abs_out),
                "max_abs_unet_branch": agree.as_ref().map(|a| a.max_abs_branch),
                "max_abs_diff_relative_to_branch": rel,
                "burn_outputs_outside_0_1": agree.as_ref().map(|a| a.clamped),
            }));
        }
    }
    let run_s = started.elapsed().as_secs_f64();
    let load_end = loadavg();
    println!("{table}");
    println!(
        "nedrt : burn is the ratio of the median wall times (below 1: nedrt is faster). Wall time \
         is host tensor in → run → host tensor out for both; nedrt device ms is its timestamp-query \
         time of the network's pass. max abs diff compares nedrt's output with burn's clamped to \
         [0, 1] (nedrt's last kernel clamps; the ONNX graph does not); ÷ branch divides it by the \
         largest |output − input|, the U-Net branch of I + UNet(I). GMAC: the convolutions' \
         multiply-adds per frame; GMAC/s from the medians. Benchmark time: {run_s:.0} s; \
         load average (1, 5, 15 min) {load_start} at the start, {load_end} at the end."
    );

    if let Some(path) = &args.json {
        let report = json!({
            "nedrt_commit": commit,
            "burn_version": burn_version,
            "burn_onnx_version": env!("NEDRT_BENCH_BURN_ONNX_VERSION"),
            "wgpu_version": env!("NEDRT_BENCH_WGPU_VERSION"),
            "precision": "f32",
            "adapters": adapters.iter().map(adapter_json).collect::<Vec<_>>(),
            "only": args.only.map(Contender::name),
            "nedrt_adapter": n_info.as_ref().map(adapter_json),
            "nedrt_timestamp_queries": n_timestamps,
            "burn_adapter": b_info.as_ref().map(adapter_json),
            "burn_wgpu_backend": b_gpu.as_ref().map(|(_, s)| format!("{:?}", s.backend)),
            "burn_device_features": b_features,
            "same_adapter": same,
            "timing": {
                "warmup_runs": args.warmup,
                "budget_s_per_case": args.budget_s,
                "min_iters": args.min_iters,
                "max_iters": args.max_iters,
                "fixed_iters": args.iters,
                "order": "ABBA (nedrt, burn, burn, nedrt, ...)",
            },
            "benchmark_seconds": run_s,
            "loadavg_start": load_start,
            "loadavg_end": load_end,
            "results": rows,
        });
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
