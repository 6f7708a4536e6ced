//! `nedrt tradeoff`: every preprocessing configuration priced in
//! milliseconds per frame (at the stated resolution, on this machine) and
//! in image quality (mean and worst PSNR, SSIM over 0–2.5 D on an image
//! set), side by side, with the Pareto front; plus the simulator's own
//! fidelity settings against their cost ([`fidelity`]). `nedrt pick` reads
//! the table back and names the configuration for a quality floor and a
//! latency budget ([`pareto::pick`]).

pub mod chart;
pub mod fidelity;
mod linear;
mod measure;
pub mod pareto;
pub mod quality;
mod report;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use measure::{Measured, displays_and_latency};
pub use measure::{host_description, latency_frame};
pub use quality::{Quality, Scorer};
pub use report::{markdown, write_table};

use super::eval::{list_images, load_all};
use super::{AppError, CommonOptions, create_dir};
use crate::preprocess::Prefilter;
use linear::{Config, LinearRun, Priced};
use nedrt_infer::{BackendKind, BackendOptions};
use nedrt_optics::sim::{Method, Simulator};
use nedrt_stages::Network;
use pareto::{Point, pareto_front};

/// What `nedrt tradeoff` measures.
#[derive(Debug, Clone)]
pub struct TradeoffOptions {
    pub images_dir: PathBuf,
    pub out_dir: PathBuf,
    /// Frame size of the latency measurements (width, height).
    pub size: (usize, usize),
    /// Trained D-CNNs, each with its DOE beside it (`<stem>.doe.safetensors`).
    pub models: Vec<PathBuf>,
    pub backends: Vec<BackendKind>,
    /// Timed runs per latency (after one warm-up).
    pub repeat: usize,
    /// A latency whose estimate exceeds this many seconds in all is not
    /// measured (its estimate is recorded, marked as such).
    pub max_seconds: f64,
    /// Threads of the ort backend (0: its default).
    pub threads: usize,
    /// Also run the simulator-fidelity study.
    pub fidelity: bool,
    /// Display designs whose DOE (with and without its Wiener) join the
    /// baselines, each with its own K.
    pub designs: Vec<super::design::Design>,
    /// The least-squares prefilters priced for each design's optics (with
    /// the objective the design was made for, whatever the spec says).
    pub prefilters: Vec<Prefilter>,
    /// Seconds after which no further configuration is started: the ones
    /// left are listed as not run and the table of those done is written
    /// (a lent GPU's step has a cap; a partial chart beats none).
    pub time_budget_s: Option<f64>,
    /// Measure only each design's `prefilters` and the `models` and add their rows to the
    /// table already in `out_dir` (replacing rows of the same name), which
    /// must come from this host, frame size, calibration and images.
    pub add: bool,
}

/// Whether `--time-budget` is spent; if so, `name` goes to the skipped
/// list with the reason.
fn out_of_time(o: &TradeoffOptions, start: Instant, name: &str, skipped: &mut Vec<String>) -> bool {
    match o.time_budget_s {
        Some(budget) if start.elapsed().as_secs_f64() >= budget => {
            skipped.push(format!(
                "{name}: not run, the --time-budget of {budget} s was spent"
            ));
            true
        }
        _ => false,
    }
}

/// Rewrites the Markdown and the charts from the JSON already in
/// `out_dir`, measuring nothing (after a change to the report's layout).
pub fn replot(out_dir: &Path) -> Result<String, AppError> {
    let mut text = write_table(&Table::load(&out_dir.join("tradeoff.json"))?, out_dir)?;
    if out_dir.join("fidelity.json").exists() {
        text.push('\n');
        text.push_str(&fidelity::replot(out_dir)?);
    }
    Ok(text)
}

