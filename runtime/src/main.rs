//! `nedrt`: the command line. Parses arguments and calls [`nedrt::app`];
//! errors are printed on one line with a non-zero exit.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand, ValueEnum};
use nedrt::app::{self, CommonOptions};
use nedrt::inference::{BackendKind, BackendOptions, OrtProvider, Precision};
use nedrt::sim::{Method, Optics};

#[derive(Parser, Debug)]
#[command(
    name = "nedrt",
    version,
    about = "Simulator and runtime of a computational multifocal near-eye display (lens + DOE + D-CNN)",
    after_help = "Examples:\n  nedrt --sim --accom 1.0            (or: nedrt sim --accom 1.0)\n  nedrt sim --accom 0.5 --method doe+wiener --out p.png\n  nedrt --design allsharp sim --accom 2.5\n  nedrt sim --accom 1.0 --method proposed --backend wgpu\n  nedrt bench inference --sizes 512x512\n  nedrt psf --out-dir out/psf\n  nedrt eval --images data/images/test"
)]
struct Cli {
    #[command(flatten)]
    global: GlobalArgs,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Args, Debug)]
struct GlobalArgs {
    /// Calibration TOML (default: the embedded calib/default.toml).
    #[arg(long, global = true, value_name = "FILE")]
    calib: Option<PathBuf>,
    /// DOE height-map file (default: the calibration's, else the three-lens initialisation).
    #[arg(long, global = true, value_name = "FILE")]
    doe: Option<PathBuf>,
    /// Display design: a DOE with the Wiener K tuned for it, by name
    /// (designs/NAME.toml: multifocal, allsharp) or as a design FILE.
    #[arg(long, global = true, value_name = "NAME|FILE", conflicts_with = "doe")]
    design: Option<String>,
    /// PSF cache folder (default: $NEDRT_CACHE_DIR, $XDG_CACHE_HOME/nedrt or ~/.cache/nedrt).
    #[arg(long, global = true, value_name = "DIR")]
    cache_dir: Option<PathBuf>,
    /// Compute every PSF afresh and store nothing.
    #[arg(long, global = true)]
    no_cache: bool,
    /// D-CNN of the `proposed` method (its DOE: the same name with
    /// `.doe.safetensors`, used unless --doe is given).
    #[arg(
        long,
        global = true,
        value_name = "FILE",
        default_value = "models/dcnn.onnx"
    )]
    dcnn: PathBuf,
    /// D-CNN of the `lens+dcnn` ablation, trained for the lens alone.
    #[arg(
        long,
        global = true,
        value_name = "FILE",
        default_value = "models/dcnn-lens.onnx"
    )]
    dcnn_lens: PathBuf,
    /// Engine that runs the D-CNN [default: cpu for the simulator, wgpu for `run`].
    #[arg(long, global = true, value_enum)]
    backend: Option<BackendKind>,
    /// Precision of the wgpu backend (f16 needs the adapter's shader-f16).
    #[arg(long, global = true, value_enum, default_value = "f32")]
    precision: Precision,
    /// Execution provider of the ort backend.
    #[arg(long, global = true, value_enum, default_value = "cpu")]
    ort_provider: OrtProvider,
    /// Threads of the ort backend (0: its default).
    #[arg(long, global = true, default_value_t = 0)]
    threads: usize,
    /// More log output (-v: debug, -vv: trace); NEDRT_LOG overrides.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
}

#[derive(Args, Debug)]
struct SimArgs {
    /// Accommodation of the eye in diopters (0 = infinity).
    #[arg(long, value_name = "D", allow_negative_numbers = true)]
    accom: Option<f64>,
    /// Input image (default: the shipped data/images/test/astronaut.png).
    #[arg(long, value_name = "IMG")]
    input: Option<PathBuf>,
    /// Display system: conventional, ai, doe-only, doe+wiener, proposed, lens+dcnn.
    #[arg(long, default_value = "conventional", value_parser = parse_method)]
    method: Method,
    /// Output PNG (16-bit) of the perceived image on the retinal grid.
    #[arg(long, default_value = "perceived.png", value_name = "FILE")]
    out: PathBuf,
    /// Simulate this display image (same size as the input) instead of a method.
    #[arg(long, value_name = "FILE")]
    display_image: Option<PathBuf>,
    /// Optics that --display-image is seen through.
    #[arg(long, value_enum, default_value = "doe")]
    optics: OpticsArg,
}

