//! `nedrt bench`'s command line (clap definitions only, as in
//! [`crate::args`]).

use std::path::PathBuf;

use clap::{Args, ValueEnum};
use nedrt_infer::BackendKind;
use nedrt_run::FramePath;
use nedrt_studies::bench_pipeline::PipelineNetwork;

use crate::args::{named, parse_size};

/// What `nedrt bench` times.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum BenchKind {
    /// The PSF computation (inputs dumped for tools/bench/compare_numpy.py).
    Psf,
    /// The perceived image (convolution) of one frame.
    Perceived,
    /// This machine's f64 GEMM and copy ceilings.
    Ceilings,
    /// The D-CNN's latency per backend and frame size.
    Inference,
    /// The radial PSF path against the 2-D path (docs/benchmarks.md).
    Radial,
    /// The service end to end per network and frame path (docs/benchmarks.md).
    Pipeline,
    /// The prefilters' transform on the device against the CPU's (docs/gpu-fft.md).
    Fft,
    /// Each tiled convolution's tile tuned on this adapter, written into
    /// its table under --tuning (docs/tuning.md).
    Tune,
}

/// `--tiles`: a conv tile as its output pixels, WIDTHxHEIGHT (8, 16 or
/// 32 wide; 1, 2, 4, 8 or 16 tall).
pub(crate) fn parse_tile(s: &str) -> Result<nedrt_infer::gpu::codegen::ConvTile, String> {
    let (w, h) = parse_size(s)?;
    if ![8, 16, 32].contains(&w) || !h.is_power_of_two() || h > 16 {
        return Err(format!(
            "{s:?}: a conv tile is 8, 16 or 32 pixels wide and 1, 2, 4, 8 or 16 tall"
        ));
    }
    Ok(nedrt_infer::gpu::codegen::ConvTile {
        px: (w / 8) as u32,
        threads_y: h as u32,
    })
}

