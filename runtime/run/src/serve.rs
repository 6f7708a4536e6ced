//! The last step of `nedrt run`: start the pipeline with the
//! preprocessing built for it (host or device, any number of views), run
//! the source and the present loop to the end, and write the report. Apart
//! from the construction in `run` and `builder`.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use super::{AppError, RunOptions};
use nedrt_service::pipeline::ladder::Ladder;
use nedrt_service::pipeline::pacing::Clock;
use nedrt_service::pipeline::service::{Control, PanelConfig, Preprocessing, Service};
use nedrt_service::pipeline::source::{self, Source};
use nedrt_service::pipeline::stats::Report;
use nedrt_service::present::Sink;

/// The preprocessing `serve` starts the pipeline with, what they are (for the
/// log), and why frames go through the host when they do.
pub(super) struct Built {
    pub preprocessing: Preprocessing,
    pub what: String,
    pub host_reason: Option<String>,
    /// `--preprocess auto`: the ladder the views' levels follow.
    pub ladder: Option<Ladder>,
}

/// Starts the pipeline with its preprocessing, runs it to the end and
/// writes the report.
pub(super) fn serve(
    opts: &RunOptions,
    control: &Control,
    panel: PanelConfig,
    clock: Arc<dyn Clock>,
    source: Box<dyn Source>,
    mut sink: Box<dyn Sink>,
    built: Built,
) -> Result<Report, AppError> {
    let (width, height, refresh_hz) = (panel.width, panel.height, panel.refresh_hz);
    let Built {
        preprocessing,
        what,
        host_reason,
        ladder,
    } = built;
    let service = Service::start(panel, preprocessing, ladder, clock);
    if let (Ok(s), Some(reason)) = (&service, host_reason) {
        *s.stats()
            .frame_path
            .lock()
            .unwrap_or_else(|p| p.into_inner()) = format!("host: {reason}");
    }
    tracing::info!(
        "panel {width}×{height} at {refresh_hz} Hz; source: {}; preprocess: {what}; sink: {}",
        source.describe(),
        sink.describe()
    );
    let mut service = service
        .map_err(|e| AppError::thread("the pipeline threads", format!("could not start: {e}")))?;
    let sources_stop = Arc::new(AtomicBool::new(false));
    let compositor = service
        .compositor()
        .ok_or_else(|| AppError::Internal("the pipeline is closed".into()))?;
    let source_thread = source::spawn(source, compositor, sources_stop.clone())
        .map_err(|e| AppError::thread("the source thread", format!("could not start: {e}")))?;
    service.close_ingest();
    let _ = control.serving.set(std::time::Instant::now());

    let presented = service.present_loop(sink.as_mut(), control);
    // However the loop ended: stop the source, drain the stages, flush the sink.
    sources_stop.store(true, Ordering::Relaxed);
    let source_result = source_thread.join();
    let mut report = service.shutdown();
    let finished = sink.finish();
    report.lost_by_sink = sink.lost_frames();
    // The report and its JSON are written on every exit path that can
    // write them: a failed sink (a recorder whose disk filled or folder
    // vanished) is when the counts matter most.
    if let Some(path) = &opts.report_json {
        let json = serde_json::to_string_pretty(&report).map_err(|e| AppError::output(path, e))?;
        nedrt_core::util::write_atomic(path, json.as_bytes())
            .map_err(|e| AppError::output(path, e))?;
    }
    let failed = presented
        .err()
        .or(finished.err())
        .map(AppError::from)
        .or(match source_result {
            Ok(Ok(n)) => {
                tracing::debug!("source submitted {n} frames");
                None
            }
            Ok(Err(e)) => Some(e.into()),
            Err(_) => Some(AppError::thread("the source thread", "panicked")),
        });
    if let Some(e) = failed {
        control.progress.note(&report.table());
        return Err(e);
    }
    Ok(report)
}