/// The table `--add` adds to, checked to be comparable with this run.
fn earlier_table(
    o: &TradeoffOptions,
    host: &str,
    calibration: &str,
    files: &[PathBuf],
) -> Result<Table, AppError> {
    let path = o.out_dir.join("tradeoff.json");
    if !path.exists() {
        return Err(AppError::input(
            path.display(),
            "--add adds rows to the table in --out-dir, and there is none (run nedrt tradeoff \
             without --add first)",
        ));
    }
    let table = Table::load(&path)?;
    let images: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
    let differs = [
        ("host", table.host == host),
        (
            "frame size",
            (table.frame_width, table.frame_height) == o.size,
        ),
        ("calibration", table.calibration == calibration),
        ("images", table.images == images),
    ];
    if let Some((what, _)) = differs.iter().find(|(_, same)| !same) {
        return Err(AppError::input(
            path.display(),
            format!(
                "its {what} is not this run's, so their rows cannot share a chart (the table: \
                 {} at {}×{}, {}, {} images)",
                table.host,
                table.frame_width,
                table.frame_height,
                table.calibration,
                table.images.len()
            ),
        ));
    }
    Ok(table)
}

/// `earlier` with `records` added, each replacing a row of its name, and
/// the front recomputed.
fn merged(mut earlier: Table, records: Vec<Record>, skipped: Vec<String>) -> Table {
    let names: Vec<String> = records.iter().map(|r| r.point.name.clone()).collect();
    earlier.records.retain(|r| !names.contains(&r.point.name));
    earlier
        .skipped
        .retain(|s| !names.iter().any(|n| s.starts_with(&format!("{n}:"))));
    earlier.records.extend(records);
    earlier.skipped.extend(skipped);
    let points = earlier.points();
    for (r, on) in earlier.records.iter_mut().zip(pareto_front(&points)) {
        r.on_front = on;
    }
    earlier
}

/// One configuration's row of the table.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Record {
    #[serde(flatten)]
    pub point: Point,
    pub method: String,
    /// D-CNN file and content hash, for D-CNN methods.
    pub model: Option<String>,
    pub model_hash: Option<String>,
    /// DOE content hash, for methods with a DOE.
    pub doe_hash: Option<String>,
    pub backend: String,
    pub precision: String,
    /// Where the preprocessing ran.
    pub device: String,
    /// Latency extrapolated from the image runs when it was not measured.
    pub estimated_ms: Option<f64>,
    /// Mean PSNR per evaluation depth, (D, dB).
    pub per_depth_psnr_db: Vec<(f64, f64)>,
    pub on_front: bool,
}

/// The table `nedrt tradeoff` writes and `nedrt pick` reads.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Table {
    pub host: String,
    pub calibration: String,
    pub frame_width: usize,
    pub frame_height: usize,
    pub images: Vec<String>,
    pub records: Vec<Record>,
    /// Configurations that could not run here, with the reason.
    pub skipped: Vec<String>,
}

impl Table {
    pub fn points(&self) -> Vec<Point> {
        self.records.iter().map(|r| r.point.clone()).collect()
    }

    /// Reads a table written by `nedrt tradeoff`, naming the file on error.
    pub fn load(path: &Path) -> Result<Self, AppError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| AppError::input(path.display(), format!("cannot read: {e}")))?;
        serde_json::from_str(&text).map_err(|e| {
            AppError::input(
                path.display(),
                format!("not a table written by `nedrt tradeoff`: {e}"),
            )
        })
    }
}

/// The D-CNN file's companion DOE, which `proposed` must be simulated with.
fn companion_doe(model: &Path) -> Result<PathBuf, AppError> {
    let doe = model.with_extension("doe.safetensors");
    if !doe.exists() {
        return Err(AppError::input(
            model.display(),
            format!(
                "no DOE beside this D-CNN ({} is missing); the proposed system is a D-CNN and the DOE it was trained with",
                doe.display()
            ),
        ));
    }
    Ok(doe)
}