#[derive(ValueEnum, Clone, Copy, Debug)]
enum OpticsArg {
    Lens,
    Doe,
}

impl From<OpticsArg> for Optics {
    fn from(o: OpticsArg) -> Self {
        match o {
            OpticsArg::Lens => Optics::Lens,
            OpticsArg::Doe => Optics::Doe,
        }
    }
}

fn parse_size(s: &str) -> Result<(usize, usize), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| format!("{s:?}: expected WIDTHxHEIGHT, e.g. 1920x1080"))?;
    let parse = |v: &str| {
        v.parse::<usize>()
            .ok()
            .filter(|&n| (1..=16384).contains(&n))
            .ok_or_else(|| format!("{s:?}: sides must be integers in 1..=16384"))
    };
    Ok((parse(w)?, parse(h)?))
}

fn parse_method(s: &str) -> Result<Method, String> {
    s.parse()
}

#[derive(Subcommand, Debug)]
enum Command {
    /// The perceived image at one accommodation, scored against the sharp
    /// image and the target (`nedrt sim` or `nedrt --sim`).
    #[command(long_flag = "sim")]
    Sim(SimArgs),
    /// PSF cross-sections against accommodation (paper Fig. 4b): PNG, SVG, CSV.
    Psf(PlotArgs),
    /// MTFs (paper Fig. 5): at 0.5 D against CPD, and against depth at 1, 5, 10 CPD.
    Mtf(PlotArgs),
    /// The DOE height map (paper Fig. 4a); `--write-init FILE` saves the three-lens DOE.
    Doe(DoeArgs),
    /// The Fig. 6 table: every method × 0…3 D on a folder of images.
    Eval(EvalArgs),
    /// Search the Wiener constant K on training images (quarter decades).
    TuneWiener(TuneArgs),
    /// Print the resolved calibration and the quantities derived from it.
    Calib,
    /// The real-time service: frames from a source, preprocessed by the
    /// D-CNN, encoded through the panel's transfer curve, presented to a sink.
    Run(RunArgs),
    /// Time the PSF and the perceived image, writing their inputs for
    /// tools/bench/compare_numpy.py (see docs/benchmarks.md).
    Bench(BenchArgs),
    /// Speed against accuracy: every preprocessing configuration's latency
    /// and quality with the Pareto front, and the simulator's fidelity study.
    Tradeoff(TradeoffArgs),
    /// Name the fastest configuration of a tradeoff table that meets a
    /// quality floor and a latency budget (exit 1 when none does).
    Pick(PickArgs),
    /// Where each method breaks (Wiener K, the D-CNN off its training
    /// distribution, the optics beyond their sampling, f16): docs/stability.md.
    Stability(StabilityArgs),
}

#[derive(Args, Debug)]
struct StabilityArgs {
    #[arg(long, default_value = "data/images/test", value_name = "DIR")]
    images: PathBuf,
    /// The report (Markdown); the JSON is written beside it.
    #[arg(long, default_value = "docs/stability.md", value_name = "FILE")]
    out: PathBuf,
    /// Side of the synthetic content frames.
    #[arg(long, default_value_t = 128)]
    content_size: usize,
    /// Skip the f16-against-f32 comparison on the wgpu adapter.
    #[arg(long)]
    no_gpu: bool,
    /// Display designs compared beside the baselines (names in designs/ or
    /// files); default: every design in designs/.
    #[arg(long, value_delimiter = ',', value_name = "NAME|FILE")]
    designs: Option<Vec<String>>,
}

