//! `nedrt run` with two views (a headset's eyes, issue 33): each eye its
//! region of the panel and its own preprocessing, built from its design
//! (`[[view]]` in the calibration; without tables, the panel's halves and
//! the run's own system). The service runs them as it runs one view: on
//! the sink's device where every eye's stage can be built there, else on
//! the host.

use std::sync::Arc;

use super::build::{device_network, host_network, linear_on_device, linear_preprocessor};
use super::plan::ViewFacts;
use super::serve::Built;
use super::{AppError, CommonOptions, RunOptions};
use nedrt_command::design::Design;
use nedrt_core::calib::Calibration;
use nedrt_core::preprocess::Preprocess;
use nedrt_infer::{BackendKind, ModelFile};
use nedrt_optics::sim::Method;
use nedrt_optics::sim::wiener::WienerFilter;
use nedrt_service::compose::ViewRegion;
use nedrt_service::pipeline::device_frames::{DeviceFrames, DeviceView};
use nedrt_service::pipeline::service::{
    DeviceEngines, Engines, FallbackFactory, PanelConfig, PreprocessStage,
};

/// A view of the run: its name, region and preprocessing (on the host),
/// and its design's options (for its stage on the device).
pub(super) struct View {
    pub name: String,
    pub region: ViewRegion,
    pub stage: PreprocessStage,
    pub common: CommonOptions,
}

/// The engines of the views: on the sink's device where the plan puts the
/// frames and every view's stage is built there (each view's host engine
/// its fallback), else each view's engine on the host, and why.
pub(super) fn engines(
    views: Vec<View>,
    opts: &RunOptions,
    panel: &PanelConfig,
    device: Option<&(wgpu::Device, wgpu::Queue, String)>,
    planned: &super::RunPlan,
    model: Option<&ModelFile>,
    wiener: &Option<(Method, Arc<WienerFilter>)>,
) -> Built {
    let on_device = match (device, planned.path) {
        (Some(gpu), super::PlannedPath::Device) => {
            device_stages(&views, opts, panel, gpu, model, wiener).and_then(|stages| {
                let (d, q, _) = gpu;
                let views = views
                    .iter()
                    .zip(stages)
                    .map(|(v, stage)| DeviceView {
                        region: v.region,
                        stage,
                    })
                    .collect();
                DeviceFrames::new(d, q, (panel.width, panel.height), views, &panel.transfer)
                    .map_err(|e| e.to_string())
            })
        }
        _ => Err(planned.path_reason.clone()),
    };
    let n = views.len();
    match on_device {
        Ok(frames) => {
            let what = format!("{n} views, {}", frames.describe());
            let fallback = views
                .into_iter()
                .map(|v| {
                    let primary = v.stage.primary;
                    Some(Box::new(move || Ok(primary)) as FallbackFactory)
                })
                .collect();
            Built {
                engines: Engines::Device(Box::new(DeviceEngines {
                    frames,
                    host: (0..n).map(|_| None).collect(),
                    fallback,
                })),
                what,
                host_reason: None,
                ladder: None,
            }
        }
        Err(why) => {
            tracing::info!("the views run on the host: {why}");
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
            Built {
                engines: Engines::Host(views.into_iter().map(|v| v.stage).collect()),
                what: format!("{n} views, {what}"),
                host_reason: Some(format!("{n} views, each its engine on the CPU: {why}")),
                ladder: None,
            }
        }
    }
}

/// Each view's stage on the sink's device: its D-CNN (on the wgpu
/// backend) behind its Wiener stage where the model has one, or its
/// prefilter, or none; `Err` says why the views stay on the host.
fn device_stages(
    views: &[View],
    opts: &RunOptions,
    panel: &PanelConfig,
    gpu: &(wgpu::Device, wgpu::Queue, String),
    model: Option<&ModelFile>,
    wiener: &Option<(Method, Arc<WienerFilter>)>,
) -> Result<Vec<Option<Box<dyn nedrt_gpu::DeviceStage>>>, String> {
    let device = &gpu.0;
    let mut stages = Vec::new();
    if let Some(model) = model {
        if views[0].common.dcnn.backend != BackendKind::Wgpu {
            return Err(format!(
                "the D-CNN runs on the {} backend, on the host",
                views[0].common.dcnn.backend.name()
            ));
        }
        for v in views {
            let size = (v.region.width, v.region.height);
            let stage = device_network(&v.common, model, gpu, wiener, size)
                .map_err(|e| format!("view {:?}: {e}", v.name))?;
            stages.push(Some(stage));
        }
        return Ok(stages);
    }
    for v in views {
        if !opts.preprocess.uses_wiener() && opts.prefilter.is_native() {
            stages.push(None);
            continue;
        }
        let view_panel = PanelConfig {
            width: v.region.width,
            height: v.region.height,
            views: Vec::new(),
            ..panel.clone()
        };
        match linear_on_device(&v.common, opts, &view_panel, device) {
            Ok((Some(stage), _)) => stages.push(Some(stage)),
            Ok((None, host)) => {
                return Err(format!(
                    "view {:?}: {} stays on the host",
                    v.name,
                    host.describe()
                ));
            }
            Err(e) => return Err(format!("view {:?}: {e}", v.name)),
        }
    }
    Ok(stages)
}

