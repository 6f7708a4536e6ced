//! `nedrt bench tune` (docs/tuning.md): the register-tiled convolutions of
//! each network tuned on this adapter at each frame size and precision,
//! merged into the adapter's table under `--tuning DIR`, which the wgpu
//! backend then reads. Prints, per case, each conv shape's tile and time
//! at the heuristics' tile and at the tuned one, and each level that can
//! run fused, fused against unfused; then the DCT filter's workgroup shape
//! at each size (`bench_tune_fft.rs`).

use std::fmt::Write as _;
use std::path::PathBuf;

use super::AppError;
use super::bench_inference::{adapter, adapter_line, bench_frame};
use crate::CommonOptions;
use nedrt_infer::BackendOptions;
use nedrt_infer::gpu::GpuBackend;
use nedrt_infer::gpu::codegen::coop::CoopTile;
use nedrt_infer::gpu::tuning::{AdapterKey, TunedConv, TunedCoop, TunedFused, TuningTable};
use nedrt_infer::model_file::ModelFile;

/// What to tune.
#[derive(Debug, Clone)]
pub struct TuneBench {
    /// (name, model) of each network.
    pub networks: Vec<(String, ModelFile)>,
    /// Frame sizes, (width, height).
    pub sizes: Vec<(usize, usize)>,
    /// Timed repetitions per tile after a warm-up (the best is kept).
    pub repeat: usize,
    /// The folder of tables (the runtime's `--tuning`).
    pub dir: PathBuf,
    /// Only these tiles besides each layer's heuristic one (None: all).
    pub tiles: Option<Vec<nedrt_infer::gpu::codegen::ConvTile>>,
    /// Only these tiles of the fused levels (None: every tile each takes;
    /// none: no fused level is timed).
    pub fused_tiles: Option<Vec<nedrt_infer::gpu::codegen::fused::FusedTile>>,
    /// Only the layers on cooperative matrices (the tiled layers' entries
    /// of the table stay as they are).
    pub coop_only: bool,
    /// Also the DCT filter's shape at each size (not with `coop_only`).
    pub fft: bool,
}

/// What a run wrote, and its report.
#[derive(Debug, Clone)]
pub struct TuneOutcome {
    pub table: PathBuf,
    pub shapes: usize,
    pub report: String,
}

fn us(ns: u64) -> String {
    format!("{:.1}", ns as f64 * 1e-3)
}

fn tile(px: u32, threads_y: u32) -> String {
    format!("{}×{}", 8 * px, threads_y)
}

/// One case's table: each shape, the heuristics' tile against the tuned.
fn case_table(title: &str, convs: &[TunedConv], tiles_timed: usize) -> String {
    let mut md = format!(
        "\n### {title}\n\n{tiles_timed} tiles timed.\n\n| conv | layer input | heuristic tile | µs | tuned tile | µs | heuristic / tuned |\n| --- | --- | --- | ---: | --- | ---: | ---: |\n"
    );
    let (mut h_sum, mut t_sum) = (0u64, 0u64);
    for c in convs {
        let s = c.shape;
        let heuristic = nedrt_infer::gpu::codegen::ConvTile::for_layer(
            s.width,
            s.height,
            s.kernel,
            s.arith.into(),
        );
        h_sum = h_sum.saturating_add(c.heuristic_ns);
        t_sum = t_sum.saturating_add(c.tuned_ns);
        let _ = writeln!(
            md,
            "| {0}×{0} {1}→{2} | {3}×{4} | {5} | {6} | {7} | {8} | {9:.2} |",
            s.kernel,
            s.cin,
            s.cout,
            s.width,
            s.height,
            tile(heuristic.px, heuristic.threads_y),
            us(c.heuristic_ns),
            tile(c.px, c.threads_y),
            us(c.tuned_ns),
            c.heuristic_ns as f64 / c.tuned_ns.max(1) as f64
        );
    }
    md + &sum_row("all tiled convs", h_sum, t_sum)
}

/// A case table's last row: the shapes' times summed, at the heuristics'
/// tiles and at the tuned.
fn sum_row(label: &str, heuristic_ns: u64, tuned_ns: u64) -> String {
    format!(
        "| {label} | | | {} | | {} | {:.2} |\n",
        us(heuristic_ns),
        us(tuned_ns),
        heuristic_ns as f64 / tuned_ns.max(1) as f64
    )
}