#[derive(Args, Debug)]
struct TradeoffArgs {
    /// Images the quality is measured on.
    #[arg(long, default_value = "data/images/test", value_name = "DIR")]
    images: PathBuf,
    #[arg(long, default_value = "docs/tradeoff", value_name = "DIR")]
    out_dir: PathBuf,
    /// Frame size of the latency measurements (default: the panel's).
    #[arg(long, value_parser = parse_size)]
    size: Option<(usize, usize)>,
    /// Trained D-CNNs (each with its .doe.safetensors beside it).
    #[arg(long, value_delimiter = ',', default_values = ["models/dcnn.onnx"])]
    models: Vec<PathBuf>,
    #[arg(long, value_delimiter = ',', value_enum, default_values = ["cpu", "ort", "wgpu"])]
    backends: Vec<BackendKind>,
    /// Timed runs per latency (median reported).
    #[arg(long, default_value_t = 3)]
    repeat: usize,
    /// Estimate, rather than measure, a latency that would take longer than this (seconds).
    #[arg(long, default_value_t = 60.0)]
    max_seconds: f64,
    /// Skip the simulator-fidelity study (minutes of PSFs at the 3 µm pitch).
    #[arg(long)]
    no_fidelity: bool,
    /// Measure nothing: rewrite the tables and charts from the JSON in --out-dir.
    #[arg(long)]
    replot: bool,
    /// Display designs compared beside the baselines (names in designs/ or
    /// files); default: every design in designs/.
    #[arg(long, value_delimiter = ',', value_name = "NAME|FILE")]
    designs: Option<Vec<String>>,
}

#[derive(Args, Debug)]
struct PickArgs {
    /// Table written by `nedrt tradeoff`.
    #[arg(
        long,
        default_value = "docs/tradeoff/tradeoff.json",
        value_name = "FILE"
    )]
    table: PathBuf,
    /// Quality floor: mean PSNR over 0–2.5 D against the sharp image, dB.
    #[arg(long, value_name = "DB")]
    min_psnr: f64,
    /// Optional floor on the worst depth's PSNR, dB.
    #[arg(long, value_name = "DB")]
    min_worst_psnr: Option<f64>,
    /// Latency budget per frame, milliseconds.
    #[arg(long, value_name = "MS")]
    budget_ms: f64,
}

#[derive(Args, Debug)]
struct RunArgs {
    /// Where frames come from.
    #[arg(long, value_enum, default_value = "pattern")]
    source: app::run::SourceKind,
    /// --source dir: a folder of images (name order) or one image, at the panel's resolution.
    #[arg(long, value_name = "PATH")]
    input: Option<PathBuf>,
    /// --source socket: the Unix socket to listen on.
    #[arg(long, value_name = "PATH", default_value = "/tmp/nedrt.sock")]
    socket: PathBuf,
    /// --source socket: folder of the clients' shared-memory objects.
    #[arg(long, value_name = "DIR", default_value = nedrt::pipeline::protocol::DEFAULT_SHM_DIR)]
    shm_dir: PathBuf,
    /// Frames the pattern or folder source submits (default: pattern until
    /// stopped, a folder once through).
    #[arg(long, value_name = "N")]
    frames: Option<u64>,
    /// Submission rate of the pattern and folder sources in Hz (default:
    /// the panel's refresh; 0: as fast as the pipeline takes them).
    #[arg(long, value_name = "HZ")]
    source_rate: Option<f64>,
    /// Where frames go.
    #[arg(long, value_enum, default_value = "window")]
    sink: app::run::SinkKind,
    /// --sink record: the folder of the PNG sequence.
    #[arg(long, value_name = "DIR", default_value = "out/recording")]
    record_dir: PathBuf,
    /// Borderless fullscreen (on --monitor, else the primary monitor).
    #[arg(long)]
    fullscreen: bool,
    /// Monitor name for --fullscreen.
    #[arg(long, value_name = "NAME")]
    monitor: Option<String>,
    /// Present without waiting for vsync where the surface allows.
    #[arg(long)]
    no_vsync: bool,
    /// What runs when the D-CNN backend cannot start or fails.
    #[arg(long, value_enum, default_value = "cpu")]
    fallback: app::run::FallbackKind,
    /// Keep showing the last frame after the source ends, until Ctrl-C or the window closes.
    #[arg(long)]
    keep_open: bool,
    /// Write a Chrome/Perfetto trace of every stage span to FILE.
    #[arg(long, value_name = "FILE")]
    trace: Option<PathBuf>,
    /// Write the counts and latency histograms as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    report_json: Option<PathBuf>,
}

#[derive(Args, Debug)]
struct PlotArgs {
    /// Output folder.
    #[arg(long, default_value = "out", value_name = "DIR")]
    out_dir: PathBuf,
    /// Accommodation step of the sweep (D).
    #[arg(long, default_value_t = 0.1, value_name = "D")]
    step: f64,
}

