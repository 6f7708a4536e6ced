//! The command line: clap definitions only. Choices come from the
//! libraries' own name lists ([`Named`]), so every flag's values and help
//! are the ones the libraries define.

use std::path::PathBuf;

use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use clap::{Args, Parser, Subcommand};
use nedrt_core::Named;
use nedrt_infer::{BackendKind, ConvPath, F16Math, OrtProvider, Precision};
use nedrt_optics::sim::{Method, Optics};
use nedrt_run::{FallbackKind, FramePath, SinkKind, SourceKind};

pub use crate::bench_args::{BenchArgs, BenchKind};
pub use crate::calib_args::{CalibAction, CalibArgs};
pub use crate::study_args::{EvalArgs, PickArgs, StabilityArgs, TradeoffArgs, TuneArgs};
pub use crate::view_args::{ShownArg, SweepArgs, ViewArgs};

/// A parser for any [`Named`] type, listing its values in `--help`.
pub fn named<T: Named + Clone>() -> impl TypedValueParser<Value = T> {
    PossibleValuesParser::new(
        T::ALL
            .iter()
            .map(|v| PossibleValue::new(v.name()).help(v.help())),
    )
    .map(|s| T::from_name(&s).unwrap_or(T::ALL[0]))
}

#[derive(Parser, Debug)]
#[command(
    name = "nedrt",
    version,
    about = "Simulator and runtime of a computational multifocal near-eye display (lens + DOE + D-CNN)",
    after_help = "Examples:\n  nedrt --sim --accom 1.0            (or: nedrt sim --accom 1.0)\n  nedrt sim --accom 0.5 --method doe+wiener --out p.png\n  nedrt --design allsharp sim --accom 2.5\n  nedrt sim --accom 1.0 --method proposed --backend wgpu\n  nedrt bench inference --sizes 512x512\n  nedrt psf --out-dir out/psf\n  nedrt eval --images data/images/test"
)]
pub struct Cli {
    #[command(flatten)]
    pub global: GlobalArgs,
    #[command(subcommand)]
    pub command: Option<Command>,
}

#[derive(Args, Debug)]
pub struct GlobalArgs {
    /// Calibration TOML (default: the embedded calib/default.toml).
    #[arg(long, global = true, value_name = "FILE")]
    pub calib: Option<PathBuf>,
    /// DOE height-map file (default: the calibration's, else the three-lens initialisation).
    #[arg(long, global = true, value_name = "FILE")]
    pub doe: Option<PathBuf>,
    /// Display design: a DOE with the Wiener K tuned for it, by name
    /// (designs/NAME.toml: multifocal, allsharp) or as a design FILE.
    #[arg(long, global = true, value_name = "NAME|FILE", conflicts_with = "doe")]
    pub design: Option<String>,
    /// A measured PSF bundle (`nedrt calib psfs`): its PSFs, interpolated
    /// in diopters, stand for the lens + DOE optics' computed ones in
    /// every method through the DOE (docs/calibration.md).
    #[arg(long, global = true, value_name = "DIR")]
    pub psfs: Option<PathBuf>,
    /// PSF cache folder (default: $NEDRT_CACHE_DIR, $XDG_CACHE_HOME/nedrt or ~/.cache/nedrt).
    #[arg(long, global = true, value_name = "DIR")]
    pub cache_dir: Option<PathBuf>,
    /// Compute every PSF afresh and store nothing.
    #[arg(long, global = true)]
    pub no_cache: bool,
    /// D-CNN of the `proposed` method (its DOE: the same name with
    /// `.doe.safetensors`, used unless --doe is given).
    #[arg(
        long,
        global = true,
        value_name = "FILE",
        default_value = "models/dcnn.onnx"
    )]
    pub dcnn: PathBuf,
    /// D-CNN of the `lens+dcnn` ablation, trained for the lens alone.
    #[arg(
        long,
        global = true,
        value_name = "FILE",
        default_value = "models/dcnn-lens.onnx"
    )]
    pub dcnn_lens: PathBuf,
    /// Engine that runs the D-CNN [default: cpu for the simulator, wgpu for `run`].
    #[arg(long, global = true, value_parser = named::<BackendKind>())]
    pub backend: Option<BackendKind>,
    /// Precision of the wgpu backend (f16 needs the adapter's shader-f16).
    #[arg(long, global = true, value_parser = named::<Precision>(), default_value = "f32")]
    pub precision: Precision,
    /// Convolution kernels of the wgpu backend: auto (the tensor cores'
    /// cooperative matrices where the adapter lists their shape, at f16) or
    /// tiled (the register-tiled kernels only).
    #[arg(long, global = true, value_parser = named::<ConvPath>(), default_value = "auto")]
    pub conv_path: ConvPath,
    /// How the tiled kernels sum at --precision f16: auto (f16 on a GPU,
    /// f32 on a CPU adapter), f16 or f32 (on f16 storage).
    #[arg(long, global = true, value_parser = named::<F16Math>(), default_value = "auto")]
    pub f16_math: F16Math,
    /// Folder of the wgpu backend's tuned conv tiles, one table per adapter
    /// and driver (`nedrt bench tune` writes them; docs/tuning.md). An
    /// adapter without a table, or a missing folder, takes the heuristics'.
    #[arg(long, global = true, value_name = "DIR", default_value = "tuning")]
    pub tuning: PathBuf,
    /// Execution provider of the ort backend.
    #[arg(long, global = true, value_parser = named::<OrtProvider>(), default_value = "cpu")]
    pub ort_provider: OrtProvider,
    /// Threads of the ort backend (0: its default).
    #[arg(long, global = true, default_value_t = 0)]
    pub threads: usize,
    #[command(flatten)]
    pub eye: crate::eye_args::EyeArgs,
    /// More log output (-v: debug, -vv: trace); NEDRT_LOG overrides.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    pub verbose: u8,
}

