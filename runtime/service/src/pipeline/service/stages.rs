//! What the preprocess stage runs: a view's preprocessing with its
//! fallback, a host stage before the device, the device path's engines,
//! and the switch to the fallback when an engine fails.

use super::{DeviceFrames, Stage, Stats};
use nedrt_core::Image;
use nedrt_core::preprocess::{Identity, Preprocess, PreprocessError};

/// Builds the preprocessor to switch to when the primary one fails.
pub type FallbackFactory = Box<dyn FnOnce() -> Result<Box<dyn Preprocess>, PreprocessError> + Send>;

/// The D-CNN stage's engines: the primary, and what replaces it if it
/// fails (a lost GPU): the factory's preprocessor, else none ([`Identity`]).
pub struct PreprocessStage {
    pub primary: Box<dyn Preprocess>,
    pub fallback: Option<FallbackFactory>,
}

impl std::fmt::Debug for PreprocessStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PreprocessStage")
            .field("primary", &self.primary)
            .field("fallback", &self.fallback.is_some())
            .finish()
    }
}

impl PreprocessStage {
    /// Runs the frame; on a backend failure logs it, switches to the
    /// fallback for good and runs the frame there.
    pub(super) fn run(&mut self, frame: &Image, stats: &Stats) -> Option<Image> {
        let out = self.run_uncounted(frame, stats)?;
        stats.dcnn_traffic.record(self.primary.last_traffic());
        Some(out)
    }

    /// As [`PreprocessStage::run`], leaving the frame's traffic to the caller
    /// (two views: one record for both eyes' runs).
    pub(super) fn run_uncounted(&mut self, frame: &Image, stats: &Stats) -> Option<Image> {
        loop {
            match self.primary.run(frame) {
                Ok(out) => {
                    if let Some(ns) = self.primary.last_gpu_ns() {
                        stats.record(Stage::PreprocessGpu, ns);
                    }
                    return Some(out);
                }
                Err(PreprocessError::Frame(e)) => {
                    // Validated at submit, so this is a bug, not the client's fault.
                    tracing::error!("D-CNN refused a validated frame: {e}");
                    stats
                        .failed
                        .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    return None;
                }
                Err(e) => {
                    let failed = format!("D-CNN {}", self.primary.describe());
                    self.primary =
                        switch_to_fallback(self.fallback.take(), &failed, &e.to_string(), stats);
                }
            }
        }
    }
}

/// The fallback's preprocessor: the factory's, else [`Identity`] (also
/// when the factory cannot start it, which is logged).
pub(super) fn fallback_preprocessor(fallback: Option<FallbackFactory>) -> Box<dyn Preprocess> {
    match fallback.map(|factory| factory()) {
        Some(Ok(p)) => p,
        Some(Err(fe)) => {
            tracing::error!("fallback backend cannot start: {fe}");
            Box::new(Identity)
        }
        None => Box::new(Identity),
    }
}

/// After a failure of the engine `failed` (`reason`): counts it and
/// returns the fallback's preprocessor, logged and named in the report's
/// backend.
pub(super) fn switch_to_fallback(
    fallback: Option<FallbackFactory>,
    failed: &str,
    reason: &str,
    stats: &Stats,
) -> Box<dyn Preprocess> {
    stats
        .dcnn_failures
        .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let next = fallback_preprocessor(fallback);
    tracing::error!(
        "{failed} failed: {reason}; falling back to {}",
        next.describe()
    );
    *stats.backend.lock().unwrap_or_else(|p| p.into_inner()) =
        format!("{} (after a failure of {failed})", next.describe());
    next
}

/// Host work on a decoded frame before it goes to the device: a
/// network's Wiener stage where the device FFT lacks the panel's size, or
/// a linear prefilter with no device stage. Its output is uploaded as the
/// frame's planes.
#[derive(Debug)]
pub struct HostPrep(pub Box<dyn Preprocess>);

impl HostPrep {
    pub fn name(&self) -> String {
        self.0.describe()
    }
}

/// The device path's preprocessing: the device side of every view, and for
/// each view its host stage before the upload (none: the frame goes up as
/// the client sent it) and the host preprocessing to switch to if the
/// device fails (it gets what the device got: the frame, or the host
/// stage's output; none: [`Identity`]).
pub struct DevicePreprocessing {
    pub frames: DeviceFrames,
    pub host: Vec<Option<HostPrep>>,
    pub fallback: Vec<Option<FallbackFactory>>,
}

impl DevicePreprocessing {
    /// One view's engines (the whole panel, or a view of it).
    pub fn single(
        frames: DeviceFrames,
        host: Option<HostPrep>,
        fallback: Option<FallbackFactory>,
    ) -> Self {
        Self {
            frames,
            host: vec![host],
            fallback: vec![fallback],
        }
    }
}

impl std::fmt::Debug for DevicePreprocessing {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DevicePreprocessing")
            .field("host", &self.host)
            .field("frames", &self.frames)
            .field(
                "fallback",
                &self
                    .fallback
                    .iter()
                    .map(Option::is_some)
                    .collect::<Vec<_>>(),
            )
            .finish()
    }
}

/// The preprocessing of a service: every view's on the host, or every
/// view's on the sink's device. A panel without views is one view.
#[derive(Debug)]
pub enum Preprocessing {
    Host(Vec<PreprocessStage>),
    Device(Box<DevicePreprocessing>),
}

impl Preprocessing {
    /// One view on the host.
    pub fn host(stage: PreprocessStage) -> Self {
        Self::Host(vec![stage])
    }

    /// The number of views the engines are for.
    pub fn views(&self) -> usize {
        match self {
            Self::Host(stages) => stages.len(),
            Self::Device(d) => d.frames.views(),
        }
    }
}