#[derive(Args, Debug)]
struct DoeArgs {
    #[arg(long, default_value = "out", value_name = "DIR")]
    out_dir: PathBuf,
    /// Write the three-lens initial DOE (design pitch) to this file and exit.
    #[arg(long, value_name = "FILE")]
    write_init: Option<PathBuf>,
    /// Also write the DOE resampled (bicubic) to the fabrication pitch to this file.
    #[arg(long, value_name = "FILE")]
    write_fabrication: Option<PathBuf>,
}

#[derive(Args, Debug)]
struct EvalArgs {
    /// Folder of test images (PNG, JPEG, TIFF).
    #[arg(long, value_name = "DIR")]
    images: PathBuf,
    #[arg(long, default_value = "out/eval", value_name = "DIR")]
    out_dir: PathBuf,
    /// Methods to evaluate (default: all available).
    #[arg(long, value_delimiter = ',', value_parser = parse_method)]
    methods: Vec<Method>,
    /// Also evaluate display images made elsewhere (e.g. the trainer's
    /// D-CNN outputs): DIR/NAME for every input image NAME, same size.
    #[arg(long, value_name = "DIR")]
    display_dir: Option<PathBuf>,
    /// Row name for --display-dir.
    #[arg(long, default_value = "external", value_name = "NAME")]
    display_name: String,
    /// Optics the --display-dir images are seen through.
    #[arg(long, value_enum, default_value = "doe")]
    display_optics: OpticsArg,
    /// Also measure focus cues: each method's perceived sharpness at 5 and
    /// 10 CPD over 0–3 D in 0.1 D steps, its focus-cue score at the main
    /// depths and a chart (focus_cues.png/.svg); renders 31 depths instead of 7.
    #[arg(long)]
    focus_cues: bool,
    /// Display designs to add, one `doe+wiener NAME` row each with its own
    /// DOE and K (names in designs/ or design files).
    #[arg(long, value_delimiter = ',', value_name = "NAME|FILE")]
    designs: Vec<String>,
}

#[derive(Args, Debug)]
struct TuneArgs {
    /// Training images.
    #[arg(long, default_value = "data/images/train", value_name = "DIR")]
    images: PathBuf,
    /// ai or doe+wiener.
    #[arg(long, value_parser = parse_method)]
    method: Method,
    /// Write the chosen K into the calibration file (comments kept).
    #[arg(long)]
    write: bool,
}

#[derive(Args, Debug)]
struct BenchArgs {
    /// psf, perceived, ceilings, inference (D-CNN latency per backend), or
    /// radial (the radial PSF path against the 2-D path, docs/benchmarks.md).
    #[arg(value_parser = ["psf", "perceived", "ceilings", "inference", "radial"])]
    what: String,
    /// inference: backends to time.
    #[arg(long, value_delimiter = ',', value_enum, default_values = ["cpu", "ort", "wgpu"])]
    backends: Vec<BackendKind>,
    /// inference: frame sizes, WIDTHxHEIGHT.
    #[arg(long, value_delimiter = ',', default_values = ["512x512", "1920x1080"], value_parser = parse_size)]
    sizes: Vec<(usize, usize)>,
    /// inference: skip a case estimated to take longer than this (seconds).
    #[arg(long, default_value_t = 120.0)]
    max_seconds: f64,
    /// Folder for the exact inputs, for the numpy side.
    #[arg(long, default_value = "out/bench", value_name = "DIR")]
    dump: PathBuf,
    /// Timed repetitions (median reported).
    #[arg(long, default_value_t = 3)]
    repeat: usize,
}