fn coop_tile(t: CoopTile) -> String {
    let flags = [
        (t.plane_gather, ", by plane"),
        (t.stage_weights, ", weights staged"),
        (t.drain_once, ", drained at once"),
        (t.prefetch, ", prefetched"),
    ];
    format!(
        "{}×{} of {}×{}, {} channels a stage{}",
        t.sg_rows,
        t.sg_cols,
        t.rows,
        t.blocks,
        16 * t.chunks,
        flags
            .iter()
            .filter(|f| f.0)
            .map(|f| f.1)
            .collect::<String>()
    )
}

/// The cooperative-matrix shapes of a case, if any: each tile as
/// subgroups (over rows × over columns) of accumulators (pixel rows ×
/// column blocks), the input channels staged between two barriers,
/// whether they are gathered plane by plane, whether the weights are
/// staged in workgroup memory, whether the accumulators are drained at
/// once, and whether the next stage is prefetched through registers.
fn coop_table(coops: &[TunedCoop]) -> String {
    if coops.is_empty() {
        return String::new();
    }
    let mut md = "\n| cooperative conv | layer input | heuristic tile | µs | tuned tile | µs | heuristic / tuned |\n| --- | --- | --- | ---: | --- | ---: | ---: |\n".to_string();
    let (mut h_sum, mut t_sum) = (0u64, 0u64);
    for c in coops {
        let s = c.shape;
        h_sum = h_sum.saturating_add(c.heuristic_ns);
        t_sum = t_sum.saturating_add(c.tuned_ns);
        let _ = writeln!(
            md,
            "| {} {}→{} | {}×{} | {} | {} | {} | {} | {:.2} |",
            if s.transposed {
                "2×2 transposed".to_string()
            } else {
                format!("{0}×{0}", s.kernel)
            },
            s.cin,
            s.cout,
            s.width,
            s.height,
            coop_tile(CoopTile::for_layer(s.columns())),
            us(c.heuristic_ns),
            coop_tile(c.tile()),
            us(c.tuned_ns),
            c.heuristic_ns as f64 / c.tuned_ns.max(1) as f64
        );
    }
    md + &sum_row("all cooperative convs", h_sum, t_sum)
}

/// The fused levels: each shape's two layers at their tuned tiles against
/// one fused kernel at its fastest tile, and whether the table fuses it.
fn fused_table(fused: &[TunedFused]) -> String {
    if fused.is_empty() {
        return String::new();
    }
    let mut md = "\n| fused level | layer input | unfused µs | fused tile | µs | unfused / fused | fused in the table |\n| --- | --- | ---: | --- | ---: | ---: | --- |\n".to_string();
    for f in fused {
        let s = f.shape;
        let _ = writeln!(
            md,
            "| {0}×{0} {1}→{2}, {3}×{3} →{4} | {5}×{6} | {7} | {8}×{9} | {10} | {11:.2} | {12} |",
            s.first_kernel,
            s.cin,
            s.mid,
            s.kernel,
            s.cout,
            s.width,
            s.height,
            us(f.unfused_ns),
            f.tile_width,
            f.tile_height,
            us(f.fused_ns),
            f.unfused_ns as f64 / f.fused_ns.max(1) as f64,
            if f.faster() { "yes" } else { "no" }
        );
    }
    md
}

