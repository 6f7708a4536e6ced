//! The studies' command lines: eval, tradeoff and pick, stability,
//! tune-wiener (clap definitions only, as in [`crate::args`]).

use std::path::PathBuf;

use clap::Args;
use nedrt_infer::BackendKind;
use nedrt_optics::sim::{Method, Optics};

use crate::args::{named, parse_size};

#[derive(Args, Debug)]
pub struct StabilityArgs {
    #[arg(long, default_value = "data/images/test", value_name = "DIR")]
    pub images: PathBuf,
    /// The report (Markdown); the JSON is written beside it.
    #[arg(long, default_value = "docs/stability.md", value_name = "FILE")]
    pub out: PathBuf,
    /// Side of the synthetic content frames.
    #[arg(long, default_value_t = 128)]
    pub content_size: usize,
    /// Skip the f16-against-f32 comparison on the wgpu adapter.
    #[arg(long)]
    pub no_gpu: bool,
    /// Display designs compared beside the baselines (names in designs/ or
    /// files); default: every design in designs/.
    #[arg(long, value_delimiter = ',', value_name = "NAME|FILE")]
    pub designs: Option<Vec<String>>,
    /// Also sweep the Wiener K of the AI display and of each design through
    /// these eyes (paper, 3mm, 4mm@20, 4mm+lca; docs/model.md §4a).
    #[arg(long, value_delimiter = ',', value_name = "EYE")]
    pub eyes: Vec<nedrt_studies::eval::eyes::EyeCase>,
}

#[derive(Args, Debug)]
pub struct TradeoffArgs {
    /// Images the quality is measured on.
    #[arg(long, default_value = "data/images/test", value_name = "DIR")]
    pub images: PathBuf,
    #[arg(long, default_value = "docs/tradeoff", value_name = "DIR")]
    pub out_dir: PathBuf,
    /// Frame size of the latency measurements (default: the panel's).
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(usize, usize)>,
    /// Trained networks: D-CNNs (NAME.onnx) or unrolled models
    /// (NAME.unrolled.toml), each with its .doe.safetensors beside it
    /// (default: models/dcnn.onnx; with --add, none).
    #[arg(long, value_delimiter = ',')]
    pub models: Option<Vec<PathBuf>>,
    #[arg(long, value_delimiter = ',', value_parser = named::<BackendKind>(), default_values = ["cpu", "ort", "wgpu"])]
    pub backends: Vec<BackendKind>,
    /// Timed runs per latency (median reported).
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// Estimate, rather than measure, a latency that would take longer than this (seconds).
    #[arg(long, default_value_t = 60.0)]
    pub max_seconds: f64,
    /// Skip the simulator-fidelity study (minutes of PSFs at the 3 µm pitch).
    #[arg(long)]
    pub no_fidelity: bool,
    /// Start no configuration after this many seconds: the rest are listed
    /// as not run and the table of those done is written.
    #[arg(long, value_name = "SECONDS")]
    pub time_budget: Option<f64>,
    /// Measure nothing: rewrite the tables and charts from the JSON in --out-dir.
    #[arg(long)]
    pub replot: bool,
    /// Measure only each design's --prefilter rows and the --models and add them to the
    /// table already in --out-dir (a row of the same name is replaced); the
    /// table must come from this host, --size, calibration and --images.
    #[arg(long, conflicts_with = "replot")]
    pub add: bool,
    /// Display designs compared beside the baselines (names in designs/ or
    /// files); default: every design in designs/.
    #[arg(long, value_delimiter = ',', value_name = "NAME|FILE")]
    pub designs: Option<Vec<String>>,
    /// Least-squares prefilters priced on each design's optics (lsq,
    /// refine:K, admm:K, optimal; each against the objective its design was
    /// made for; `native` alone adds none).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "lsq,refine:1,refine:3,refine:10,admm:1,admm:3,admm:10,optimal",
        value_name = "PREFILTER"
    )]
    pub prefilter: Vec<nedrt_stages::preprocess::Prefilter>,
}