/// Logging to stderr, and with `trace` a Chrome/Perfetto trace of every
/// span; the returned guard writes the trace when dropped.
fn init_logging(
    verbose: u8,
    trace: Option<&std::path::Path>,
) -> Result<Option<tracing_chrome::FlushGuard>> {
    use tracing_subscriber::prelude::*;
    let default = match verbose {
        0 => "nedrt=info",
        1 => "nedrt=debug",
        _ => "nedrt=trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_env("NEDRT_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let fmt = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_target(false)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .without_time();
    let (chrome, guard) = match trace {
        Some(path) => {
            let file = std::fs::File::create(path)
                .with_context(|| format!("{}: cannot create the trace file", path.display()))?;
            let (layer, guard) = tracing_chrome::ChromeLayerBuilder::new()
                .writer(file)
                .include_args(true)
                .build();
            (Some(layer), Some(guard))
        }
        None => (None, None),
    };
    tracing_subscriber::registry()
        .with(filter)
        .with(fmt)
        .with(chrome)
        .init();
    Ok(guard)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let trace = match &cli.command {
        Some(Command::Run(a)) => a.trace.clone(),
        _ => None,
    };
    let guard = match init_logging(cli.global.verbose, trace.as_deref()) {
        Ok(g) => g,
        Err(e) => {
            eprintln!("error: {e:#}");
            return ExitCode::FAILURE;
        }
    };
    let result = run(cli);
    drop(guard);
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", format!("{e:#}").replace('\n', " "));
            ExitCode::FAILURE
        }
    }
}

/// Ctrl-C and SIGTERM stop the service cleanly (a second one exits at
/// once); SIGUSR1 prints the latency table.
fn install_signals(control: &nedrt::pipeline::service::Control) -> Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM, SIGUSR1};
    for sig in [SIGINT, SIGTERM] {
        signal_hook::flag::register_conditional_shutdown(sig, 1, control.stop.clone())?;
        signal_hook::flag::register(sig, control.stop.clone())?;
    }
    signal_hook::flag::register(SIGUSR1, control.report.clone())?;
    Ok(())
}

