//! The one builder of `nedrt run` (issue 54): every view of the plan, any
//! number of them, each with the plan's levels (the frame budget's ladder,
//! or a fixed run's one level), on the sink's device where the plan puts
//! the frames and every view's levels build there, else every view on the
//! host. Fault injection and the fallback act on every view alike, and all
//! views take the same host/device decision.

use super::build::{Gpu, device_network, fallback_factory, host_network};
use super::ladder::{self, PlannedLevel, Rung};
use super::network::{RunNetwork, WienerStage};
use super::plan::{PlannedPath, RunPlan, ViewFacts};
use super::serve::Built;
use super::{AppError, CommonOptions, RunOptions};
use nedrt_command::design::Design;
use nedrt_core::preprocess::Preprocess;
use nedrt_gpu::DeviceStage;
use nedrt_optics::sim::Prepared;
use nedrt_service::pipeline::device_frames::{DeviceFrames, DeviceView};
use nedrt_service::pipeline::ladder::{DeviceLevels, HostLevels, Ladder, Selection};
use nedrt_service::pipeline::service::{
    DevicePreprocessing, FallbackFactory, HostPrep, PanelConfig, PreprocessStage, Preprocessing,
};
use nedrt_stages::FailsAfter;
use nedrt_stages::device_prefilter::prefilter_stage;

/// What the views are built from besides the options and the plan.
pub(super) struct Parts<'a> {
    pub views: &'a [ViewFacts],
    /// The run's networks, in the ladder's order (a fixed run's alone).
    pub networks: &'a [RunNetwork],
}

/// A view's options and its optics, prepared once for all its levels on
/// the device and the host.
struct ViewParts {
    common: CommonOptions,
    prepared: Option<Prepared>,
}

/// Everything one build shares among its views.
struct Build<'a> {
    opts: &'a RunOptions,
    parts: &'a Parts<'a>,
    levels: Vec<PlannedLevel>,
    views: Vec<ViewParts>,
    /// `--preprocess auto`: the levels run behind one [`Selection`].
    laddered: bool,
    selection: Selection,
}

/// Where a view's network level comes from on the host.
#[derive(Clone, Copy, PartialEq, Eq)]
enum HostNetwork {
    /// The run's backend (on the sink's GPU for wgpu where there is one).
    Primary,
    /// `--fallback`'s: the network on the CPU, or none. `behind_wiener`:
    /// whether it runs the network's Wiener stage itself (not where the
    /// host ran it before the upload).
    Fallback { behind_wiener: bool },
}

/// Builds every view of `planned`: on the device where the plan says so
/// and every view's levels build there, else on the host, and why.
pub(super) fn build(
    common: &CommonOptions,
    opts: &RunOptions,
    panel: &PanelConfig,
    device: Option<&Gpu>,
    planned: &RunPlan,
    parts: &Parts<'_>,
) -> Result<Built, AppError> {
    let levels = planned.levels.clone();
    let views = parts
        .views
        .iter()
        .map(|v| {
            let common = view_common(common, opts, v)?;
            let prepared = ladder::prepared_levels(&common, opts, &levels)?;
            Ok(ViewParts { common, prepared })
        })
        .collect::<Result<Vec<_>, AppError>>()?;
    let b = Build {
        opts,
        parts,
        levels,
        views,
        laddered: planned.ladder.is_some(),
        selection: Selection::default(),
    };
    let ladder = planned.ladder.as_ref().map(|_| Ladder {
        levels: ladder::service_levels(&b.levels),
        selection: b.selection.clone(),
    });
    let host_reason = match (device, planned.path) {
        (Some(gpu), PlannedPath::Device) => match b.on_device(panel, gpu) {
            Ok((engines, what)) => {
                return Ok(Built {
                    preprocessing: Preprocessing::Device(Box::new(engines)),
                    what,
                    host_reason: None,
                    ladder,
                });
            }
            Err(e) => {
                tracing::warn!("frames cannot stay on the GPU: {e}; they go through the host");
                e.to_string()
            }
        },
        _ => planned.path_reason.clone(),
    };
    let (stages, what) = b.on_host(device, &host_reason)?;
    Ok(Built {
        preprocessing: Preprocessing::Host(stages),
        what,
        host_reason: Some(host_reason),
        ladder,
    })
}

/// A view's options: its own design's DOE where it has one, else the
/// system's (the network's companion DOE for `proposed`).
fn view_common(
    common: &CommonOptions,
    opts: &RunOptions,
    v: &ViewFacts,
) -> Result<CommonOptions, AppError> {
    let mut c = common.clone();
    if let Some(d) = v.design.as_deref() {
        let d = Design::resolve(d)?;
        c.doe = Some(d.doe.clone());
        c.design = Some(d);
    }
    Ok(ladder::ladder_common(&c, opts.preprocess))
}

