//! `nedrt bench pipeline`: the whole service end to end, the test pattern
//! through the D-CNN stage to an off-screen panel on the default adapter,
//! for each network and each frame path, one after the other in one run.
//! Reports the end-to-end latency of the frames shown (p50, p99, max), how
//! many were shown and dropped, and the run report's host traffic per
//! frame, so the device path and the host path sit side by side.
//!
//! Networks: `none` (no network: the frame as it comes), `half` and `full`
//! (the trainer's U-Net at 16 and 32 channels, random weights: latency does
//! not depend on them) and `model` (the `--dcnn` model, models/dcnn.onnx
//! by default, with its card: the shipped one runs its Wiener stage first,
//! on the device where the frame stays there), `wiener` (no network:
//! the DOE's Wiener prefilter, `doe+wiener`) and `refine10` (its `lsq` and
//! 10 projected-gradient steps). Performance is measured here, never
//! asserted in tests.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use serde_json::json;

use super::AppError;
use super::run::{
    FallbackKind, FramePath, LadderSpec, QualityTable, RunOptions, SinkKind, SourceKind,
};
use crate::CommonOptions;
use nedrt_core::Named;
use nedrt_infer::{BackendKind, synth};
use nedrt_optics::sim::Method;
use nedrt_service::pipeline::service::Control;
use nedrt_service::pipeline::stats::{Report, summarize};

/// A network the pipeline runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PipelineNetwork {
    /// The frame budget's ladder (`--preprocess auto`).
    Auto,
    None,
    Wiener,
    Refine10,
    Admm3,
    Admm10,
    Half,
    Full,
    Model,
}

impl Named for PipelineNetwork {
    const ALL: &'static [Self] = &[
        Self::Auto,
        Self::None,
        Self::Wiener,
        Self::Refine10,
        Self::Admm3,
        Self::Admm10,
        Self::Half,
        Self::Full,
        Self::Model,
    ];
    fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::None => "none",
            Self::Wiener => "wiener",
            Self::Refine10 => "refine10",
            Self::Admm3 => "admm3",
            Self::Admm10 => "admm10",
            Self::Half => "half",
            Self::Full => "full",
            Self::Model => "model",
        }
    }
    fn help(self) -> &'static str {
        match self {
            Self::Auto => {
                "the frame budget: each frame the best level of none < wiener < admm:K < the \
                 --dcnn model that fits the refresh (--preprocess auto)"
            }
            Self::None => "no network: the frame as it comes, clamped",
            Self::Wiener => "no network: the DOE's Wiener prefilter (doe+wiener, the --design's)",
            Self::Refine10 => {
                "no network: doe+wiener's lsq prefilter and 10 projected-gradient steps (refine:10)"
            }
            Self::Admm3 => {
                "no network: doe+wiener's lsq prefilter and 3 split-solver steps (admm:3, issue 55's \
                 time line)"
            }
            Self::Admm10 => {
                "no network: doe+wiener's lsq prefilter and 10 split-solver steps (admm:10)"
            }
            Self::Half => "the U-Net at 16–128 channels (random weights)",
            Self::Full => "the U-Net at 32–256 channels (random weights)",
            Self::Model => "the --dcnn model (models/dcnn.onnx) with its card",
        }
    }
}

/// What to run.
#[derive(Debug, Clone)]
pub struct PipelineBench {
    pub networks: Vec<PipelineNetwork>,
    pub paths: Vec<FramePath>,
    /// Frames the pattern submits per case, at the panel's refresh.
    pub frames: u64,
    /// A case is stopped after this long (its frames so far are reported).
    pub max_seconds: f64,
    /// The panel's size instead of the calibration's.
    pub panel_size: Option<(usize, usize)>,
    /// Where the synthetic networks are written.
    pub dump: PathBuf,
    /// Two views side by side, each of the panel's size (a panel twice as
    /// wide), each eye its engine; the table adds each eye's engine time.
    pub stereo: bool,
    /// Where each case's frame timelines go (none: not written).
    pub frame_log: Option<PathBuf>,
}