/// Tunes every network at every size, at the precision the backend is
/// asked for (`--precision`; tiles are tuned per storage and arithmetic
/// type),
/// merges the result into the adapter's table in `b.dir` (a shape tuned
/// again takes the new tile) and writes it.
pub fn run(b: &TuneBench, common: &CommonOptions) -> Result<TuneOutcome, AppError> {
    if b.networks.is_empty() || b.sizes.is_empty() {
        return Err(AppError::input(
            "bench tune",
            "no network or no size to tune",
        ));
    }
    let mut md = adapter_line(&adapter(common), common);
    // The adapter's table, read once the adapter is known (before minutes
    // of tuning, so a broken one costs none), each result merged in.
    let mut table: Option<TuningTable> = None;
    let precision = common.dcnn.backend_options.precision;
    let options = BackendOptions {
        // The tuner times against the heuristics, not an old table.
        tuning_dir: None,
        ..common.dcnn.backend_options.clone()
    };
    let networks = b
        .networks
        .iter()
        .map(|(name, model)| Ok((name, model.lower()?)))
        .collect::<Result<Vec<_>, AppError>>()?;
    // Every size checked before minutes of tuning.
    for (name, network) in &networks {
        let m = network.multiple.max(1);
        if let Some((w, h)) = b
            .sizes
            .iter()
            .find(|(w, h)| !w.is_multiple_of(m) || !h.is_multiple_of(m))
        {
            return Err(AppError::input(
                format!("--sizes {w}x{h}"),
                format!("the sides must be multiples of {m} for {name}"),
            ));
        }
    }
    for (name, network) in &networks {
        let mut gpu = GpuBackend::new_default(network, &options)?;
        if table.is_none() {
            let key = AdapterKey::of(&gpu.adapter_info());
            table = Some(match TuningTable::find(&b.dir, &key)? {
                Some((_, t)) => t,
                None => TuningTable::new(key, Vec::new(), Vec::new()),
            });
        }
        for &(w, h) in &b.sizes {
            tracing::info!("tuning {name} at {precision:?}, {w}×{h}");
            let kinds = nedrt_infer::gpu::TuneKinds {
                tiled: !b.coop_only,
                coop: true,
            };
            let result = gpu.tune_kinds(
                &bench_frame(w, h),
                b.repeat,
                b.tiles.as_deref(),
                b.fused_tiles.as_deref(),
                kinds,
            )?;
            md += &case_table(
                &format!("{name}, {precision:?}, {w}×{h}"),
                &result.convs,
                result.tiles_timed,
            );
            md += &coop_table(&result.coops);
            md += &fused_table(&result.fused);
            if !result.passed_over.is_empty() {
                md += "\nPassed over, their output not the heuristics' bit for bit (a kernel bug on \
                       this adapter):\n\n";
                for line in &result.passed_over {
                    md += &format!("- {line}\n");
                }
            }
            // A shape met again (another network, the same layer) keeps
            // its latest tuning.
            if let Some(t) = &mut table {
                t.merge(result.convs, result.coops);
                t.merge_fused(result.fused);
            }
        }
    }
    let Some(mut table) = table else {
        return Err(AppError::input(
            "bench tune",
            "no network could be prepared on the adapter",
        ));
    };
    // Stamped with this nedrt and template, whatever the old table said;
    // the conv entries written before the filter's tuning, which cannot
    // then lose them.
    let (ffts, fused) = (
        std::mem::take(&mut table.ffts),
        std::mem::take(&mut table.fused),
    );
    table = TuningTable::new(table.adapter, table.convs, table.coops);
    table.ffts = ffts;
    table.fused = fused;
    let mut path = table.save(&b.dir)?;
    if b.fft && !b.coop_only {
        let (adapter, device, queue) = nedrt_gpu::open_device(&options.gpu, false)?;
        if AdapterKey::of(&adapter.get_info()) != table.adapter {
            return Err(AppError::Internal(format!(
                "the DCT filter's adapter ({}) is not the networks' ({}); {} holds the conv entries",
                adapter.get_info().name,
                table.adapter.name,
                path.display()
            )));
        }
        tracing::info!("tuning the DCT filter at {} sizes", b.sizes.len());
        let fft = super::bench_tune_fft::tune(&device, &queue, &b.sizes, b.repeat)?;
        md += &fft.report;
        table.merge_ffts(fft.entries);
        path = table.save(&b.dir)?;
    }
    let shapes = table.convs.len() + table.coops.len();
    let _ = writeln!(
        md,
        "\nWrote {} ({} conv shapes, {} on cooperative matrices; {} fused level shape(s), {} fused; the DCT filter's shape at {} frame size(s)).",
        path.display(),
        shapes,
        table.coops.len(),
        table.fused.len(),
        table.fused.iter().filter(|f| f.faster()).count(),
        table.ffts.len()
    );
    Ok(TuneOutcome {
        table: path,
        shapes,
        report: md,
    })
}
