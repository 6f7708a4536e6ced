//! The engines of `nedrt run --preprocess auto`: every level of the
//! ladder for every view, on the sink's device where the plan puts the
//! frames (each view's host ladder its fallback), else on the host; one
//! [`Selection`] for all, set by the service's frame budget. Any number of
//! views is built the same way, and fault injection and the fallback act
//! on each view alike.

use std::sync::Arc;

use super::build::{device_network, fallback_factory, host_network};
use super::ladder::{self, PlannedLevel};
use super::plan::{PlannedPath, RunPlan, ViewFacts};
use super::serve::Built;
use super::{AppError, CommonOptions, RunOptions};
use nedrt_command::design::Design;
use nedrt_core::preprocess::Preprocess;
use nedrt_engines::FailsAfter;
use nedrt_infer::ModelFile;
use nedrt_optics::sim::wiener::WienerFilter;
use nedrt_optics::sim::{Method, Prepared};
use nedrt_service::pipeline::device_frames::{DeviceFrames, DeviceView};
use nedrt_service::pipeline::ladder::{DeviceLevels, HostLevels, Ladder, Selection};
use nedrt_service::pipeline::service::{
    DeviceEngines, Engines, FallbackFactory, PanelConfig, PreprocessStage,
};

/// What the ladder's engines are built from besides the options.
pub(super) struct LadderParts<'a> {
    pub views: &'a [ViewFacts],
    pub model: Option<&'a ModelFile>,
    /// The network's Wiener stage, where its card puts one in front.
    pub wiener: &'a Option<(Method, Arc<WienerFilter>)>,
}

/// The ladder's engines, as the plan says: on the device where it puts
/// the frames and every view's levels build there, else on the host.
pub(super) fn laddered(
    common: &CommonOptions,
    opts: &RunOptions,
    panel: &PanelConfig,
    device: Option<&(wgpu::Device, wgpu::Queue, String)>,
    planned: &RunPlan,
    parts: &LadderParts<'_>,
) -> Result<Built, AppError> {
    let plan = planned
        .ladder
        .as_ref()
        .ok_or_else(|| AppError::Internal("--preprocess auto without a ladder plan".into()))?;
    let levels: Vec<PlannedLevel> = plan
        .levels
        .iter()
        .filter(|l| l.left_out.is_none())
        .cloned()
        .collect();
    let selection = Selection::default();
    let ladder = Ladder {
        levels: ladder::service_levels(&levels),
        selection: selection.clone(),
    };
    let names = levels
        .iter()
        .map(|l| l.name.as_str())
        .collect::<Vec<_>>()
        .join(" < ");
    let commons = parts
        .views
        .iter()
        .map(|v| view_common(common, opts, v))
        .collect::<Result<Vec<_>, _>>()?;
    // Each view's optics, prepared once for its device and host levels.
    let prepared = commons
        .iter()
        .map(|c| ladder::prepared_levels(c, &levels))
        .collect::<Result<Vec<_>, _>>()?;
    // Every view's host ladder: the device path's fallbacks (the network
    // on the CPU, or none with --fallback passthrough), or the host path's
    // engines (the network on the chosen backend).
    let host_ladders = |as_fallback: bool| -> Result<Vec<_>, AppError> {
        prepared
            .iter()
            .map(|p| {
                let mut network = || -> Result<Box<dyn Preprocess>, AppError> {
                    let model = parts.model.cloned().ok_or_else(|| {
                        AppError::Internal("a network level without its model".into())
                    })?;
                    if as_fallback {
                        Ok(fallback_factory(
                            opts.fallback,
                            model,
                            common,
                            parts.wiener.clone(),
                        )()?)
                    } else {
                        host_network(common, &model, parts.wiener)
                    }
                };
                ladder::host_levels(p.as_ref(), &levels, &mut network)
            })
            .collect()
    };
    let n = parts.views.len();
    let host_reason = match (device, planned.path) {
        (Some(gpu), PlannedPath::Device) => {
            match device_frames(
                opts,
                panel,
                gpu,
                parts,
                (&commons, &prepared),
                &levels,
                &selection,
            ) {
                Ok(frames) => {
                    let what = format!("{n} view(s), the frame budget over {names} on the GPU");
                    let fallback = host_ladders(true)?
                        .into_iter()
                        .map(|levels| {
                            let selection = selection.clone();
                            Some(Box::new(move || {
                                Ok(Box::new(HostLevels::new(levels, selection))
                                    as Box<dyn Preprocess>)
                            }) as FallbackFactory)
                        })
                        .collect();
                    return Ok(Built {
                        engines: Engines::Device(Box::new(DeviceEngines {
                            frames,
                            host: (0..n).map(|_| None).collect(),
                            fallback,
                        })),
                        what,
                        host_reason: None,
                        ladder: Some(ladder),
                    });
                }
                Err(e) => {
                    tracing::warn!(
                        "the ladder cannot stay on the GPU: {e}; frames go through the host"
                    );
                    e.to_string()
                }
            }
        }
        _ => planned.path_reason.clone(),
    };
    let host = host_ladders(false)?;
    let stages = host
        .into_iter()
        .map(|levels| {
            let primary: Box<dyn Preprocess> = Box::new(HostLevels::new(levels, selection.clone()));
            let primary = match opts.inject_device_loss_after {
                Some(frames_left) => Box::new(FailsAfter::new(primary, frames_left)),
                None => primary,
            };
            PreprocessStage {
                primary,
                fallback: None,
            }
        })
        .collect();
    Ok(Built {
        engines: Engines::Host(stages),
        what: format!("{n} view(s), the frame budget over {names} on the host ({host_reason})"),
        host_reason: Some(host_reason),
        ladder: Some(ladder),
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

/// Every view's levels on the sink's device, in one [`DeviceFrames`].
fn device_frames(
    opts: &RunOptions,
    panel: &PanelConfig,
    gpu: &(wgpu::Device, wgpu::Queue, String),
    parts: &LadderParts<'_>,
    (commons, prepared): (&[CommonOptions], &[Option<Prepared>]),
    levels: &[PlannedLevel],
    selection: &Selection,
) -> Result<DeviceFrames, AppError> {
    let (device, queue, _) = gpu;
    let mut views = Vec::new();
    for ((v, c), p) in parts.views.iter().zip(commons).zip(prepared) {
        let size = (v.region.width, v.region.height);
        let mut network = || -> Result<Box<dyn nedrt_gpu::DeviceStage>, AppError> {
            let model = parts
                .model
                .ok_or_else(|| AppError::Internal("a network level without its model".into()))?;
            device_network(c, model, gpu, parts.wiener, size)
        };
        let stages = ladder::device_levels(p.as_ref(), levels, device, size, &mut network)?;
        let stage: Box<dyn nedrt_gpu::DeviceStage> =
            Box::new(DeviceLevels::new(stages, selection.clone()));
        let stage = match opts.inject_device_loss_after {
            Some(frames_left) => Box::new(FailsAfter::new(stage, frames_left)),
            None => stage,
        };
        views.push(DeviceView {
            region: v.region,
            stage: Some(stage),
        });
    }
    Ok(DeviceFrames::new(
        device,
        queue,
        (panel.width, panel.height),
        views,
        &panel.transfer,
    )?)
}