/// Runs every case, handing each result to `on_record` (JSON) as it is
/// measured, and returns the Markdown table.
pub fn run(
    b: &PipelineBench,
    common: &CommonOptions,
    on_record: &mut dyn FnMut(&serde_json::Value),
) -> Result<String, AppError> {
    // One message for the pair (tests/cli/bad_input.rs quotes it): each case
    // stops at whichever limit comes first, so both must be positive.
    if !(b.max_seconds.is_finite() && b.max_seconds > 0.0) || b.frames == 0 {
        return Err(AppError::Conflict(format!(
            "--frames {} and --max-seconds {} must be positive",
            b.frames, b.max_seconds
        )));
    }
    let calib = common.calibration()?;
    let (eye_w, h) = b
        .panel_size
        .unwrap_or((calib.panel.width_px, calib.panel.height_px));
    let w = if b.stereo { 2 * eye_w } else { eye_w };
    std::fs::create_dir_all(&b.dump).map_err(|e| AppError::output(&b.dump, e))?;
    if let Some(dir) = &b.frame_log {
        std::fs::create_dir_all(dir).map_err(|e| AppError::output(dir, e))?;
    }
    let period_ms = 1e3 / calib.panel.refresh_hz;
    let ms2 = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.2}"));
    // Where the time of each case's frames went, by what became of them.
    let mut why = String::from(
        "\nWhere the frames' time went (the timelines' medians by what became of each frame: \
         shown on its predicted refresh, before or after it, or replaced in the present slot by a \
         newer frame; frames evicted from a queue before it have no timeline; to preprocess: \
         submission to the preprocess stage; held: waiting for a present; preprocess: its own \
         time less the hold; of it GPU: the stages' own time on the device (timestamps); of it \
         recorded: the host's before the submission; of it frame on GPU: the whole submission on \
         the device (uploads' copies, unpacks, layers, stages, encodes); to ready: its end to the present slot; ready before take: the \
         present loop's wake for the frame's predicted refresh less its ready time, negative \
         when it missed it; present: the take to the present's end, of the frames shown; \
         first/last s: when the first and last of them were submitted)\n\n\
         | network | frame path | frames | count | to preprocess ms | held ms | preprocess ms | \
         of it GPU ms | of it recorded ms | of it frame on GPU ms | to ready ms | \
         ready before take ms | present ms | first s | last s |\n\
         | --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
    );
    let views = if b.stereo {
        format!("two views of {eye_w}×{h} (each eye its frames and engine), ")
    } else {
        String::new()
    };
    let eye_columns = if b.stereo {
        (" eye 0 p50 ms | eye 1 p50 ms |", " --- | --- |")
    } else {
        ("", "")
    };
    let mut table = format!(
        "`nedrt bench pipeline`: test pattern at {} Hz, {w}×{h}, {views}wgpu backend, headless sink; \
         at most {} frames or {} s per case from its first frame \
         (prepare s: the PSFs and filters for the panel, before it; dropped: the source's frames \
         never shown; late: shown after the refresh predicted at submission; submitted ahead: \
         the mean time from a frame's submission to the refresh predicted for it, the pipeline's \
         bound plus the present loop's lead; GPU p50: the engine's own time on the device per \
         frame, from timestamp queries; quality: the mean PSNR vs sharp over 0–2.5 D of the \
         configuration in the tradeoff table, for `auto` of the levels run, weighted by their \
         frames)\n\n\
         | network | frame path | prepare s | shown | dropped | late | submitted ahead ms | e2e p50 ms | e2e p99 ms | \
         e2e max ms | GPU p50 ms | MB up / frame | uploads / frame | MB back / frame | read-backs / frame | quality dB |{}\n\
         | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |{}\n",
        calib.panel.refresh_hz, b.frames, b.max_seconds, eye_columns.0, eye_columns.1
    );
    let table_of_quality = QualityTable::load(None)?;
    // Each `auto` case's levels: frames, mean time and switches per level.
    let mut levels_lines = String::new();
    for &network in &b.networks {
        let mut case = common.clone();
        case.dcnn.backend = BackendKind::Wgpu;
        let preprocess = match network {
            PipelineNetwork::Auto => Method::Proposed,
            PipelineNetwork::None => Method::Conventional,
            PipelineNetwork::Wiener
            | PipelineNetwork::Refine10
            | PipelineNetwork::Admm3
            | PipelineNetwork::Admm10 => Method::DoeWiener,
            PipelineNetwork::Model => Method::Proposed,
            PipelineNetwork::Half | PipelineNetwork::Full => {
                let width = if network == PipelineNetwork::Half {
                    16
                } else {
                    32
                };
                let path = b.dump.join(format!("pipeline-{}.onnx", network.name()));
                let bytes = synth::encode(&synth::unet(width, 4, 1));
                nedrt_core::util::write_atomic(&path, &bytes)
                    .map_err(|e| AppError::output(&path, e))?;
                case.dcnn.path = path;
                Method::Proposed
            }
        };
        for &path in &b.paths {
            let opts = RunOptions {
                preprocess,
                prefilter: match network {
                    PipelineNetwork::Refine10 => crate::preprocess::Prefilter::Refine(
                        10,
                        crate::preprocess::Prefilter::DEFAULT_OBJECTIVE,
                    ),
                    PipelineNetwork::Admm3 => crate::preprocess::Prefilter::Admm(
                        3,
                        crate::preprocess::Prefilter::DEFAULT_OBJECTIVE,
                    ),
                    PipelineNetwork::Admm10 => crate::preprocess::Prefilter::Admm(
                        10,
                        crate::preprocess::Prefilter::DEFAULT_OBJECTIVE,
                    ),
                    _ => crate::preprocess::Prefilter::Native,
                },
                ladder: (network == PipelineNetwork::Auto).then(LadderSpec::default),
                ladder_quality: None,
                ladder_networks: Vec::new(),
                source: SourceKind::Pattern,
                input: None,
                socket: PathBuf::from("unused.sock"),
                shm_dir: std::env::temp_dir(),
                frames: Some(b.frames),
                source_rate_hz: None,
                sink: SinkKind::Headless,
                record_dir: PathBuf::from("unused"),
                window: Default::default(),
                fallback: FallbackKind::Passthrough,
                frame_path: path,
                panel_size: Some((w, h)),
                report_json: None,
                inject_device_loss_after: None,
                stereo: b.stereo,
            };
            let (report, prepare_s) = run_case(&case, &opts, b.max_seconds)?;
            let quality_db = match &report.frame_budget {
                Some(budget) => {
                    let _ = writeln!(
                        levels_lines,
                        "- {} on the {} path: {}",
                        network.name(),
                        path.name(),
                        budget_line(budget)
                    );
                    budget.quality_delivered_db
                }
                None if matches!(network, PipelineNetwork::Half | PipelineNetwork::Full) => None,
                // No preprocessing on this display is the DOE alone (the
                // case runs `conventional`'s: the same frame, clamped).
                None if network == PipelineNetwork::None => super::run::fixed_quality(
                    &case,
                    Method::DoeOnly,
                    opts.prefilter,
                    &table_of_quality,
                )?,
                None => super::run::fixed_quality(
                    &case,
                    opts.preprocess,
                    opts.prefilter,
                    &table_of_quality,
                )?,
            };
            let stage = |name: &str| report.stages.iter().find(|s| s.stage == name).cloned();
            let e2e = stage("end-to-end");
            // The engine's own time on the device (timestamps), per frame.
            let gpu = stage("preprocess-gpu");
            let t = report.traffic_per_frame();
            // Source frames not shown. Two views submit a frame per eye and
            // each refresh composes one of each, so the slot's count of
            // replaced composites is not a count of frames lost: those are
            // the source's frames (its submissions over the views) that
            // never reached the panel.
            let views = if b.stereo { 2 } else { 1 };
            let dropped = if views > 1 {
                (report.submitted / views)
                    .saturating_sub(report.presented + report.in_flight_at_stop)
            } else {
                report.dropped_queued + report.dropped_at_present
            };
            // How far ahead of its predicted refresh the source submitted
            // (its plan: the pipeline's bound and the loop's latch).
            let ahead_ms = report.clients.first().map(|c| c.mean_lead_ms);
            let timeline = summarize(&report.frames, &report.refreshes, period_ms);
            for r in &timeline {
                let _ = writeln!(
                    why,
                    "| {} | {} | {} | {} | {:.2} | {:.2} | {:.2} | {} | {} | {} | {:.2} | {} | {} | {:.2} | {:.2} |",
                    network.name(),
                    path.name(),
                    r.frames,
                    r.count,
                    r.to_preprocess_ms,
                    r.held_ms,
                    r.preprocess_ms,
                    ms2(r.gpu_ms),
                    ms2(r.record_ms),
                    ms2(r.frame_gpu_ms),
                    r.to_ready_ms,
                    ms2(r.ready_before_take_ms),
                    ms2(r.present_ms),
                    r.first_s,
                    r.last_s
                );
            }
            let precision = case.dcnn.backend_options.precision.name();
            if let Some(dir) = &b.frame_log {
                let stereo = if b.stereo { "-stereo" } else { "" };
                let file = dir.join(format!(
                    "frames-{}-{}{stereo}-{precision}.json",
                    network.name(),
                    path.name()
                ));
                let log = json!({
                    "network": network.name(),
                    "frame_path": path.name(),
                    "views": if b.stereo { 2 } else { 1 },
                    "refresh_hz": calib.panel.refresh_hz,
                    "precision": precision,
                    // The frame budget's level names: each frame's `level`
                    // indexes them (`auto` only).
                    "levels": report.frame_budget.as_ref().map(|b| {
                        b.levels.iter().map(|l| l.name.clone()).collect::<Vec<_>>()
                    }),
                    "frames": report.frames,
                    "refreshes": report.refreshes,
                });
                let bytes = serde_json::to_vec(&log)
                    .map_err(|e| AppError::output(&file, std::io::Error::other(e)))?;
                nedrt_core::util::write_atomic(&file, &bytes)
                    .map_err(|e| AppError::output(&file, e))?;
            }
            let record = json!({
                "kind": "pipeline",
                "network": network.name(),
                "frame_path": path.name(),
                "path_detail": report.frame_path,
                "backend": report.backend,
                "width": w,
                "height": h,
                "views": views,
                "refresh_hz": calib.panel.refresh_hz,
                "precision": precision,
                "prepare_s": prepare_s,
                "presented": report.presented,
                "dropped": dropped,
                "dropped_queued": report.dropped_queued,
                "dropped_at_present": report.dropped_at_present,
                "timeline": timeline,
                "dcnn_failures": report.dcnn_failures,
                "e2e_p50_ms": e2e.as_ref().map(|s| s.p50_ms),
                "e2e_p99_ms": e2e.as_ref().map(|s| s.p99_ms),
                "e2e_max_ms": e2e.as_ref().map(|s| s.max_ms),
                "gpu_p50_ms": gpu.as_ref().map(|s| s.p50_ms),
                "to_device_mb": t.to_device_bytes / 1e6,
                "uploads": t.uploads,
                "to_host_mb": t.to_host_bytes / 1e6,
                "read_backs": t.read_backs,
                "late": report.late.count,
                "late_p50_ms": report.late.p50_ms,
                "missed_refreshes": report.missed_refreshes,
                "ahead_ms": ahead_ms,
                "shown_vs_predicted": report.shown_vs_predicted,
                "stages": stages_json(&report.stages),
                "eyes": stages_json(&report.view_stages),
                "quality_db": quality_db,
                "frame_budget": report.frame_budget,
            });
            on_record(&record);
            let ms = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.1}"));
            // Each eye's engine time, where it ran a stage ("–": no stage).
            let eyes: String = if b.stereo {
                (0..2)
                    .map(|v| {
                        let name = format!("preprocess view {v}");
                        match report.view_stages.iter().find(|s| s.stage == name) {
                            Some(s) => format!(" {:.1} |", s.p50_ms),
                            None => " – |".to_string(),
                        }
                    })
                    .collect()
            } else {
                String::new()
            };
            let _ = writeln!(
                table,
                "| {} | {} | {prepare_s:.1} | {} | {dropped} | {} | {} | {} | {} | {} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {} |{eyes}",
                network.name(),
                // "device" or "host" as it ran (a device case the engine
                // could not run on the device says "host").
                report.frame_path.split([' ', ':']).next().unwrap_or("?"),
                report.presented,
                report.late.count,
                ms(ahead_ms),
                ms(e2e.as_ref().map(|s| s.p50_ms)),
                ms(e2e.as_ref().map(|s| s.p99_ms)),
                ms(e2e.as_ref().map(|s| s.max_ms)),
                ms(gpu.as_ref().map(|s| s.p50_ms)),
                t.to_device_bytes / 1e6,
                t.uploads,
                t.to_host_bytes / 1e6,
                t.read_backs,
                quality_db.map_or("–".to_string(), |q| format!("{q:.2}"))
            );
        }
    }
    if !levels_lines.is_empty() {
        table.push_str(
            "\nThe frame budget's levels (frames, mean time, switches in, left late):\n\n",
        );
        table.push_str(&levels_lines);
    }
    table.push_str(&why);
    Ok(table)
}