/// The views of `calib` (or the halves of a `width`×`height` panel), each
/// with its engine. A view's design sets its DOE and Wiener K; the D-CNN
/// methods run the network co-designed with its own DOE, so a view's design
/// there is refused rather than ignored.
pub(super) fn views(
    common: &CommonOptions,
    opts: &RunOptions,
    calib: &Calibration,
    (width, height): (usize, usize),
    wiener_stage: &Option<(Method, Arc<WienerFilter>)>,
    model: Option<&ModelFile>,
) -> Result<Vec<View>, AppError> {
    let layout = layout(calib, (width, height))?;
    let mut out = Vec::new();
    for super::plan::ViewFacts {
        name,
        region,
        design,
    } in layout
    {
        let mut c = common.clone();
        if let Some(d) = design.as_deref().filter(|_| model.is_none()) {
            let d = Design::resolve(d)?;
            c.doe = Some(d.doe.clone());
            c.design = Some(d);
        }
        let primary: Box<dyn Preprocess> = match (model, design.as_deref()) {
            (Some(_), Some(d)) => {
                return Err(AppError::Conflict(format!(
                    "view {name:?}: design {d:?} with --preprocess {}: a D-CNN runs on the DOE it \
                     was trained with; a view's design needs a method without a network \
                     (doe+wiener, doe-only)",
                    opts.preprocess
                )));
            }
            // Each eye its own engine on the host (tract, or ORT when chosen).
            (Some(model), None) => host_network(common, model, wiener_stage)?,
            (None, _) => linear_preprocessor(&c, opts.preprocess, opts.prefilter)?,
        };
        out.push(View {
            name,
            region,
            stage: PreprocessStage {
                primary,
                fallback: None,
            },
            common: c,
        });
    }
    Ok(out)
}

/// The views of `calib`, or the halves of a `width`×`height` panel when it
/// has none (`--stereo`), each checked to fit the panel this run drives.
pub(super) fn layout(
    calib: &Calibration,
    (width, height): (usize, usize),
) -> Result<Vec<ViewFacts>, AppError> {
    let min = nedrt_core::calib::views::MIN_VIEW_SIDE_PX;
    let layout: Vec<ViewFacts> = if calib.views.is_empty() {
        if width / 2 < min || height < min {
            return Err(AppError::Conflict(format!(
                "--stereo on a {width}×{height} panel: each eye would be {}×{height}; a view is \
                 at least {min} pixels a side",
                width / 2
            )));
        }
        let [left, right] = ViewRegion::side_by_side(width, height);
        vec![
            ViewFacts {
                name: "left".into(),
                region: left,
                design: None,
            },
            ViewFacts {
                name: "right".into(),
                region: right,
                design: None,
            },
        ]
    } else {
        // The calibration checked its views against its own panel; the run
        // may drive another size (--panel in the benchmarks).
        for v in &calib.views {
            let [x, y, w, h] = v.region_px;
            let region = ViewRegion {
                x,
                y,
                width: w,
                height: h,
            };
            if !region.fits((width, height)) {
                return Err(AppError::Conflict(format!(
                    "{}: view {:?} ({w}×{h} at ({x}, {y})) is not inside the {width}×{height} \
                     panel this run drives",
                    calib.source, v.name
                )));
            }
        }
        calib
            .views
            .iter()
            .map(|v| {
                let [x, y, w, h] = v.region_px;
                let region = ViewRegion {
                    x,
                    y,
                    width: w,
                    height: h,
                };
                ViewFacts {
                    name: v.name.clone(),
                    region,
                    design: v.design.clone(),
                }
            })
            .collect()
    };
    Ok(layout)
}
