//! The parts the builder (`builder`) puts together: a network on the
//! host or on the sink's device (a D-CNN behind its Wiener stage, or an
//! unrolled model); the network's fallback; a method's optics prepared
//! for its prefilter.

use std::sync::Arc;

use super::network::{RunNetwork, optics};
use super::{AppError, CommonOptions, FallbackKind};
use nedrt_core::preprocess::{Identity, Preprocess};
use nedrt_infer::gpu::DeviceDcnn;
use nedrt_infer::{BackendKind, Dcnn};
use nedrt_optics::sim::wiener::WienerFilter;
use nedrt_optics::sim::{Method, Prepared, Simulator};
use nedrt_service::pipeline::service::FallbackFactory;
use nedrt_stages::Chain;
use nedrt_stages::device_prefilter::wiener_stage;
use nedrt_stages::preprocess::RawWiener;
use nedrt_stages::unrolled::Manifest;

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

/// The sink's device: the device, its queue and the adapter's name.
pub(super) type Gpu = (wgpu::Device, wgpu::Queue, String);

/// A network for frames on the host, behind its Wiener stage where it has
/// one: on the chosen backend, wgpu's kernels on the sink's GPU where there
/// is one that runs the precision (the frames read back), else on its own
/// GPU; tract f32 where the sink's GPU lacks f16 shaders for an f16 network.
pub(super) fn host_network(
    common: &CommonOptions,
    network: &RunNetwork,
    device: Option<&Gpu>,
) -> Result<Box<dyn Preprocess>, AppError> {
    let options = &common.dcnn.backend_options;
    let (model, stage) = match network {
        RunNetwork::Dcnn { model, wiener, .. } => (model, wiener),
        RunNetwork::Unrolled { manifest, prepared } => {
            return host_unrolled(common, manifest, optics(prepared)?, device);
        }
    };
    let f32_options = nedrt_infer::BackendOptions {
        precision: nedrt_infer::Precision::F32,
        ..options.clone()
    };
    let dcnn: Box<dyn Preprocess> = match (common.dcnn.backend, device) {
        (BackendKind::Wgpu, Some((d, q, name))) => {
            if options.precision == nedrt_infer::Precision::F32
                || d.features().contains(wgpu::Features::SHADER_F16)
            {
                Box::new(Dcnn::on_device(model.clone(), d, q, name.clone(), options)?)
            } else {
                Box::new(Dcnn::from_model(
                    model.clone(),
                    BackendKind::Cpu,
                    &f32_options,
                )?)
            }
        }
        (kind, _) => Box::new(Dcnn::from_model(model.clone(), kind, options)?),
    };
    Ok(behind(stage, dcnn))
}

/// An unrolled model on the host: its steps on the host and its
/// corrections on the run's backend; with wgpu and the sink's GPU, the
/// whole model as one device stage there (the frames read back), its
/// host twin for sizes the device FFT lacks.
fn host_unrolled(
    common: &CommonOptions,
    manifest: &Manifest,
    prepared: &Prepared,
    device: Option<&Gpu>,
) -> Result<Box<dyn Preprocess>, AppError> {
    let net = nedrt_stages::network::Network::Unrolled {
        manifest: manifest.clone(),
        kind: common.dcnn.backend,
        options: common.dcnn.backend_options.clone(),
    };
    let gpu = device.map(|(d, q, _)| (d.clone(), q.clone()));
    Ok(nedrt_stages::device_prefilter::network_on(
        net,
        gpu.as_ref(),
        manifest.method,
        prepared,
    )?)
}

/// A network's kernels on the sink's device for frames of `size`, behind
/// its Wiener stage on the device where it has one. Where that stage
/// cannot be built there (a size the device FFT lacks), `host_wiener`
/// says what to do: run the Wiener on the host before the upload (it is
/// returned, to go there), or fail.
pub(super) fn device_network(
    common: &CommonOptions,
    network: &RunNetwork,
    (device, queue, name): &Gpu,
    size: (usize, usize),
    host_wiener: bool,
) -> Result<(Box<dyn nedrt_gpu::DeviceStage>, Option<RawWiener>), AppError> {
    let (model, stage) = match network {
        RunNetwork::Dcnn { model, wiener, .. } => (model, wiener),
        RunNetwork::Unrolled { manifest, prepared } => {
            let stage = nedrt_stages::unrolled::device_stage(
                manifest,
                optics(prepared)?,
                device,
                queue,
                name,
                &common.dcnn.backend_options,
            )?;
            return Ok((Box::new(stage), None));
        }
    };
    let net: Box<dyn nedrt_gpu::DeviceStage> = Box::new(DeviceDcnn::on_device(
        model.clone(),
        device,
        queue,
        name.clone(),
        &common.dcnn.backend_options,
    )?);
    let Some((method, filter)) = stage else {
        return Ok((net, None));
    };
    let what = format!(
        "the Wiener prefilter of {method} (K = {:e}) before the clamp",
        filter.k_reg
    );
    match wiener_stage(device, what.clone(), filter.clone(), Some(size)) {
        Ok(w) => Ok((Box::new(nedrt_gpu::Chain::new(device, w, net)), None)),
        Err(e) if host_wiener => {
            tracing::warn!("{what} stays on the host: {e}");
            let raw = RawWiener {
                method: *method,
                filter: filter.clone(),
            };
            Ok((net, Some(raw)))
        }
        Err(e) => Err(e.into()),
    }
}

/// `--fallback`'s network: the same network on the CPU (tract, f32), or
/// none (a D-CNN's Wiener stage alone where it has one).
pub(super) fn fallback_factory(
    kind: FallbackKind,
    network: RunNetwork,
    common: &CommonOptions,
    stage: Option<(Method, Arc<WienerFilter>)>,
) -> FallbackFactory {
    let options = nedrt_infer::BackendOptions {
        precision: nedrt_infer::Precision::F32,
        ..common.dcnn.backend_options.clone()
    };
    let engine = |e: &dyn std::fmt::Display| nedrt_core::PreprocessError::Engine {
        engine: "cpu (tract)".into(),
        reason: e.to_string(),
    };
    match kind {
        FallbackKind::Cpu => Box::new(move || match network {
            RunNetwork::Dcnn { model, .. } => {
                let dcnn =
                    Dcnn::from_model(model, BackendKind::Cpu, &options).map_err(|e| engine(&e))?;
                Ok(behind(&stage, Box::new(dcnn)))
            }
            RunNetwork::Unrolled { manifest, prepared } => {
                let prepared = optics(&prepared).map_err(|e| engine(&e))?;
                let model = nedrt_stages::unrolled::Unrolled::load(
                    manifest,
                    prepared,
                    BackendKind::Cpu,
                    &options,
                )
                .map_err(|e| engine(&e))?;
                Ok(Box::new(model) as Box<dyn Preprocess>)
            }
        }),
        // Without the network a Wiener-stage system still shows its Wiener.
        FallbackKind::Passthrough => Box::new(move || Ok(behind(&stage, Box::new(Identity)))),
    }
}

/// `method`'s optics prepared for `prefilter` (its Wiener; the headline
/// depths for the least-squares family).
pub(super) fn prepared_for(
    common: &CommonOptions,
    method: Method,
    prefilter: nedrt_stages::preprocess::Prefilter,
) -> Result<nedrt_optics::sim::Prepared, AppError> {
    let sim = common.measured(Simulator::new(
        common.calibration()?,
        common.doe_path_for(&[method]).as_deref(),
        common.cache(),
    )?)?;
    Ok(sim.prepare(
        &[method],
        &prefilter.depths_d(&sim.calib),
        common.progress(),
    )?)
}