/// An `auto` case's levels in one line.
fn budget_line(b: &nedrt_service::pipeline::ladder::BudgetReport) -> String {
    let levels: Vec<String> = b
        .levels
        .iter()
        .map(|l| {
            format!(
                "{} {} frames{} ({} in, {} late)",
                l.name,
                l.frames,
                l.mean_ms
                    .map_or(String::new(), |m| format!(" at {m:.2} ms")),
                l.switches_in,
                l.left_late
            )
        })
        .collect();
    let mut s = format!("budget {:.2} ms; {}", b.budget_ms, levels.join(", "));
    if !b.dropped.is_empty() {
        s += &format!(
            "; left out (no better than a faster level): {}",
            b.dropped.join(", ")
        );
    }
    s
}

/// Each stage's count and percentiles, for a record.
fn stages_json(stages: &[nedrt_service::pipeline::stats::StageReport]) -> Vec<serde_json::Value> {
    stages
        .iter()
        .map(|s| {
            json!({
                "stage": s.stage,
                "count": s.count,
                "p50_ms": s.p50_ms,
                "p99_ms": s.p99_ms,
            })
        })
        .collect()
}

/// One case, stopped `max_seconds` after it takes its first frame (the
/// preparation, PSFs and filters for the panel's size, is not counted
/// against it: on a fast GPU refine:10's is longer than its frames), and
/// the seconds it took to prepare.
fn run_case(
    common: &CommonOptions,
    opts: &RunOptions,
    max_seconds: f64,
) -> Result<(Report, f64), AppError> {
    let stop = Arc::new(AtomicBool::new(false));
    let done = Arc::new(AtomicBool::new(false));
    let control = Control {
        stop: stop.clone(),
        ..Control::default()
    };
    let started = std::time::Instant::now();
    let timer = {
        let (stop, done, serving) = (stop.clone(), done.clone(), control.serving.clone());
        std::thread::spawn(move || {
            while !done.load(Ordering::Relaxed) {
                if let Some(since) = serving.get()
                    && since.elapsed().as_secs_f64() >= max_seconds
                {
                    stop.store(true, Ordering::Relaxed);
                    return;
                }
                std::thread::sleep(Duration::from_millis(20));
            }
        })
    };
    let report = super::run::run(common, opts, &control);
    done.store(true, Ordering::Relaxed);
    let _ = timer.join();
    if stop.load(Ordering::Relaxed) {
        tracing::warn!(
            "{}: stopped {max_seconds} s after its first frame",
            opts.frame_path.name()
        );
    }
    let prepare_s = control
        .serving
        .get()
        .map_or(started.elapsed(), |t| t.duration_since(started))
        .as_secs_f64();
    Ok((report?, prepare_s))
}
