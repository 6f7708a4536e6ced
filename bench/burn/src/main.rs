//! nedrt's generated WGSL against burn's wgpu backend: the same ONNX model, the
//! same frame sizes, the same adapter, in one run. For each model and size it
//! checks that the two engines agree on a deterministic random input, then
//! times both, interleaved (ABBA order) after warm-up runs, each doing the same
//! work: a host f32 CHW tensor in, the network, a host f32 tensor out.
//! README.md says how to build and run it.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail, ensure};
use burn::tensor::{Device, Tensor, TensorData};
use nedrt_infer::gpu::GpuBackend;
use nedrt_infer::{Backend as _, ModelFile, Precision};
use serde_json::{Value, json};

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

/// A model both engines run: nedrt reads `onnx` at run time; burn runs the
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

struct Args {
    json: Option<PathBuf>,
    sizes: Vec<usize>,
    models: Vec<String>,
    /// Fixed timed iterations per model and size (else from `budget_s`).
    iters: Option<usize>,
    /// Seconds of timed runs (both engines) per model and size: iterations
    /// go on until it is spent (within `min_iters` and `max_iters`).
    budget_s: f64,
    min_iters: usize,
    max_iters: usize,
    warmup: usize,
    /// Runs one engine alone (an isolation check): no comparison.
    only: Option<Engine>,
}

const USAGE: &str = "usage: nedrt-bench-burn [--json PATH] [--sizes 64,256,512] \
[--models dcnn,dcnn_w32] [--iters N | --budget SECONDS] [--min-iters N] [--max-iters N] [--warmup N] \
[--only nedrt|burn]";

fn parse_args() -> Result<Args> {
    let mut a = Args {
        json: None,
        sizes: vec![64, 256, 512],
        models: vec!["dcnn".into(), "dcnn_w32".into()],
        iters: None,
        budget_s: 30.0,
        min_iters: 4,
        max_iters: 100,
        warmup: 1,
        only: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        if flag == "-h" || flag == "--help" {
            println!("{USAGE}");
            std::process::exit(0);
        }
        let value = it
            .next()
            .with_context(|| format!("{flag} needs a value\n{USAGE}"))?;
        let count = |v: &str| -> Result<usize> {
            v.parse()
                .with_context(|| format!("{flag}: '{v}' is not a count"))
        };
        match flag.as_str() {
            "--json" => a.json = Some(value.into()),
            "--sizes" => {
                a.sizes = value
                    .split(',')
                    .map(|s| count(s.trim()))
                    .collect::<Result<_>>()?
            }
            "--models" => a.models = value.split(',').map(|s| s.trim().to_string()).collect(),
            "--iters" => a.iters = Some(count(&value)?.max(1)),
            "--budget" => {
                a.budget_s = value
                    .parse()
                    .with_context(|| format!("--budget: '{value}' is not a number"))?
            }
            "--min-iters" => a.min_iters = count(&value)?.max(1),
            "--max-iters" => a.max_iters = count(&value)?.max(1),
            "--warmup" => a.warmup = count(&value)?.max(1),
            "--only" => {
                a.only = Some(match value.as_str() {
                    "nedrt" => Engine::Nedrt,
                    "burn" => Engine::Burn,
                    other => bail!("--only: '{other}' is not nedrt or burn"),
                })
            }
            other => bail!("unknown flag {other}\n{USAGE}"),
        }
    }
    ensure!(!a.sizes.is_empty(), "--sizes is empty");
    Ok(a)
}