/// `--fused-tiles`: a fused level's tile as its output pixels,
/// WIDTHxHEIGHT (8×8, 16×8, 8×16, 16×16, 32×8 or 32×16).
pub(crate) fn parse_fused_tile(
    s: &str,
) -> Result<nedrt_infer::gpu::codegen::fused::FusedTile, String> {
    let (w, h) = parse_size(s)?;
    let tile = nedrt_infer::gpu::codegen::fused::FusedTile {
        width: w as u32,
        height: h as u32,
    };
    if w > 32 || h > 16 || !tile.is_valid() {
        return Err(format!(
            "{s:?}: a fused level's tile is 8x8, 16x8, 8x16, 16x16, 32x8 or 32x16"
        ));
    }
    Ok(tile)
}

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// What to time.
    #[arg(value_enum)]
    pub what: BenchKind,
    /// inference: backends to time.
    #[arg(long, value_delimiter = ',', value_parser = named::<BackendKind>(), default_values = ["cpu", "ort", "wgpu"])]
    pub backends: Vec<BackendKind>,
    /// inference: frame sizes, WIDTHxHEIGHT.
    #[arg(long, value_delimiter = ',', default_values = ["512x512", "1920x1080"], value_parser = parse_size)]
    pub sizes: Vec<(usize, usize)>,
    /// inference: skip a case estimated to take longer than this (seconds);
    /// pipeline: stop a case after this long.
    #[arg(long, default_value_t = 120.0)]
    pub max_seconds: f64,
    /// pipeline: networks to run; tune: networks to tune (half, full,
    /// model; the others have no convolutions and are passed over).
    #[arg(long, value_delimiter = ',', value_parser = named::<PipelineNetwork>(), default_values = ["none", "half", "full", "model"])]
    pub networks: Vec<PipelineNetwork>,
    /// pipeline: frame paths to run each network on.
    #[arg(long, value_delimiter = ',', value_parser = named::<FramePath>(), default_values = ["device", "host"])]
    pub frame_paths: Vec<FramePath>,
    /// pipeline: frames the test pattern submits per case.
    #[arg(long, default_value_t = 100)]
    pub frames: u64,
    /// pipeline: the panel's size, WIDTHxHEIGHT (default: the calibration's).
    #[arg(long, value_parser = parse_size, value_name = "WxH")]
    pub panel: Option<(usize, usize)>,
    /// pipeline: two views (eyes) side by side, each of the --panel size
    /// (or the calibration's): a panel twice as wide; each eye's engine time.
    #[arg(long)]
    pub stereo: bool,
    /// pipeline: write each case's frame timelines (JSON, one file a case:
    /// when each frame was submitted, went through each stage, and was
    /// shown or replaced) into DIR.
    #[arg(long, value_name = "DIR")]
    pub frame_log: Option<PathBuf>,
    /// Folder for the exact inputs, for the numpy side.
    #[arg(long, default_value = "out/bench", value_name = "DIR")]
    pub dump: PathBuf,
    /// Timed repetitions (median reported).
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// inference: time each layer on the wgpu backend (timestamp queries)
    /// and say which sit furthest from the floor; fft: each dispatch.
    #[arg(long)]
    pub per_layer: bool,
    /// inference --per-layer: the general (CUDA) cores' peak multiply-add
    /// rate, GMAC/s, the CUDA-core floor (default: the best any layer on
    /// them reaches in the run).
    #[arg(long, value_name = "GMAC/S")]
    pub peak_gmacs: Option<f64>,
    /// inference --per-layer: the tensor cores' (matrix units') peak
    /// multiply-add rate at f16, GMAC/s, the floor of the layers on
    /// cooperative matrices (half the f16 GEMM's FLOP rate; default: the
    /// best any such layer reaches in the run).
    #[arg(long, value_name = "GMAC/S")]
    pub peak_tensor_gmacs: Option<f64>,
    /// inference --per-layer, fft: the adapter's peak memory bandwidth, GB/s
    /// (inference: default the best any layer reaches in the run; fft: no floor).
    #[arg(long, value_name = "GB/S")]
    pub peak_gbps: Option<f64>,
    /// tune: only these register-tiled conv tiles besides each layer's
    /// heuristic one, WIDTHxHEIGHT in output pixels (default: every tile;
    /// each is a kernel to compile, seconds apiece on a software adapter).
    /// The layers on cooperative matrices are tuned over all their tiles.
    #[arg(long, value_delimiter = ',', value_parser = parse_tile, value_name = "WxH")]
    pub tiles: Vec<nedrt_infer::gpu::codegen::ConvTile>,
    /// tune: only these tiles of the fused levels, WIDTHxHEIGHT in output
    /// pixels (default: every tile each level takes; each tile of each
    /// level is a kernel to compile).
    #[arg(long, value_delimiter = ',', value_parser = parse_fused_tile, value_name = "WxH")]
    pub fused_tiles: Vec<nedrt_infer::gpu::codegen::fused::FusedTile>,
    /// tune: no fused level (the table's fused entries stay as they are).
    #[arg(long, conflicts_with = "fused_tiles")]
    pub no_fused: bool,
    /// tune: only the layers on cooperative matrices (at --precision f16 on
    /// an adapter that has them); the table's tiled entries stay as they are.
    #[arg(long)]
    pub coop_only: bool,
    /// tune: leave the DCT filter's entries as they are (by default each
    /// size's filter is tuned too, unless --coop-only).
    #[arg(long)]
    pub no_fft: bool,
    /// fft: the device FFT paths to time side by side.
    #[arg(long, value_delimiter = ',', value_enum, default_values = ["auto", "multipass"])]
    pub fft_paths: Vec<FftPathArg>,
    /// fft: shapes of the workgroup-memory kernels to time beside the
    /// paths, THREADSxPAIRS: threads a workgroup (32 to 1024) and at most
    /// that many sequence pairs a workgroup (1, 2, 4 or 8), rows and
    /// columns alike, as many as fit the adapter's workgroup memory.
    #[arg(long, value_delimiter = ',', value_parser = parse_fft_variant, value_name = "TxP")]
    pub fft_variants: Vec<nedrt_gpu::fft::FusedVariant>,
    /// fft: also `refine:K` per frame at each size, its steps fused into the
    /// filter's rows beside their own kernels (issue 56, item 3).
    #[arg(long, value_name = "K", value_parser = clap::value_parser!(u16).range(1..=1000))]
    pub refine_steps: Option<u16>,
}

/// `--fft-variants` THREADSxPAIRS.
pub(crate) fn parse_fft_variant(s: &str) -> Result<nedrt_gpu::fft::FusedVariant, String> {
    let bad =
        || format!("{s:?}: not THREADSxPAIRS (threads 32 to 1024, pairs 1, 2, 4 or 8; e.g. 256x4)");
    let (t, p) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let threads: u32 = t.trim().parse().map_err(|_| bad())?;
    let pairs: u32 = p.trim().parse().map_err(|_| bad())?;
    // Fewer threads unroll a whole length's butterflies into each one:
    // a kernel of hundreds of thousands of lines.
    if !(32..=1024).contains(&threads) || ![1, 2, 4, 8].contains(&pairs) {
        return Err(bad());
    }
    Ok(nedrt_gpu::fft::FusedVariant {
        threads: Some(threads),
        max_seqs: Some(pairs),
    })
}

/// `nedrt bench fft --fft-paths`: which kernels run the DCT filter.
#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FftPathArg {
    /// One dispatch per axis in workgroup memory where the sides fit, else the passes.
    Auto,
    /// The multi-pass fallback (each radix a dispatch through device memory), forced.
    Multipass,
}

impl From<FftPathArg> for nedrt_gpu::fft::FftPath {
    fn from(p: FftPathArg) -> Self {
        match p {
            FftPathArg::Auto => Self::Auto,
            FftPathArg::Multipass => Self::MultiPass,
        }
    }
}
