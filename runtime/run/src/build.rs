//! The engines `nedrt run` builds: the D-CNN's fallback, the linear
//! prefilters on the host, and one view's device engines with its host
//! part and fallback. Apart from `run` so that the wiring reads as
//! one sequence of choices and the construction details live here.

use std::sync::Arc;

use super::{AppError, CommonOptions, FallbackKind, RunOptions};
use nedrt_core::preprocess::{Identity, Preprocess};
use nedrt_engines::device_prefilter::{prefilter_stage, wiener_stage};
use nedrt_engines::preprocess::RawWiener;
use nedrt_engines::{Chain, FailsAfter};
use nedrt_infer::gpu::DeviceDcnn;
use nedrt_infer::{BackendKind, Dcnn, ModelFile};
use nedrt_optics::sim::wiener::WienerFilter;
use nedrt_optics::sim::{Method, Simulator};
use nedrt_service::pipeline::device_frames::DeviceFrames;
use nedrt_service::pipeline::service::{DeviceEngines, FallbackFactory, HostPrep, PanelConfig};

/// `network` behind its Wiener stage where the model has one.
pub(super) fn behind(
    stage: &Option<(Method, Arc<WienerFilter>)>,
    network: Box<dyn Preprocess>,
) -> Box<dyn Preprocess> {
    match stage {
        Some((method, filter)) => Box::new(Chain::behind_wiener(*method, filter.clone(), network)),
        None => network,
    }
}

/// A network on the host, f32 (the CPU engines offer no f16), on the
/// chosen backend (tract where that is wgpu), behind its Wiener stage where
/// it has one: a view's engine on the host.
pub(super) fn host_network(
    common: &CommonOptions,
    model: &ModelFile,
    stage: &Option<(Method, Arc<WienerFilter>)>,
) -> Result<Box<dyn Preprocess>, AppError> {
    let kind = match common.dcnn.backend {
        BackendKind::Wgpu => BackendKind::Cpu,
        other => other,
    };
    let options = nedrt_infer::BackendOptions {
        precision: nedrt_infer::Precision::F32,
        ..common.dcnn.backend_options.clone()
    };
    let dcnn = Dcnn::from_model(model.clone(), kind, &options)?;
    Ok(behind(stage, Box::new(dcnn)))
}

/// A network's kernels on the sink's device for frames of `size`, behind
/// its Wiener stage on the device where it has one.
pub(super) fn device_network(
    common: &CommonOptions,
    model: &ModelFile,
    (device, queue, name): &(wgpu::Device, wgpu::Queue, String),
    stage: &Option<(Method, Arc<WienerFilter>)>,
    size: (usize, usize),
) -> Result<Box<dyn nedrt_gpu::DeviceStage>, AppError> {
    let net: Box<dyn nedrt_gpu::DeviceStage> = Box::new(DeviceDcnn::on_device(
        model.clone(),
        device,
        queue,
        name.clone(),
        &common.dcnn.backend_options,
    )?);
    Ok(match stage {
        Some((method, filter)) => {
            let what = format!(
                "the Wiener prefilter of {method} (K = {:e}) before the clamp",
                filter.k_reg
            );
            let w = wiener_stage(device, what, filter.clone(), Some(size))?;
            Box::new(nedrt_gpu::Chain::new(device, w, net))
        }
        None => net,
    })
}

pub(super) fn fallback_factory(
    kind: FallbackKind,
    model: ModelFile,
    common: &CommonOptions,
    stage: Option<(Method, Arc<WienerFilter>)>,
) -> FallbackFactory {
    let options = nedrt_infer::BackendOptions {
        precision: nedrt_infer::Precision::F32,
        ..common.dcnn.backend_options.clone()
    };
    match kind {
        FallbackKind::Cpu => Box::new(move || {
            let dcnn = Dcnn::from_model(model, BackendKind::Cpu, &options).map_err(|e| {
                nedrt_core::PreprocessError::Engine {
                    engine: "cpu (tract)".into(),
                    reason: e.to_string(),
                }
            })?;
            Ok(behind(&stage, Box::new(dcnn)))
        }),
        // Without the network a Wiener-stage system still shows its Wiener.
        FallbackKind::Passthrough => Box::new(move || Ok(behind(&stage, Box::new(Identity)))),
    }
}

/// The preprocessing of a method without a network: its Wiener prefilter
/// (the PSFs it averages come from the cache after the first run), none,
/// or a least-squares prefilter on its optics.
pub(super) fn linear_preprocessor(
    common: &CommonOptions,
    method: Method,
    prefilter: nedrt_engines::preprocess::Prefilter,
) -> Result<Box<dyn Preprocess>, AppError> {
    if !method.uses_wiener() && prefilter.is_native() {
        return Ok(Box::new(Identity));
    }
    let prepared = prepared_for(common, method, prefilter)?;
    let mut dcnns = std::collections::HashMap::new();
    Ok(nedrt_engines::preprocess::for_system(
        method, prefilter, &prepared, &mut dcnns,
    )?)
}

