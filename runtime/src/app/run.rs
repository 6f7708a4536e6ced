//! `nedrt run`: the real-time service. Builds the sink (first: a window
//! must live on this thread, and its GPU is offered to the D-CNN), the
//! D-CNN with its fallback, the pipeline and the source, presents until the
//! source ends or a signal stops it, then reports the counts and latencies.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use super::{AppError, CommonOptions};
use crate::inference::gpu::open_device;
use crate::inference::{BackendKind, Dcnn, ModelFile};
use crate::pipeline::pacing::{Clock, SystemClock};
use crate::pipeline::service::{
    Control, DcnnStage, FallbackFactory, PanelConfig, PassThrough, Preprocessor, Service,
};
use crate::pipeline::source::{
    self, Source, dir::DirSource, pattern::PatternSource, socket::SocketSource,
};
use crate::pipeline::stats::Report;
use crate::present::Sink;
use crate::present::headless::HeadlessSink;
use crate::present::recorder::RecorderSink;
use crate::present::transfer::Transfer;
use crate::present::window::{WindowOptions, WindowSink};

/// Where frames come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SourceKind {
    /// The synthetic moving test pattern.
    Pattern,
    /// Images from --input (a folder or one file), in name order, looping.
    Dir,
    /// Applications over the Unix-socket protocol (docs/protocol.md).
    Socket,
}

/// Where frames go.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SinkKind {
    /// A window (fullscreen with --fullscreen) with a vsync'd wgpu surface.
    Window,
    /// An off-screen wgpu target of the panel's size.
    Headless,
    /// A PNG sequence in --record-dir.
    Record,
}

/// What replaces the D-CNN backend when it cannot start or fails.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum FallbackKind {
    /// The same network on the CPU (tract).
    Cpu,
    /// No preprocessing: the frame as submitted.
    Passthrough,
}

/// Slowest and fastest paced source rates `--source-rate` takes (Hz).
pub const MIN_SOURCE_RATE_HZ: f64 = 0.01;
pub const MAX_SOURCE_RATE_HZ: f64 = 10_000.0;

/// Options of `nedrt run`.
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub source: SourceKind,
    pub input: Option<PathBuf>,
    pub socket: PathBuf,
    pub shm_dir: PathBuf,
    /// Frames the pattern or folder source submits (`None`: pattern until
    /// stopped, folder once through).
    pub frames: Option<u64>,
    /// Submission rate of the pattern and folder sources (`None`: the panel's refresh; 0: unpaced).
    pub source_rate_hz: Option<f64>,
    pub sink: SinkKind,
    pub record_dir: PathBuf,
    pub window: WindowOptions,
    pub fallback: FallbackKind,
    pub report_json: Option<PathBuf>,
}

fn fallback_factory(
    kind: FallbackKind,
    model: ModelFile,
    common: &CommonOptions,
) -> FallbackFactory {
    let options = crate::inference::BackendOptions {
        precision: crate::inference::Precision::F32,
        ..common.dcnn.backend_options.clone()
    };
    match kind {
        FallbackKind::Cpu => Box::new(move || {
            Ok(
                Box::new(Dcnn::from_model(model, BackendKind::Cpu, &options)?)
                    as Box<dyn Preprocessor>,
            )
        }),
        FallbackKind::Passthrough => {
            Box::new(|| Ok(Box::new(PassThrough) as Box<dyn Preprocessor>))
        }
    }
}