#[derive(Args, Debug)]
pub struct SimArgs {
    /// Accommodation of the eye in diopters (0 = infinity).
    #[arg(long, value_name = "D", allow_negative_numbers = true)]
    pub accom: Option<f64>,
    /// Input image (default: the shipped data/images/test/astronaut.png).
    #[arg(long, value_name = "IMG")]
    pub input: Option<PathBuf>,
    /// Display system: conventional, ai, doe-only, doe+wiener, proposed,
    /// lens+dcnn (default: the shipped system, proposed, or doe+wiener
    /// where no D-CNN is here, followed by a table of every method).
    #[arg(long, value_parser = named::<Method>())]
    pub method: Option<Method>,
    /// The perceived image on the retinal grid: .png (16-bit) or .tif
    /// (32-bit float, exact).
    #[arg(long, default_value = "perceived.png", value_name = "FILE")]
    pub out: PathBuf,
    /// Also write the display frame the panel shows (after the method's
    /// preprocessing): .png (16-bit) or .tif (32-bit float, exact).
    #[arg(long, value_name = "FILE")]
    pub display_out: Option<PathBuf>,
    /// Simulate this display image (same size as the input) instead of a method.
    #[arg(long, value_name = "FILE")]
    pub display_image: Option<PathBuf>,
    /// Optics that --display-image is seen through.
    #[arg(long, value_parser = named::<Optics>(), default_value = "doe")]
    pub optics: Optics,
    /// How the display image is made from the frame, given the method's
    /// optics: native (the method's own: none, Wiener or D-CNN), lsq (the
    /// linear least-squares prefilter), refine:K (lsq and K projected-gradient
    /// steps), admm:K (lsq and K split-solver steps) or optimal (the bounded
    /// least-squares optimum); all but native
    /// against the target (default) or, with @sharp, the sharp image over
    /// 0–2.5 D (docs/optimal.md).
    #[arg(long, default_value = "native", value_name = "PREFILTER")]
    pub prefilter: nedrt_stages::preprocess::Prefilter,
    /// Instead of --method and --prefilter: a level of `nedrt run`'s frame
    /// budget by the name its report gives (none, wiener, admm:K, refine:K, or the
    /// network's file stem, dcnn), on the optics that level runs on (the
    /// shipped system's DOE).
    #[arg(long, value_name = "LEVEL", conflicts_with_all = ["method", "prefilter", "display_image"])]
    pub level: Option<String>,
    #[command(flatten)]
    pub zones: crate::eye_args::ZoneArgs,
}