/// `method`'s optics prepared for `prefilter` (its Wiener; the headline
/// depths for the least-squares family).
pub(super) fn prepared_for(
    common: &CommonOptions,
    method: Method,
    prefilter: nedrt_engines::preprocess::Prefilter,
) -> Result<nedrt_optics::sim::Prepared, AppError> {
    let sim = Simulator::new(
        common.calibration()?,
        common.doe_path_for(&[method]).as_deref(),
        common.cache(),
    )?;
    Ok(sim.prepare(
        &[method],
        &prefilter.depths_d(&sim.calib),
        common.progress(),
    )?)
}

/// One view's engines on the sink's device `d`: the network's
/// kernels behind its Wiener stage (on the device, where the device FFT
/// takes the panel's size; else on the host first), or no network and the
/// method's linear prefilter (its Wiener, or `lsq`) on the device, or the
/// least-squares solvers on the host, or nothing.
pub(super) fn device_engines(
    common: &CommonOptions,
    opts: &RunOptions,
    panel: &PanelConfig,
    (device, queue, name): &(wgpu::Device, wgpu::Queue, String),
    model: Option<ModelFile>,
    stage: &Option<(Method, Arc<WienerFilter>)>,
) -> Result<DeviceEngines, AppError> {
    let (host, network, fallback) = match model {
        Some(model) => {
            let net: Box<dyn nedrt_gpu::DeviceStage> = Box::new(DeviceDcnn::on_device(
                model.clone(),
                device,
                queue,
                name.clone(),
                &common.dcnn.backend_options,
            )?);
            let mut host = None;
            let mut on_device_stage = None;
            let net = match stage {
                Some((method, filter)) => {
                    let what = format!(
                        "the Wiener prefilter of {method} (K = {:e}) before the clamp",
                        filter.k_reg
                    );
                    match wiener_stage(
                        device,
                        what.clone(),
                        filter.clone(),
                        Some((panel.width, panel.height)),
                    ) {
                        Ok(w) => {
                            on_device_stage = stage.clone();
                            Box::new(nedrt_gpu::Chain::new(device, w, net))
                                as Box<dyn nedrt_gpu::DeviceStage>
                        }
                        Err(e) => {
                            tracing::warn!("{what} stays on the host: {e}");
                            host = Some(HostPrep(Box::new(RawWiener {
                                method: *method,
                                filter: filter.clone(),
                            })));
                            net
                        }
                    }
                }
                None => net,
            };
            let net = match opts.inject_device_loss_after {
                Some(frames_left) => Box::new(FailsAfter::new(net, frames_left)),
                None => net,
            };
            // The fallback gets what the device got: the frame (the Wiener
            // then runs in the fallback too), or the host stage's output.
            let fallback = fallback_factory(opts.fallback, model, common, on_device_stage);
            (host, Some(net), Some(fallback))
        }
        None if !opts.preprocess.uses_wiener() && opts.prefilter.is_native() => (None, None, None),
        None => match linear_on_device(common, opts, panel, device)? {
            (Some(stage), linear) => (
                None,
                Some(stage),
                Some(Box::new(move || Ok(linear)) as FallbackFactory),
            ),
            (None, linear) => (Some(HostPrep(linear)), None, None),
        },
    };
    let frames = DeviceFrames::single(
        device,
        queue,
        (panel.width, panel.height),
        &panel.transfer,
        network,
    )?;
    Ok(DeviceEngines::single(frames, host, fallback))
}

/// A prefilter's device stage, if the device runs it, and the same on the host.
pub(super) type DeviceAndHost = (Option<Box<dyn nedrt_gpu::DeviceStage>>, Box<dyn Preprocess>);

/// The method's prefilter on the host, and as a device stage where the
/// device runs it ([`nedrt_engines::device_prefilter::prefilter_stage`]; a size the
/// device FFT lacks stays on the host, with a warning). The host one is the
/// device stage's fallback, or the host stage.
pub(super) fn linear_on_device(
    common: &CommonOptions,
    opts: &RunOptions,
    panel: &PanelConfig,
    device: &wgpu::Device,
) -> Result<DeviceAndHost, AppError> {
    let method = opts.preprocess;
    let prepared = prepared_for(common, method, opts.prefilter)?;
    let host = nedrt_engines::preprocess::for_system(
        method,
        opts.prefilter,
        &prepared,
        &mut std::collections::HashMap::new(),
    )?;
    let what = host.describe();
    let size = Some((panel.width, panel.height));
    match prefilter_stage(
        device,
        method,
        opts.prefilter,
        &prepared,
        what.clone(),
        size,
    ) {
        Ok(stage) => Ok((stage, host)),
        Err(nedrt_engines::EngineError::Fft(e)) => {
            tracing::warn!("{what} stays on the host: {e}");
            Ok((None, host))
        }
        Err(e) => Err(e.into()),
    }
}