/// Deterministic values in [0, 1) (xorshift64*), a frame's worth.
fn random_input(len: usize, seed: u64) -> Vec<f32> {
    let mut s = seed.max(1);
    (0..len)
        .map(|_| {
            s ^= s >> 12;
            s ^= s << 25;
            s ^= s >> 27;
            let r = s.wrapping_mul(0x2545_f491_4f6c_dd1d);
            (r >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect()
}

/// Median, p90 (nearest rank) and min of `v`, in the unit given; None
/// for no values.
fn stats(v: &[f64]) -> Option<(f64, f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let rank = |q: f64| s[((q * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1];
    let median = if s.len() % 2 == 1 {
        s[s.len() / 2]
    } else {
        (s[s.len() / 2 - 1] + s[s.len() / 2]) / 2.0
    };
    Some((median, rank(0.9), s[0]))
}

/// An engine under test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Engine {
    Nedrt,
    Burn,
}

impl Engine {
    fn name(self) -> &'static str {
        match self {
            Engine::Nedrt => "nedrt",
            Engine::Burn => "burn",
        }
    }
}

/// One engine's run times on one model and size, ms.
#[derive(Default)]
struct Timings {
    ms: Vec<f64>,
    /// nedrt's device (timestamp-query) times.
    dev: Vec<f64>,
}

impl Timings {
    fn push(&mut self, ms: f64, dev: Option<f64>) {
        self.ms.push(ms);
        self.dev.extend(dev);
    }
    fn reset(&mut self) {
        self.ms.clear();
        self.dev.clear();
    }
}

fn adapter_json(info: &wgpu::AdapterInfo) -> Value {
    json!({
        "name": info.name,
        "backend": format!("{:?}", info.backend),
        "device_type": format!("{:?}", info.device_type),
        "driver": info.driver,
        "driver_info": info.driver_info,
        "vendor": info.vendor,
        "device": info.device,
    })
}

fn describe(info: &wgpu::AdapterInfo) -> String {
    format!(
        "{} ({:?}, {:?}, driver {} {})",
        info.name, info.backend, info.device_type, info.driver, info.driver_info
    )
}

/// nedrt's commit, and whether its runtime differs from it (read-only git).
fn nedrt_commit() -> String {
    if let Ok(c) = std::env::var("NEDRT_COMMIT") {
        return c;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .args(args)
            .current_dir(&root)
            .env("GIT_OPTIONAL_LOCKS", "0")
            .output()
            .ok()
    };
    let Some(out) = git(&["rev-parse", "--short", "HEAD"]).filter(|o| o.status.success()) else {
        return "unknown".into();
    };
    let mut commit = String::from_utf8_lossy(&out.stdout).trim().to_string();
    if git(&["diff", "--quiet", "HEAD", "--", "runtime"]).is_some_and(|o| !o.status.success()) {
        commit.push_str(" (+ uncommitted changes in runtime/)");
    }
    commit
}

/// The machine's load average (Linux), for the report: other work on the
/// cores slows a CPU adapter such as lavapipe.
fn loadavg() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "n/a".into())
}

/// Multiply-adds of one `size`×`size` frame through `network` (its convolutions).
fn macs(network: &nedrt_infer::Network, size: usize) -> u64 {
    use nedrt_infer::network::Layer;
    let plane = |v: usize| {
        let side = (size >> network.values[v].level) as u64;
        side * side
    };
    network
        .layers
        .iter()
        .map(|l| match l {
            Layer::Conv(c) => (c.cin * c.cout * c.kernel * c.kernel) as u64 * plane(c.output),
            // Each input pixel feeds a 2×2 block of every output channel.
            Layer::ConvTranspose(c) => (c.cin * c.cout * 4) as u64 * plane(c.input),
            Layer::MaxPool { .. } | Layer::Concat { .. } => 0,
        })
        .sum()
}

/// One nedrt run: host tensor in, network, host tensor out.
fn run_nedrt(
    be: &mut GpuBackend,
    input: &[f32],
    size: usize,
) -> Result<(f64, Option<f64>, Vec<f32>)> {
    let t = Instant::now();
    let out = be.run_tensor(input, size, size)?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    Ok((ms, be.last_gpu_ns().map(|ns| ns as f64 / 1e6), out))
}

/// One burn run: `Tensor::from_data` → forward → `into_data` (which waits for
/// the device). The host `TensorData` is made before the clock starts, as
/// nedrt's input slice exists before its run.
fn run_burn(net: &BurnNet, device: &Device, input: &[f32], size: usize) -> Result<(f64, Vec<f32>)> {
    let data = TensorData::new(input.to_vec(), [1, 3, size, size]);
    let t = Instant::now();
    let x = Tensor::<4>::from_data(data, device);
    let y = net.forward(x);
    let dims = y.dims();
    let data = y.into_data();
    let dtype = data.dtype();
    let out = data
        .try_into_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("burn's output is {dtype:?}, not f32: {e:?}"))?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    ensure!(
        dims == [1, 3, size, size],
        "burn's output is {dims:?}, not [1, 3, {size}, {size}]"
    );
    Ok((ms, out))
}

/// How far apart the two outputs are. nedrt's last kernel clamps to [0, 1]
/// (the panel's range), the ONNX graph does not, so burn's output is clamped
/// on the host before the comparison (clamping never widens a difference).
struct Agreement {
    max_abs: f64,
    max_abs_out: f64,
    /// Share of burn's outputs outside [0, 1], where the clamp hides the value.
    clamped: f64,
    /// Largest |burn − input|: the size of the U-Net branch of `I + UNet(I)`,
    /// the scale against which the difference is relative.
    max_abs_branch: f64,
    non_finite: usize,
}

fn agreement(input: &[f32], nedrt: &[f32], burn: &[f32]) -> Result<Agreement> {
    ensure!(
        nedrt.len() == burn.len(),
        "nedrt gave {} values, burn {}",
        nedrt.len(),
        burn.len()
    );
    let mut a = Agreement {
        max_abs: 0.0,
        max_abs_out: 0.0,
        clamped: 0.0,
        max_abs_branch: 0.0,
        non_finite: 0,
    };
    let mut clamped = 0usize;
    for ((&n, &b), &x) in nedrt.iter().zip(burn).zip(input) {
        if !n.is_finite() || !b.is_finite() {
            a.non_finite += 1;
            continue;
        }
        clamped += usize::from(!(0.0..=1.0).contains(&b));
        a.max_abs = a.max_abs.max(f64::from((n - b.clamp(0.0, 1.0)).abs()));
        a.max_abs_out = a.max_abs_out.max(f64::from(b.abs()));
        a.max_abs_branch = a.max_abs_branch.max(f64::from((b - x).abs()));
    }
    a.clamped = clamped as f64 / burn.len().max(1) as f64;
    Ok(a)
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
             rebuild (cargo build --release) so both engines run the same model",
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
        Some(Engine::Burn) => None,
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
        Some(Engine::Nedrt) => None,
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
        "- timing: {} warm-up run(s) per engine (the first is cold: pipelines, burn's autotune), \
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
            let mut run = |engine: Engine,
                           n_t: &mut Timings,
                           b_t: &mut Timings|
             -> Result<Option<Vec<f32>>> {
                Ok(match engine {
                    Engine::Nedrt => match &mut nedrt {
                        Some(be) => {
                            let (ms, dev, out) = run_nedrt(be, &input, size)?;
                            n_t.push(ms, dev);
                            Some(out)
                        }
                        None => None,
                    },
                    Engine::Burn => match &burn {
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
                    run(Engine::Nedrt, &mut n_t, &mut b_t)?,
                    run(Engine::Burn, &mut n_t, &mut b_t)?,
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
                // ABBA: each engine goes first in half the pairs.
                let order = if iters % 2 == 0 {
                    [Engine::Nedrt, Engine::Burn]
                } else {
                    [Engine::Burn, Engine::Nedrt]
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
            "only": args.only.map(Engine::name),
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