#[derive(Args, Debug)]
pub struct PickArgs {
    /// Table written by `nedrt tradeoff`.
    #[arg(
        long,
        default_value = "docs/tradeoff/tradeoff.json",
        value_name = "FILE"
    )]
    pub table: PathBuf,
    /// Quality floor: mean PSNR over 0–2.5 D against the sharp image, dB.
    #[arg(long, value_name = "DB")]
    pub min_psnr: f64,
    /// Optional floor on the worst depth's PSNR, dB.
    #[arg(long, value_name = "DB")]
    pub min_worst_psnr: Option<f64>,
    /// Latency budget per frame, milliseconds.
    #[arg(long, value_name = "MS")]
    pub budget_ms: f64,
}

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Folder of test images (PNG, JPEG, TIFF).
    #[arg(long, value_name = "DIR")]
    pub images: PathBuf,
    #[arg(long, default_value = "out/eval", value_name = "DIR")]
    pub out_dir: PathBuf,
    /// Methods to evaluate (default: conventional, ai, doe-only, doe+wiener
    /// and, where the --dcnn model exists, proposed; with proposed, every
    /// DOE method uses its DOE).
    #[arg(long, value_delimiter = ',', value_parser = named::<Method>())]
    pub methods: Vec<Method>,
    /// Also evaluate display images made elsewhere (e.g. the trainer's
    /// D-CNN outputs): DIR/NAME for every input image NAME, same size.
    #[arg(long, value_name = "DIR")]
    pub display_dir: Option<PathBuf>,
    /// Row name for --display-dir.
    #[arg(long, default_value = "external", value_name = "NAME")]
    pub display_name: String,
    /// Optics the --display-dir images are seen through.
    #[arg(long, value_parser = named::<Optics>(), default_value = "doe")]
    pub display_optics: Optics,
    /// Also measure focus cues: each method's perceived sharpness at 5 and
    /// 10 CPD over 0–3 D in 0.1 D steps, its focus-cue score at the main
    /// depths and a chart (focus_cues.png/.svg); renders 31 depths instead of 7.
    #[arg(long)]
    pub focus_cues: bool,
    /// Display designs to add, one `doe+wiener NAME` row each with its own
    /// DOE and K (names in designs/ or design files).
    #[arg(long, value_delimiter = ',', value_name = "NAME|FILE")]
    pub designs: Vec<String>,
    /// Also write a focus sweep of every image into DIR: DIR/NAME.png, an
    /// animated PNG of the evaluated methods side by side over 0–3 D in
    /// 0.1 D steps (`nedrt sweep`).
    #[arg(long, value_name = "DIR")]
    pub sweeps: Option<PathBuf>,
    /// How each display image is made from the frame, given the method's
    /// optics: native (the method's own: none, Wiener or D-CNN), lsq (the
    /// linear least-squares prefilter), refine:K (lsq and K projected-gradient
    /// steps), admm:K (lsq and K split-solver steps) or optimal (the bounded
    /// least-squares optimum); all but native
    /// against the target (default) or, with @sharp, the sharp image over
    /// 0–2.5 D (docs/optimal.md).
    /// A list gives one row per method (and design) and prefilter.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "native",
        value_name = "PREFILTER"
    )]
    pub prefilter: Vec<nedrt_stages::preprocess::Prefilter>,
    /// Repeat the evaluation for each eye (docs/model.md §4a): `paper`, a
    /// pupil `3mm`, with a field angle `4mm@20`, with eye LCA `4mm+lca`;
    /// one folder each under --out-dir, tables and a chart over them (eyes.md).
    #[arg(long, value_delimiter = ',', value_name = "EYE")]
    pub eyes: Vec<nedrt_studies::eval::eyes::EyeCase>,
}

#[derive(Args, Debug)]
pub struct TuneArgs {
    /// Training images.
    #[arg(long, default_value = "data/images/train", value_name = "DIR")]
    pub images: PathBuf,
    /// ai or doe+wiener.
    #[arg(long, value_parser = named::<Method>())]
    pub method: Method,
    /// Write the chosen K into the calibration file (comments kept).
    #[arg(long)]
    pub write: bool,
}