impl Build<'_> {
    fn has_network(&self) -> bool {
        self.levels
            .iter()
            .any(|l| matches!(l.rung, Rung::Network(_)))
    }

    /// The run's `n`-th network.
    fn model(&self, n: usize) -> Result<&RunNetwork, AppError> {
        self.parts
            .networks
            .get(n)
            .ok_or_else(|| AppError::Internal("a network level without its model".into()))
    }

    /// Network `n`'s Wiener stage for its fallback, where the fallback
    /// runs it itself (not where the host ran it before the upload).
    fn fallback_wiener(&self, n: usize, behind_wiener: bool) -> WienerStage {
        match behind_wiener {
            true => self.model(n).ok().and_then(RunNetwork::wiener),
            false => None,
        }
    }

    fn level_names(&self) -> String {
        self.levels
            .iter()
            .map(|l| l.name.as_str())
            .collect::<Vec<_>>()
            .join(" < ")
    }

    /// View `i`'s levels on the host, as one preprocessor (the selection's
    /// level where there are several).
    fn host_view(
        &self,
        i: usize,
        device: Option<&Gpu>,
        network: HostNetwork,
    ) -> Result<Box<dyn Preprocess>, AppError> {
        let v = &self.views[i];
        let mut make_network = |n: usize| -> Result<Box<dyn Preprocess>, AppError> {
            let model = self.model(n)?;
            match network {
                HostNetwork::Primary => host_network(&v.common, model, device),
                HostNetwork::Fallback { behind_wiener } => Ok(fallback_factory(
                    self.opts.fallback,
                    model.clone(),
                    &v.common,
                    self.fallback_wiener(n, behind_wiener),
                )()?),
            }
        };
        let mut levels = ladder::host_levels(
            v.prepared.as_ref(),
            &self.levels,
            self.opts,
            &mut make_network,
        )?;
        Ok(if self.laddered {
            Box::new(HostLevels::new(levels, self.selection.clone()))
        } else {
            levels.remove(0)
        })
    }

    /// View `i`'s fallback on the host: its levels with `--fallback`'s
    /// network (built when needed for a fixed run's network).
    fn host_fallback(&self, i: usize, behind_wiener: bool) -> Result<FallbackFactory, AppError> {
        let fallback = HostNetwork::Fallback { behind_wiener };
        if !self.laddered && self.has_network() {
            return Ok(fallback_factory(
                self.opts.fallback,
                self.model(0)?.clone(),
                &self.views[i].common,
                self.fallback_wiener(0, behind_wiener),
            ));
        }
        let levels = self.host_view(i, None, fallback)?;
        Ok(Box::new(move || Ok(levels)))
    }

    fn inject(&self, stage: Box<dyn Preprocess>) -> Box<dyn Preprocess> {
        match self.opts.inject_device_loss_after {
            Some(frames_left) => Box::new(FailsAfter::new(stage, frames_left)),
            None => stage,
        }
    }

    /// Every view on the host; a network that cannot start on the run's
    /// backend runs on `--fallback`'s instead, with a warning.
    fn on_host(
        &self,
        device: Option<&Gpu>,
        reason: &str,
    ) -> Result<(Vec<PreprocessStage>, String), AppError> {
        let mut stages = Vec::new();
        for i in 0..self.views.len() {
            let (primary, fallback) = match self.host_view(i, device, HostNetwork::Primary) {
                Ok(p) => {
                    let fallback = match self.has_network() {
                        true => Some(self.host_fallback(i, true)?),
                        false => None,
                    };
                    (p, fallback)
                }
                Err(e) if self.has_network() => {
                    let f = self.host_fallback(i, true)?()?;
                    tracing::warn!("{e}; running the D-CNN on the fallback: {}", f.describe());
                    (f, None)
                }
                Err(e) => return Err(e),
            };
            stages.push(PreprocessStage {
                primary: self.inject(primary),
                fallback,
            });
        }
        let what = match stages.as_slice() {
            [one] => format!(
                "{} (frames through the host: {reason})",
                one.primary.describe()
            ),
            _ => format!(
                "{} views, {} (frames through the host: {reason})",
                stages.len(),
                self.parts
                    .views
                    .iter()
                    .zip(&stages)
                    .map(|(v, s)| {
                        let r = v.region;
                        format!(
                            "{} ({}×{} at {}, {}): {}",
                            v.name,
                            r.width,
                            r.height,
                            r.x,
                            r.y,
                            s.primary.describe()
                        )
                    })
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
        };
        Ok((stages, what))
    }

    /// Every view's levels on the sink's device, in one [`DeviceFrames`],
    /// each view's host levels its fallback.
    fn on_device(
        &self,
        panel: &PanelConfig,
        gpu: &Gpu,
    ) -> Result<(DevicePreprocessing, String), AppError> {
        let (device, queue, _) = gpu;
        let (mut views, mut host, mut fallback) = (Vec::new(), Vec::new(), Vec::new());
        for (i, v) in self.parts.views.iter().enumerate() {
            let size = (v.region.width, v.region.height);
            let built = self.device_view(i, gpu, size)?;
            let stage = built
                .stage
                .map(|s| match self.opts.inject_device_loss_after {
                    Some(frames_left) => {
                        Box::new(FailsAfter::new(s, frames_left)) as Box<dyn DeviceStage>
                    }
                    None => s,
                });
            host.push(built.prep);
            fallback.push(built.fallback);
            views.push(DeviceView {
                region: v.region,
                stage,
            });
        }
        let frames = DeviceFrames::new(
            device,
            queue,
            (panel.width, panel.height),
            views,
            &panel.transfer,
        )?;
        let n = self.views.len();
        let what = if self.laddered {
            format!(
                "{n} view(s), the frame budget over {} on the GPU",
                self.level_names()
            )
        } else {
            let first: Vec<String> = host.iter().flatten().map(HostPrep::name).collect();
            let on_gpu = format!("on the GPU: {}", frames.describe());
            let what = match first.is_empty() {
                true => on_gpu,
                false => format!("{}, then {on_gpu}", first.join("; ")),
            };
            match n {
                1 => what,
                _ => format!("{n} views, {what}"),
            }
        };
        let engines = DevicePreprocessing {
            frames,
            host,
            fallback,
        };
        Ok((engines, what))
    }

    /// View `i`'s work on the device for frames of `size`.
    fn device_view(&self, i: usize, gpu: &Gpu, size: (usize, usize)) -> Result<OnDevice, AppError> {
        let v = &self.views[i];
        let device = &gpu.0;
        if self.laddered {
            let mut network = |n: usize| {
                let model = self.model(n)?;
                let (stage, _) = device_network(&v.common, model, gpu, size, false)?;
                Ok(stage)
            };
            let stages = ladder::device_levels(
                v.prepared.as_ref(),
                &self.levels,
                device,
                size,
                &mut network,
            )?;
            return Ok(OnDevice {
                prep: None,
                stage: Some(Box::new(DeviceLevels::new(stages, self.selection.clone()))),
                fallback: Some(self.host_fallback(i, true)?),
            });
        }
        match self.levels[0].rung {
            Rung::None => Ok(OnDevice {
                prep: None,
                stage: None,
                fallback: None,
            }),
            Rung::Network(n) => {
                let model = self.model(n)?;
                let (stage, host_wiener) = device_network(&v.common, model, gpu, size, true)?;
                // The fallback gets what the device got: the frame (it then
                // runs the network's Wiener itself), or the output of the
                // Wiener on the host where the device FFT lacks the size.
                let fallback = self.host_fallback(i, host_wiener.is_none())?;
                Ok(OnDevice {
                    prep: host_wiener.map(|w| HostPrep(Box::new(w))),
                    stage: Some(stage),
                    fallback: Some(fallback),
                })
            }
            Rung::Wiener | Rung::Refine(_) | Rung::Admm(_) => Err(AppError::Internal(
                "a ladder's level outside a ladder".into(),
            )),
            Rung::Method => {
                let opts = self.opts;
                let linear = self.host_view(i, None, HostNetwork::Primary)?;
                let prepared = v.prepared.as_ref().ok_or_else(|| {
                    AppError::Internal("a prefilter level without its optics".into())
                })?;
                let what = linear.describe();
                let stage = match prefilter_stage(
                    device,
                    opts.preprocess,
                    opts.prefilter,
                    prepared,
                    what.clone(),
                    Some(size),
                    false,
                ) {
                    Ok(stage) => stage,
                    Err(nedrt_stages::EngineError::Fft(e)) => {
                        tracing::warn!("{what} stays on the host: {e}");
                        None
                    }
                    Err(e) => return Err(e.into()),
                };
                Ok(match stage {
                    Some(stage) => OnDevice {
                        prep: None,
                        stage: Some(stage),
                        fallback: Some(Box::new(move || Ok(linear))),
                    },
                    // No device stage (`optimal`, or a size the device FFT
                    // lacks): the prefilter on the host, its planes uploaded.
                    None => OnDevice {
                        prep: Some(HostPrep(linear)),
                        stage: None,
                        fallback: None,
                    },
                })
            }
        }
    }
}

/// A view's work on the device: its host stage before the upload (where
/// the device cannot run a fixed level's prefilter or network's Wiener),
/// its device stage, and its fallback on the host.
struct OnDevice {
    prep: Option<HostPrep>,
    stage: Option<Box<dyn DeviceStage>>,
    fallback: Option<FallbackFactory>,
}
