//! The last step of `nedrt run`: start the pipeline (host or resident),
//! run the source and the present loop to the end, and write the report.
//! Apart from the construction in `run` and `engines`.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use super::{AppError, RunOptions};
use nedrt_core::preprocess::Preprocess;
use nedrt_service::pipeline::pacing::Clock;
use nedrt_service::pipeline::service::{
    Control, FallbackFactory, PanelConfig, PreprocessStage, ResidentStage, Service,
};
use nedrt_service::pipeline::source::{self, Source};
use nedrt_service::pipeline::stats::Report;
use nedrt_service::present::Sink;

/// The pipeline `serve` starts.
pub(super) enum Pipeline {
    /// Frames through the host, and why.
    Host {
        primary: Box<dyn Preprocess>,
        fallback: Option<FallbackFactory>,
        reason: String,
    },
    /// Frames on the sink's device.
    Resident(Box<ResidentStage>),
    /// Two views, each its own engine, through the host.
    Views(Vec<super::views::View>),
    /// Two views on the sink's device, the host engines their fallback.
    DeviceViews(
        Box<nedrt_service::pipeline::device_views::DeviceViews>,
        Vec<super::views::View>,
    ),
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
    pipeline: Pipeline,
) -> Result<Report, AppError> {
    let (width, height, refresh_hz) = (panel.width, panel.height, panel.refresh_hz);
    let (service, what) = match pipeline {
        Pipeline::Host {
            primary,
            fallback,
            reason,
        } => {
            let what = format!("{} (frames through the host: {reason})", primary.describe());
            let service = Service::start(panel, PreprocessStage { primary, fallback }, clock);
            if let Ok(s) = &service {
                *s.stats()
                    .frame_path
                    .lock()
                    .unwrap_or_else(|p| p.into_inner()) = format!("host: {reason}");
            }
            (service, what)
        }
        Pipeline::Views(views) => {
            let what = views
                .iter()
                .map(|v| {
                    format!(
                        "{} ({}×{} at {}, {}): {}",
                        v.name,
                        v.region.width,
                        v.region.height,
                        v.region.x,
                        v.region.y,
                        v.stage.primary.describe()
                    )
                })
                .collect::<Vec<_>>()
                .join("; ");
            let stages = views.into_iter().map(|v| v.stage).collect();
            let service = Service::start_views(panel, stages, clock);
            if let Ok(s) = &service {
                *s.stats()
                    .frame_path
                    .lock()
                    .unwrap_or_else(|p| p.into_inner()) =
                    "host: two views, each its engine on the CPU".into();
            }
            (service, format!("two views, {what}"))
        }
        Pipeline::DeviceViews(device, views) => {
            let what = format!("two views, {}", device.describe());
            let host = views.into_iter().map(|v| v.stage).collect();
            (
                Service::start_device_views(panel, *device, host, clock),
                what,
            )
        }
        Pipeline::Resident(resident) => {
            let what = match &resident.host {
                Some(h) => format!(
                    "{}, then on the GPU: {}",
                    h.name,
                    resident.frames.describe()
                ),
                None => format!("on the GPU: {}", resident.frames.describe()),
            };
            (Service::start_resident(panel, *resident, clock), what)
        }
    };
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