fn run(cli: Cli) -> Result<()> {
    let g = &cli.global;
    let design = g
        .design
        .as_deref()
        .map(app::design::Design::resolve)
        .transpose()?;
    let common = CommonOptions {
        calib: g.calib.clone(),
        cache_dir: g.cache_dir.clone(),
        no_cache: g.no_cache,
        doe: design
            .as_ref()
            .map(|d| d.doe.clone())
            .or_else(|| g.doe.clone()),
        design,
        dcnn: app::DcnnOptions {
            path: g.dcnn.clone(),
            lens_path: g.dcnn_lens.clone(),
            backend: g.backend.unwrap_or(BackendKind::Cpu),
            backend_options: BackendOptions {
                threads: g.threads,
                precision: g.precision,
                ort_provider: g.ort_provider,
            },
        },
    };
    match cli.command {
        Some(Command::Psf(a)) => print!("{}", app::plots::psf(&common, &a.out_dir, a.step)?),
        Some(Command::Mtf(a)) => print!("{}", app::plots::mtf(&common, &a.out_dir, a.step)?),
        Some(Command::Doe(a)) => print!(
            "{}",
            app::plots::doe(
                &common,
                &a.out_dir,
                a.write_init.as_deref(),
                a.write_fabrication.as_deref()
            )?
        ),
        Some(Command::Eval(a)) => {
            let external = a.display_dir.map(|dir| app::eval::ExternalDisplays {
                name: a.display_name,
                dir,
                optics: a.display_optics.into(),
            });
            print!(
                "{}",
                app::eval::run(
                    &common,
                    &a.images,
                    &a.out_dir,
                    &a.methods,
                    &app::eval::EvalExtras {
                        external,
                        designs: a
                            .designs
                            .iter()
                            .map(|n| app::design::Design::resolve(n))
                            .collect::<Result<_, _>>()?,
                        focus_cues: a.focus_cues,
                    }
                )?
            )
        }
        Some(Command::TuneWiener(a)) => {
            print!("{}", app::tune::run(&common, &a.images, a.method, a.write)?)
        }
        Some(Command::Run(a)) => {
            let mut common = common;
            common.dcnn.backend = g.backend.unwrap_or(BackendKind::Wgpu);
            let control = nedrt::pipeline::service::Control {
                keep_open: a.keep_open,
                progress: std::io::IsTerminal::is_terminal(&std::io::stderr()),
                ..Default::default()
            };
            install_signals(&control)?;
            let opts = app::run::RunOptions {
                source: a.source,
                input: a.input,
                socket: a.socket,
                shm_dir: a.shm_dir,
                frames: a.frames,
                source_rate_hz: a.source_rate,
                sink: a.sink,
                record_dir: a.record_dir,
                window: nedrt::present::window::WindowOptions {
                    title: "nedrt".into(),
                    fullscreen: a.fullscreen,
                    monitor: a.monitor,
                    vsync: !a.no_vsync,
                },
                fallback: a.fallback,
                report_json: a.report_json,
            };
            let report = app::run::run(&common, &opts, &control)?;
            print!("{}", report.table());
        }
        Some(Command::Calib) => print!("{}", app::plots::calib_summary(&common)?),
        Some(Command::Bench(a)) => match a.what.as_str() {
            "psf" => println!("{}", app::bench::psf(&common, &a.dump, a.repeat)?),
            "perceived" => print!("{}", app::bench::perceived(&common, &a.dump, a.repeat)?),
            "radial" => print!("{}", app::bench::radial(&common, &a.dump)?),
            "inference" => {
                let bench = app::bench_inference::InferenceBench {
                    backends: a.backends,
                    sizes: a.sizes,
                    models: vec![("full".into(), 32), ("half".into(), 16)],
                    repeat: a.repeat,
                    max_seconds: a.max_seconds,
                    threads: g.threads,
                };
                let table = app::bench_inference::run(&bench, &mut |r| println!("{r}"))?;
                print!("{table}");
            }
            _ => {
                let (gflops, gbps) = app::bench::ceilings();
                println!(
                    "{{\"kind\": \"ceilings\", \"f64_gemm_gflops\": {gflops:.2}, \"copy_gbps\": {gbps:.2}}}"
                );
            }
        },
        Some(Command::Tradeoff(a)) if a.replot => {
            print!("{}", app::tradeoff::replot(&a.out_dir)?);
        }
        Some(Command::Tradeoff(a)) => {
            let calib = common.calibration()?;
            let opts = app::tradeoff::TradeoffOptions {
                images_dir: a.images,
                out_dir: a.out_dir,
                size: a
                    .size
                    .unwrap_or((calib.panel.width_px, calib.panel.height_px)),
                models: a.models,
                backends: a.backends,
                repeat: a.repeat,
                max_seconds: a.max_seconds,
                threads: g.threads,
                fidelity: !a.no_fidelity,
                designs: app::design::Design::resolve_list(a.designs.as_deref())?,
            };
            print!("{}", app::tradeoff::run(&common, &opts)?);
        }
        Some(Command::Pick(a)) => {
            for (name, v) in [("--min-psnr", a.min_psnr), ("--budget-ms", a.budget_ms)]
                .into_iter()
                .chain(a.min_worst_psnr.map(|w| ("--min-worst-psnr", w)))
            {
                if !v.is_finite() {
                    bail!("{name} {v}: not a number");
                }
            }
            let table = app::tradeoff::Table::load(&a.table)?;
            let req = app::tradeoff::pareto::Requirement {
                min_mean_psnr_db: a.min_psnr,
                min_worst_psnr_db: a.min_worst_psnr,
                max_latency_ms: a.budget_ms,
            };
            let points = table.points();
            let pick = app::tradeoff::pareto::pick(&points, &req);
            if !matches!(pick, app::tradeoff::pareto::Pick::Chosen(_)) {
                bail!(
                    "{pick} ({}, {}×{} frames on {})",
                    a.table.display(),
                    table.frame_width,
                    table.frame_height,
                    table.host
                );
            }
            println!("{pick}");
        }
        Some(Command::Stability(a)) => {
            if a.content_size < 8 {
                bail!("--content-size {}: at least 8 pixels", a.content_size);
            }
            let opts = app::stability::StabilityOptions {
                images_dir: a.images,
                out: a.out,
                model: g.dcnn.clone(),
                content_size: a.content_size,
                gpu: !a.no_gpu,
                designs: app::design::Design::resolve_list(a.designs.as_deref())?,
            };
            print!("{}", app::stability::run(&common, &opts)?);
        }
        Some(Command::Sim(s)) => {
            let accommodation_d = s
                .accom
                .context("--sim needs --accom D (the eye's accommodation in diopters)")?;
            let opts = app::sim::SimOptions {
                accommodation_d,
                input: s.input,
                method: s.method,
                out: s.out,
                display_image: s.display_image,
                optics: s.optics.into(),
            };
            println!("{}", app::sim::run(&common, &opts)?);
        }
        None => {
            bail!("nothing to do: give a command, e.g. `nedrt sim --accom 1.0` (see nedrt --help)")
        }
    }
    Ok(())
}
