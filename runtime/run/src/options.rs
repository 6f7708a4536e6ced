//! The options of `nedrt run`: where frames come from and go, the D-CNN's
//! fallback, the frame path, and [`RunOptions`] itself. Apart from the
//! wiring so that the CLI and the studies read them without the pipeline.

use std::path::PathBuf;

use nedrt_core::Named;
use nedrt_optics::sim::Method;
use nedrt_service::present::window::WindowOptions;

/// Where frames come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceKind {
    /// The synthetic moving test pattern.
    Pattern,
    /// Images from --input (a folder or one file), in name order, looping.
    Dir,
    /// Applications over the Unix-socket protocol (docs/protocol.md).
    Socket,
}

impl Named for SourceKind {
    const ALL: &'static [Self] = &[SourceKind::Pattern, SourceKind::Dir, SourceKind::Socket];
    fn name(self) -> &'static str {
        match self {
            SourceKind::Pattern => "pattern",
            SourceKind::Dir => "dir",
            SourceKind::Socket => "socket",
        }
    }
    fn help(self) -> &'static str {
        match self {
            SourceKind::Pattern => "the synthetic moving test pattern",
            SourceKind::Dir => "images from --input (a folder or one file), in name order, looping",
            SourceKind::Socket => "applications over the Unix-socket protocol (docs/protocol.md)",
        }
    }
}

/// Where frames go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SinkKind {
    /// A window (fullscreen with --fullscreen) with a vsync'd wgpu surface.
    Window,
    /// An off-screen wgpu target of the panel's size.
    Headless,
    /// A PNG sequence in --record-dir.
    Record,
}

impl Named for SinkKind {
    const ALL: &'static [Self] = &[SinkKind::Window, SinkKind::Headless, SinkKind::Record];
    fn name(self) -> &'static str {
        match self {
            SinkKind::Window => "window",
            SinkKind::Headless => "headless",
            SinkKind::Record => "record",
        }
    }
    fn help(self) -> &'static str {
        match self {
            SinkKind::Window => {
                "a window (fullscreen with --fullscreen) with a vsync'd wgpu surface"
            }
            SinkKind::Headless => "an off-screen wgpu target of the panel's size",
            SinkKind::Record => "a PNG sequence in --record-dir",
        }
    }
}

/// What replaces the D-CNN backend when it cannot start or fails.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FallbackKind {
    /// The same network on the CPU (tract).
    Cpu,
    /// No network: the frame as submitted, or, for a network behind a
    /// Wiener stage, that Wiener prefilter alone (clamped).
    Passthrough,
}

impl Named for FallbackKind {
    const ALL: &'static [Self] = &[FallbackKind::Cpu, FallbackKind::Passthrough];
    fn name(self) -> &'static str {
        match self {
            FallbackKind::Cpu => "cpu",
            FallbackKind::Passthrough => "passthrough",
        }
    }
    fn help(self) -> &'static str {
        match self {
            FallbackKind::Cpu => "the same network on the CPU (tract)",
            FallbackKind::Passthrough => {
                "no network: the frame as submitted (or the model's Wiener stage alone, clamped)"
            }
        }
    }
}

/// Where frames go between the client and the panel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FramePath {
    /// On the sink's GPU from the upload to the panel, where the sink and
    /// the engine allow; else the host.
    #[default]
    Device,
    /// Decoded, preprocessed and encoded on the host; the sink uploads the
    /// codes (the path before the resident one, for comparison).
    Host,
}

impl Named for FramePath {
    const ALL: &'static [Self] = &[FramePath::Device, FramePath::Host];
    fn name(self) -> &'static str {
        match self {
            FramePath::Device => "device",
            FramePath::Host => "host",
        }
    }
    fn help(self) -> &'static str {
        match self {
            FramePath::Device => {
                "frames stay on the sink's GPU (window or headless sink; wgpu backend or no \
                 network), else the host"
            }
            FramePath::Host => "decode, preprocess and encode on the host; the sink uploads codes",
        }
    }
}

/// Slowest and fastest paced source rates `--source-rate` takes (Hz).
pub const MIN_SOURCE_RATE_HZ: f64 = 0.01;
pub const MAX_SOURCE_RATE_HZ: f64 = 10_000.0;

/// Options of `nedrt run`.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// The preprocessing on the panel: a method's (its D-CNN, its Wiener
    /// prefilter, or none).
    pub preprocess: Method,
    /// Or a least-squares prefilter on that method's optics (not `native`).
    pub prefilter: nedrt_stages::preprocess::Prefilter,
    /// `--preprocess auto[:LO..HI]`: the frame budget picks each frame's
    /// level from the ladder (`preprocess` names the system whose network
    /// and DOE the levels use).
    pub ladder: Option<crate::ladder::LadderSpec>,
    /// The tradeoff table the ladder's quality comes from (default
    /// [`crate::ladder::DEFAULT_QUALITY_TABLE`] where it exists).
    pub ladder_quality: Option<PathBuf>,
    /// More network levels of the ladder (D-CNNs or unrolled models, as
    /// `--dcnn` takes them), cheapest first, between admm:10 and the
    /// system's own network.
    pub ladder_networks: Vec<PathBuf>,
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
    pub frame_path: FramePath,
    /// The panel's size instead of the calibration's (benchmarks on slow
    /// adapters).
    pub panel_size: Option<(usize, usize)>,
    pub report_json: Option<PathBuf>,
    /// Fault injection: the D-CNN backend fails, as a lost GPU makes it
    /// fail, from this frame on (0: the first).
    pub inject_device_loss_after: Option<u64>,
    /// Two views (a headset's eyes): the calibration's `[[view]]` tables,
    /// or the panel's halves with the run's own system. A calibration with
    /// views runs them whether or not this is set.
    pub stereo: bool,
}