/// Runs every configuration and writes `tradeoff.{md,json,png,svg}` (and
/// the fidelity study's files) into the output folder.
pub fn run(common: &CommonOptions, o: &TradeoffOptions) -> Result<String, AppError> {
    let start = Instant::now();
    if o.size.0 == 0 || o.size.1 == 0 {
        return Err(AppError::option(
            "--size",
            "width and height must be positive",
        ));
    }
    if o.models.is_empty() {
        return Err(AppError::Unavailable(
            "no trained D-CNN to compare (give --models FILE,…)".into(),
        ));
    }
    let files = list_images(&o.images_dir)?;
    let inputs = load_all(&files, common.panel_px()?)?;
    create_dir(&o.out_dir)?;
    let dcnn_doe = companion_doe(&o.models[0])?;
    let calib = common.calibration()?;
    let frame = latency_frame(o.size);
    let mut records = Vec::new();
    let mut skipped = Vec::new();
    let host = host_description();

    // The baselines, simulated with the first model's DOE (or --doe/--design).
    let sim = common.measured(Simulator::new(
        calib.clone(),
        Some(common.doe.as_deref().unwrap_or(&dcnn_doe)),
        common.cache(),
    )?)?;
    let baselines = [
        Method::Conventional,
        Method::Ai,
        Method::DoeOnly,
        Method::DoeWiener,
    ];
    let design_sims = o
        .designs
        .iter()
        .map(|d| d.simulator(calib.clone(), common.cache()))
        .collect::<Result<Vec<_>, _>>()?;
    let design_methods = [Method::DoeOnly, Method::DoeWiener];
    let earlier = if o.add {
        Some(earlier_table(o, &host, &calib.source, &files)?)
    } else {
        None
    };
    let design_scorers = design_sims
        .iter()
        .map(|s| Scorer::new(s, &design_methods, &inputs, common.progress()))
        .collect::<Result<Vec<_>, _>>()?;
    let bar = common.phase("configs");
    let prefilters: Vec<Prefilter> = o
        .prefilters
        .iter()
        .filter(|p| !p.is_native())
        .copied()
        .collect();
    bar.set_length(
        (baselines.len()
            + (design_methods.len() + prefilters.len()) * o.designs.len()
            + o.models.len() * (o.backends.len() + 1)) as u64,
    );
    let run = LinearRun {
        inputs: &inputs,
        frame: &frame,
        repeat: o.repeat,
        max_seconds: o.max_seconds,
        device: format!("{host} (rayon, {} threads)", rayon::current_num_threads()),
        gpu: if o.backends.contains(&BackendKind::Wgpu) {
            match nedrt_gpu::open_device(&common.dcnn.backend_options.gpu, false) {
                Ok((adapter, device, queue)) => Some(((device, queue), adapter.get_info().name)),
                Err(e) => {
                    tracing::warn!("the prefilters' device rows: skipped: {e}");
                    skipped.push(format!("prefilters on wgpu: {e}"));
                    None
                }
            }
        } else {
            None
        },
    };
    // The rows a lent GPU is asked for first (under --time-budget the
    // rest may not run): each design's least-squares prefilters, then the
    // networks; the baselines and the designs' plain systems last.
    let priced = Priced {
        o,
        start,
        run: &run,
        bar: &bar,
    };
    priced.linear(
        o.designs
            .iter()
            .zip(&design_sims)
            .zip(&design_scorers)
            .flat_map(|((design, sim), scorer)| {
                prefilters.iter().map(move |p| {
                    let prefilter = p.with_objective(design.objective());
                    Config {
                        scorer,
                        doe_hash: &sim.doe_hash,
                        method: Method::DoeWiener,
                        prefilter,
                        name: prefilter.label(&format!(
                            "{} {}",
                            Method::DoeWiener.name(),
                            design.name
                        )),
                    }
                })
            }),
        &mut records,
        &mut skipped,
    )?;
    for model in &o.models {
        let doe = companion_doe(model)?;
        let stem = model
            .file_stem()
            .map_or_else(|| "dcnn".into(), |s| s.to_string_lossy().into_owned());
        // The network's scorer is minutes of PSFs on a small machine: not
        // started once the budget is spent.
        if out_of_time(o, start, &format!("proposed {stem}"), &mut skipped) {
            bar.inc(o.backends.len() as u64 + 1);
            continue;
        }
        let staged = crate::preprocess::dcnn_input(model)? != crate::preprocess::DcnnInput::Frame;
        let sim = common
            .measured(Simulator::new(calib.clone(), Some(&doe), common.cache())?)?
            .with_wiener_stages(if staged {
                vec![Method::Proposed]
            } else {
                Vec::new()
            });
        let scorer = Scorer::new(
            &sim,
            &[Method::Proposed],
            &inputs,
            &nedrt_core::progress::Silent,
        )?;
        for &kind in &o.backends {
            for &precision in kind.precisions() {
                let options = BackendOptions {
                    threads: o.threads,
                    precision,
                    ..common.dcnn.backend_options.clone()
                };
                let prec = format!("{precision:?}").to_lowercase();
                let name = format!("proposed {stem} {} {prec}", kind.name());
                if out_of_time(o, start, &name, &mut skipped) {
                    continue;
                }
                let network = match Network::load(Method::Proposed, model, kind, &options) {
                    Ok(d) => d,
                    Err(e) => {
                        tracing::warn!("{name}: skipped: {e}");
                        skipped.push(format!("{name}: {e}"));
                        continue;
                    }
                };
                let model_hash = network.hash().to_string();
                // The network with the stage its card asks for in front
                // (the Wiener, for a network trained on its output), or the
                // unrolled model through the prepared optics: timed and
                // scored as the runtime runs it.
                let gpu = run.gpu.as_ref().map(|(g, _)| g);
                let mut dcnn = crate::device_prefilter::network_on(
                    network,
                    gpu,
                    Method::Proposed,
                    &scorer.prepared,
                )?;
                let Measured {
                    displays,
                    latency_ms,
                    estimated_ms,
                } = displays_and_latency(&name, &inputs, &frame, o.repeat, o.max_seconds, |i| {
                    dcnn.run(i)
                })?;
                let q = scorer.quality(Method::Proposed, &displays)?;
                let mut r = q.record(
                    &name,
                    Method::Proposed,
                    latency_ms,
                    estimated_ms,
                    Some(sim.doe_hash.clone()),
                    (kind.name(), &prec, dcnn.describe()),
                );
                r.model = Some(model.display().to_string());
                r.model_hash = Some(model_hash);
                records.push(r);
            }
            bar.inc(1);
        }
        bar.inc(1);
    }
    // --add: the designs' prefilters and the networks, not the baselines.
    if let Some(earlier) = earlier {
        bar.finish_and_clear();
        let text = write_table(&merged(earlier, records, skipped), &o.out_dir)?;
        return Ok(format!(
            "{text}\nWall time {:.1} s.\n",
            start.elapsed().as_secs_f64()
        ));
    }

    let scorer = Scorer::new(&sim, &baselines, &inputs, common.progress())?;
    priced.linear(
        baselines
            .iter()
            .map(|&method| Config {
                scorer: &scorer,
                doe_hash: &sim.doe_hash,
                method,
                prefilter: Prefilter::Native,
                name: method.name().to_string(),
            })
            .chain(
                o.designs
                    .iter()
                    .zip(&design_sims)
                    .zip(&design_scorers)
                    .flat_map(|((design, sim), scorer)| {
                        design_methods.iter().map(move |&method| Config {
                            scorer,
                            doe_hash: &sim.doe_hash,
                            method,
                            prefilter: Prefilter::Native,
                            name: format!("{} {}", method.name(), design.name),
                        })
                    }),
            ),
        &mut records,
        &mut skipped,
    )?;
    bar.finish_and_clear();
    if records.is_empty()
        && let Some(budget) = o.time_budget_s
    {
        return Err(AppError::option(
            "--time-budget",
            format!(
                "{budget} s was spent before the first configuration ran ({} not run); nothing written",
                skipped.len()
            ),
        ));
    }
    let points: Vec<Point> = records.iter().map(|r| r.point.clone()).collect();
    for (r, on) in records.iter_mut().zip(pareto_front(&points)) {
        r.on_front = on;
    }
    let table = Table {
        host,
        calibration: calib.source.clone(),
        frame_width: o.size.0,
        frame_height: o.size.1,
        images: files.iter().map(|f| f.display().to_string()).collect(),
        records,
        skipped,
    };
    let mut text = write_table(&table, &o.out_dir)?;
    if o.fidelity {
        text.push('\n');
        text.push_str(&fidelity::run(common, &dcnn_doe, &inputs, &o.out_dir)?);
    }
    let _ = writeln!(text, "\nWall time {:.1} s.", start.elapsed().as_secs_f64());
    Ok(text)
}