/// Runs the service until its source ends (and the last frame is shown)
/// or `control.stop` is set.
pub fn run(
    common: &CommonOptions,
    opts: &RunOptions,
    control: &Control,
) -> Result<Report, AppError> {
    // 0 is "as fast as the pipeline takes them"; anything else must give a
    // period a clock can wait (NaN, inf or 1e-300 Hz would run unpaced).
    if let Some(rate_hz) = opts.source_rate_hz
        && !(rate_hz == 0.0 || (MIN_SOURCE_RATE_HZ..=MAX_SOURCE_RATE_HZ).contains(&rate_hz))
    {
        return Err(AppError::Usage(format!(
            "--source-rate {rate_hz}: give 0 (unpaced) or a rate from {MIN_SOURCE_RATE_HZ} \
             to {MAX_SOURCE_RATE_HZ} Hz"
        )));
    }
    let calib = common.calibration()?;
    let p = &calib.panel;
    let panel = PanelConfig {
        width: p.width_px,
        height: p.height_px,
        refresh_hz: p.refresh_hz,
        transfer: Transfer::from_panel(p),
    };
    let (w, h) = (panel.width as u32, panel.height as u32);
    // Output folders are checked before anything runs, not after.
    if let Some(dir) = opts
        .report_json
        .as_deref()
        .and_then(std::path::Path::parent)
        && !dir.as_os_str().is_empty()
    {
        std::fs::create_dir_all(dir).map_err(|e| AppError::output(dir, e))?;
    }
    let clock: Arc<dyn Clock> = Arc::new(SystemClock);
    let rate_hz = opts.source_rate_hz.unwrap_or(panel.refresh_hz);
    // Sources first: a bad input is reported before any window opens.
    let source: Box<dyn Source> = match opts.source {
        SourceKind::Pattern => Box::new(PatternSource::new(
            panel.width,
            panel.height,
            opts.frames,
            rate_hz,
            clock.clone(),
        )),
        SourceKind::Dir => {
            let input = opts.input.as_ref().ok_or_else(|| {
                AppError::Usage("--source dir needs --input FOLDER_OR_IMAGE".into())
            })?;
            Box::new(DirSource::load(
                input,
                panel.width,
                panel.height,
                opts.frames,
                rate_hz,
                clock.clone(),
            )?)
        }
        SourceKind::Socket => Box::new(SocketSource::bind(&opts.socket, &opts.shm_dir)?),
    };

    let dcnn = &common.dcnn;
    let model = ModelFile::read(&dcnn.path)?;
    let precision = dcnn.backend_options.precision;
    // The sink, and a GPU for the D-CNN to share with it.
    let (mut sink, device): (Box<dyn Sink>, _) = match opts.sink {
        SinkKind::Window => {
            let s = WindowSink::open(w, h, opts.window.clone())?;
            let device = s.device();
            (Box::new(s), Some(device))
        }
        SinkKind::Headless => {
            let (adapter, device, queue) = open_device(precision)?;
            let name = adapter.get_info().name;
            let s = HeadlessSink::new(&device, &queue, name.clone(), w, h)?;
            (Box::new(s), Some((device, queue, name)))
        }
        SinkKind::Record => (Box::new(RecorderSink::new(&opts.record_dir)?), None),
    };
    let primary: Result<Box<dyn Preprocessor>, _> = match (dcnn.backend, &device) {
        (BackendKind::Wgpu, Some((d, q, name)))
            if precision == crate::inference::Precision::F32
                || d.features().contains(wgpu::Features::SHADER_F16) =>
        {
            Dcnn::on_device(model.clone(), d, q, name.clone(), precision)
                .map(|x| Box::new(x) as Box<dyn Preprocessor>)
        }
        (kind, _) => Dcnn::from_model(model.clone(), kind, &dcnn.backend_options)
            .map(|x| Box::new(x) as Box<dyn Preprocessor>),
    };
    let mut fallback = Some(fallback_factory(opts.fallback, model, common));
    let primary = match primary {
        Ok(p) => p,
        Err(e) => {
            let Some(factory) = fallback.take() else {
                return Err(e.into());
            };
            let f = factory()?;
            tracing::warn!("{e}; running the D-CNN on the fallback: {}", f.describe());
            f
        }
    };
    tracing::info!(
        "panel {w}×{h} at {} Hz; source: {}; D-CNN: {}; sink: {}",
        panel.refresh_hz,
        source.describe(),
        primary.describe(),
        sink.describe()
    );
    let mut service = Service::start(panel, DcnnStage { primary, fallback }, clock)
        .map_err(|e| AppError::Usage(format!("cannot start the pipeline threads: {e}")))?;
    let sources_stop = Arc::new(AtomicBool::new(false));
    let compositor = service
        .compositor()
        .ok_or_else(|| AppError::Usage("the pipeline is closed".into()))?;
    let source_thread = source::spawn(source, compositor, sources_stop.clone())
        .map_err(|e| AppError::Usage(format!("cannot start the source thread: {e}")))?;
    service.close_ingest();

    let presented = service.present_loop(sink.as_mut(), control);
    // However the loop ended: stop the source, drain the stages, flush the sink.
    sources_stop.store(true, Ordering::Relaxed);
    let source_result = source_thread.join();
    let report = service.shutdown();
    let finished = sink.finish();
    presented?;
    finished?;
    match source_result {
        Ok(Ok(n)) => tracing::debug!("source submitted {n} frames"),
        Ok(Err(e)) => return Err(e.into()),
        Err(_) => return Err(AppError::Usage("the source thread panicked".into())),
    }
    if let Some(path) = &opts.report_json {
        let json = serde_json::to_string_pretty(&report).map_err(|e| AppError::output(path, e))?;
        crate::util::write_atomic(path, json.as_bytes()).map_err(|e| AppError::output(path, e))?;
    }
    Ok(report)
}