pub(crate) fn parse_size(s: &str) -> Result<(usize, usize), String> {
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

#[derive(Subcommand, Debug)]
pub enum Command {
    /// The perceived image at one accommodation, scored against the sharp
    /// image and the target (`nedrt sim` or `nedrt --sim`).
    #[command(long_flag = "sim")]
    Sim(SimArgs),
    /// PSF cross-sections against accommodation (paper Fig. 4b): PNG, SVG,
    /// CSV; with --at D, a method's full PSFs at D (safetensors).
    Psf(PsfArgs),
    /// MTFs (paper Fig. 5): at 0.5 D against CPD, and against depth at 1, 5, 10 CPD.
    Mtf(PlotArgs),
    /// The DOE height map (paper Fig. 4a); `--write-init FILE` saves the three-lens DOE.
    Doe(DoeArgs),
    /// The Fig. 6 table: every method × 0…3 D on a folder of images.
    Eval(EvalArgs),
    /// A window showing each method's perceived image side by side as the
    /// eye's accommodation moves (wheel, arrow keys, slider).
    View(ViewArgs),
    /// The side-by-side view over a sweep of accommodations, as an animated
    /// PNG or GIF with the labels burnt in.
    Sweep(SweepArgs),
    /// Search the Wiener constant K on training images (quarter decades).
    TuneWiener(TuneArgs),
    /// The display images of one method and prefilter for a folder of
    /// images (32-bit float TIFF), and the objective's kernels for the
    /// trainer: the D-CNN recipe's teacher (docs/optimal.md).
    Prefilter(PrefilterArgs),
    /// Print the resolved calibration and the quantities derived from it;
    /// `calib patterns` writes what to show the built display to calibrate
    /// it (docs/calibration.md).
    Calib(CalibArgs),
    /// The real-time service: frames from a source, preprocessed at the best
    /// level that fits the refresh (or by one method), encoded through the
    /// panel's transfer curve, presented to a sink.
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
    /// The tolerances that matter: each fabrication and assembly error alone
    /// (etch depth, levels, decentre, eye relief, panel distance,
    /// primaries) and a realistic combination, for every method without a
    /// network; nominal, as built without calibration and as built
    /// calibrated, and the error at which each loses 0.5 dB
    /// (docs/tolerance.md).
    Tolerance(crate::calib_args::ToleranceArgs),
}

/// `nedrt run --preprocess`: a method, or the frame budget's ladder.
#[derive(Debug, Clone)]
pub enum RunPreprocess {
    Method(Method),
    Auto(nedrt_run::LadderSpec),
}

fn parse_run_preprocess(s: &str) -> Result<RunPreprocess, String> {
    if let Some(spec) = nedrt_run::LadderSpec::parse(s) {
        return spec.map(RunPreprocess::Auto);
    }
    Method::from_name(s)
        .map(RunPreprocess::Method)
        .map_err(|_| {
            let names: Vec<&str> = Method::ALL.iter().map(|m| m.name()).collect();
            format!(
                "{s:?} is neither a method ({}) nor auto[:LO..HI]",
                names.join(", ")
            )
        })
}

#[derive(Args, Debug)]
pub struct RunArgs {
    /// The preprocessing on the panel: a display system's (its D-CNN, its
    /// Wiener prefilter, or none; `ai` and `doe+wiener` put the Wiener
    /// prefilter on the panel), or `auto[:LO..HI]`: the frame budget picks
    /// each frame's level from none < wiener < admm:1 < admm:3 <
    /// admm:10 < the network (dcnn), LO to HI, so that every refresh is
    /// on time (docs/service.md, "The frame budget"). Methods: conventional,
    /// ai, doe-only, doe+wiener, proposed, lens+dcnn. [default: auto; with
    /// --prefilter, proposed: that prefilter on the shipped system's optics]
    #[arg(long, value_parser = parse_run_preprocess, value_name = "METHOD|auto[:LO..HI]")]
    pub preprocess: Option<RunPreprocess>,
    /// `--preprocess auto`: the tradeoff table (`nedrt tradeoff`'s JSON)
    /// the levels' quality comes from [default: docs/tradeoff/tradeoff.json
    /// where it exists; without one the levels keep their order].
    #[arg(long, value_name = "FILE")]
    pub ladder_quality: Option<PathBuf>,
    /// `--preprocess auto`: one more network level of the ladder, repeated
    /// for more (a D-CNN's ONNX or an unrolled model's manifest, as --dcnn
    /// takes them; e.g. models/unrolled/unrolled-k1.unrolled.toml): named by
    /// its file's stem, cheapest first, between admm:10 and --dcnn's.
    #[arg(long, value_name = "FILE")]
    pub ladder_network: Vec<PathBuf>,
    /// Instead, a least-squares prefilter on --preprocess's optics: lsq,
    /// refine:K, admm:K or optimal (@sharp or @target; see `nedrt sim --help`).
    #[arg(long, default_value = "native", value_name = "PREFILTER")]
    pub prefilter: nedrt_stages::preprocess::Prefilter,
    /// Where frames come from.
    #[arg(long, value_parser = named::<SourceKind>(), default_value = "pattern")]
    pub source: SourceKind,
    /// --source dir: a folder of images (name order) or one image, at the panel's resolution.
    #[arg(long, value_name = "PATH")]
    pub input: Option<PathBuf>,
    /// --source socket: the Unix socket to listen on.
    #[arg(long, value_name = "PATH", default_value = "/tmp/nedrt.sock")]
    pub socket: PathBuf,
    /// --source socket: folder of the clients' shared-memory objects.
    #[arg(long, value_name = "DIR", default_value = nedrt_protocol::DEFAULT_SHM_DIR)]
    pub shm_dir: PathBuf,
    /// Frames the pattern or folder source submits (default: pattern until
    /// stopped, a folder once through).
    #[arg(long, value_name = "N")]
    pub frames: Option<u64>,
    /// Submission rate of the pattern and folder sources in Hz, on a timer
    /// of their own (default: each frame made just in time for the panel
    /// refresh it will be shown at; 0: as fast as the pipeline takes them).
    #[arg(long, value_name = "HZ")]
    pub source_rate: Option<f64>,
    /// Where frames go.
    #[arg(long, value_parser = named::<SinkKind>(), default_value = "window")]
    pub sink: SinkKind,
    /// --sink record: the folder of the PNG sequence.
    #[arg(long, value_name = "DIR", default_value = "out/recording")]
    pub record_dir: PathBuf,
    /// Borderless fullscreen (on --monitor, else the primary monitor).
    #[arg(long)]
    pub fullscreen: bool,
    /// Monitor name for --fullscreen.
    #[arg(long, value_name = "NAME")]
    pub monitor: Option<String>,
    /// Present without waiting for vsync where the surface allows.
    #[arg(long)]
    pub no_vsync: bool,
    /// What runs when the D-CNN backend cannot start or fails.
    #[arg(long, value_parser = named::<FallbackKind>(), default_value = "cpu")]
    pub fallback: FallbackKind,
    /// Where frames go between the client and the panel: `device` keeps
    /// them on the sink's GPU where the sink and the engine allow (window
    /// or headless sink, wgpu backend or no network), else the host.
    #[arg(long, value_parser = named::<FramePath>(), default_value = "device")]
    pub frame_path: FramePath,
    /// Keep showing the last frame after the source ends, until Ctrl-C or the window closes.
    #[arg(long)]
    pub keep_open: bool,
    /// Print what the run would build (views, each view's stages, the frame
    /// path, where the network runs, the pacing) and why, then exit:
    /// nothing is started, opened or bound.
    #[arg(long)]
    pub plan: bool,
    /// Write a Chrome/Perfetto trace of every stage span to FILE.
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
    /// Write the counts and latency histograms as JSON to FILE.
    #[arg(long, value_name = "FILE")]
    pub report_json: Option<PathBuf>,
    /// Fault injection for the fault tests (docs/reliability.md): the D-CNN
    /// backend fails as a lost GPU does after N frames.
    #[arg(long, value_name = "N", hide = true)]
    pub inject_device_loss_after: Option<u64>,
    /// Two views, a headset's eyes: the calibration's [[view]] tables (each
    /// eye its region and design; with tables every run has them), else the
    /// panel's left and right halves with this run's system. On the sink's
    /// GPU where it has one (both eyes in one submission), else the host.
    #[arg(long)]
    pub stereo: bool,
}

#[derive(Args, Debug)]
pub struct PlotArgs {
    /// Output folder.
    #[arg(long, default_value = "out", value_name = "DIR")]
    pub out_dir: PathBuf,
    /// Accommodation step of the sweep (D).
    #[arg(long, default_value_t = 0.1, value_name = "D")]
    pub step: f64,
}

#[derive(Args, Debug)]
pub struct PsfArgs {
    #[command(flatten)]
    pub plot: PlotArgs,
    /// Instead of the sweep: the full PSFs of --method's optics with the
    /// eye accommodated at D diopters, into OUT_DIR/psfs.safetensors
    /// (channel × N × N, each cell's share of the light; `veil` beside).
    #[arg(long, value_name = "D")]
    pub at: Option<f64>,
    /// The method whose optics --at takes.
    #[arg(long, default_value = "doe+wiener", value_name = "METHOD", value_parser = named::<Method>(), requires = "at")]
    pub method: Method,
}

#[derive(Args, Debug)]
pub struct DoeArgs {
    #[arg(long, default_value = "out", value_name = "DIR")]
    pub out_dir: PathBuf,
    /// Write the three-lens initial DOE (design pitch) to this file and exit.
    #[arg(long, value_name = "FILE")]
    pub write_init: Option<PathBuf>,
    /// Also write the DOE resampled (bicubic) to the fabrication pitch to this file.
    #[arg(long, value_name = "FILE")]
    pub write_fabrication: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct PrefilterArgs {
    /// Folder of images (PNG, JPEG, TIFF).
    #[arg(long, value_name = "DIR")]
    pub images: PathBuf,
    /// Where DIR/NAME.tif, prefilter.json and the kernels go.
    #[arg(long, value_name = "DIR")]
    pub out_dir: PathBuf,
    /// Display system whose optics (and K) the prefilter uses.
    #[arg(long, default_value = "doe+wiener", value_parser = named::<Method>())]
    pub method: Method,
    /// lsq, refine:K, admm:K or optimal, @sharp or @target (see `nedrt sim --help`).
    #[arg(long, default_value = "optimal", value_name = "PREFILTER")]
    pub prefilter: nedrt_stages::preprocess::Prefilter,
    /// Also write the objective as kernels for WxH patches
    /// (operator-WxH.safetensors; repeat or comma-separate for more sizes).
    #[arg(long, value_delimiter = ',', value_parser = parse_size, value_name = "WxH")]
    pub operator: Vec<(usize, usize)>,
    /// Write the display images before the panel's clamp (the native
    /// Wiener prefilter only): the input of a D-CNN that corrects the
    /// Wiener's clamp (docs/training.md).
    #[arg(long)]
    pub unclamped: bool,
    /// With --psfs: average each measured PSF with its mirror images
    /// first, for every output of the run (the objective's kernels exist
    /// only for mirror-symmetric PSFs; the trainer's fine-tune on a bundle,
    /// docs/calibration.md). prefilter.json records the asymmetry removed.
    #[arg(long)]
    pub mirror_psfs: bool,
}
