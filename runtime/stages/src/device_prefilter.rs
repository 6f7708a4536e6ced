//! The prefilters on the device (docs/gpu-fft.md): nedrt-gpu's stages (the
//! DCT filter, the refinement) fed with the gains and terms nedrt-optics
//! computes for each frame size. `nedrt run` keeps their frames on the
//! device; `nedrt sim` and `nedrt eval` with `--backend wgpu` run them
//! through [`OnDevice`], which uploads a frame and reads its display image
//! back, so the tables can be made on a GPU with the CPU's results.

use std::collections::HashMap;
use std::sync::Arc;

use crate::Network;
use nedrt_core::preprocess::{HostTraffic, PreprocessError, check_frame};
use nedrt_core::{Image, Preprocess};
use nedrt_gpu::DeviceStage;
use nedrt_gpu::fft::{FftError, GainsFor, SpectralStage};
use nedrt_gpu::refine::{RefineStage, RefineTerms, TermsFor};
use nedrt_gpu::split::{SplitStage, SplitTerms, SplitTermsFor};
use nedrt_optics::sim::optimal::SplitSchedule;
use nedrt_optics::sim::wiener::WienerFilter;
use nedrt_optics::sim::{DisplayProblem, Method, Prepared};

use crate::EngineError;
use crate::preprocess::{DcnnInput, Prefilter, RawWiener};

/// A linear prefilter's gains as a device stage, prepared for a
/// `width`×`height` frame now where given (gains computed and uploaded:
/// an error, such as a side with a prime factor the device FFT lacks,
/// shows before the first frame).
pub fn spectral_stage(
    device: &wgpu::Device,
    what: String,
    gains_for: GainsFor,
    size: Option<(usize, usize)>,
) -> Result<Box<dyn DeviceStage>, FftError> {
    let mut stage = SpectralStage::new(device, what, gains_for)?;
    if let Some((w, h)) = size {
        stage.filter(w, h)?;
    }
    Ok(Box::new(stage))
}

/// A Wiener filter on the device ([`spectral_stage`]).
pub fn wiener_stage(
    device: &wgpu::Device,
    what: String,
    filter: Arc<WienerFilter>,
    size: Option<(usize, usize)>,
) -> Result<Box<dyn DeviceStage>, FftError> {
    let gains_for: GainsFor =
        Box::new(move |w, h| filter.plan(w, h).dct_gains().map_err(Into::into));
    spectral_stage(device, what, gains_for, size)
}

/// The `lsq` prefilter of `problem` on the device.
pub fn lsq_stage(
    device: &wgpu::Device,
    what: String,
    problem: Arc<DisplayProblem>,
    size: Option<(usize, usize)>,
) -> Result<Box<dyn DeviceStage>, FftError> {
    let gains_for: GainsFor =
        Box::new(move |w, h| problem.linear_dct_gains(w, h).map_err(Into::into));
    spectral_stage(device, what, gains_for, size)
}

/// `refine:K` of `problem` on the device; `warm`: a still frame goes on
/// from the last frame's steps, as [`nedrt_optics::sim::SolvedPrefilter::warm_started`]
/// does on the host.
pub fn refine_stage(
    device: &wgpu::Device,
    what: String,
    problem: Arc<DisplayProblem>,
    steps: usize,
    size: Option<(usize, usize)>,
    warm: bool,
) -> Result<Box<dyn DeviceStage>, FftError> {
    let terms_for: TermsFor = Box::new(move |w, h| {
        let t = problem.device_terms(w, h)?;
        Ok(RefineTerms {
            linear: t.linear,
            adjoint_target: t.adjoint_target,
            normal: t.normal,
            step: t.step,
        })
    });
    let mut stage = RefineStage::new(device, what, steps, terms_for)?;
    if warm {
        let still_rms = nedrt_optics::sim::SolvedPrefilter::STILL_RMS as f32;
        stage = stage.warm_started(still_rms)?;
    }
    if let Some((w, h)) = size {
        stage.prepare(w, h)?;
    }
    Ok(Box::new(stage))
}

/// `admm:K` of `problem` on the device (the shipped schedule, whose
/// penalty is constant); `warm`: a still frame goes on from the last
/// frame's steps, as on the host.
pub fn split_stage(
    device: &wgpu::Device,
    what: String,
    problem: Arc<DisplayProblem>,
    steps: usize,
    size: Option<(usize, usize)>,
    warm: bool,
) -> Result<Box<dyn DeviceStage>, FftError> {
    let terms_for: SplitTermsFor = Box::new(move |w, h| {
        let t = problem.device_split_terms(w, h, &SplitSchedule::SHIPPED)?;
        Ok(SplitTerms {
            linear: t.linear,
            data: t.data,
            penalty: t.penalty,
            relaxation: t.relaxation,
        })
    });
    let mut stage = SplitStage::new(device, what, steps, terms_for)?;
    if warm {
        let still_rms = nedrt_optics::sim::SolvedPrefilter::STILL_RMS as f32;
        stage = stage.warm_started(still_rms)?;
    }
    if let Some((w, h)) = size {
        stage.prepare(w, h)?;
    }
    Ok(Box::new(stage))
}

/// Whether the device runs `method`'s `prefilter`: its Wiener, `lsq`,
/// `refine:K` and `admm:K` (not `optimal`, whose stopping rule reads its objective
/// back, nor a method without a prefilter; a network's Wiener front end
/// is its own case).
pub fn runs_on_device(method: Method, prefilter: Prefilter) -> bool {
    match prefilter {
        Prefilter::Native => method.uses_wiener(),
        Prefilter::Lsq(_) | Prefilter::Refine(..) | Prefilter::Admm(..) => true,
        Prefilter::Optimal(_) => false,
    }
}

/// `method`'s `prefilter` as a device stage named `what`, prepared for
/// `size` where given; `None` where the device does not run it
/// ([`runs_on_device`]). `warm`: `refine:K` and `admm:K` go on over still
/// frames (the ladder's levels). A size the device FFT lacks is
/// `EngineError::Fft`.
pub fn prefilter_stage(
    device: &wgpu::Device,
    method: Method,
    prefilter: Prefilter,
    prepared: &Prepared,
    what: String,
    size: Option<(usize, usize)>,
    warm: bool,
) -> Result<Option<Box<dyn DeviceStage>>, EngineError> {
    if !runs_on_device(method, prefilter) {
        return Ok(None);
    }
    Ok(Some(match prefilter {
        Prefilter::Lsq(o) => lsq_stage(
            device,
            what,
            Arc::new(prepared.display_problem(method, o)?),
            size,
        )?,
        Prefilter::Refine(k, o) => refine_stage(
            device,
            what,
            Arc::new(prepared.display_problem(method, o)?),
            k,
            size,
            warm,
        )?,
        Prefilter::Admm(k, o) => {
            let problem = prepared.display_problem(method, o)?;
            if !problem.has_split() {
                return Ok(None);
            }
            split_stage(device, what, Arc::new(problem), k, size, warm)?
        }
        _ => match prepared.wiener_shared(method) {
            Some(filter) => wiener_stage(device, what, filter, size)?,
            None => return Ok(None),
        },
    }))
}

/// A device stage as a host [`Preprocess`]: each frame uploaded, the
/// stage recorded, its output read back (clamped to the panel's range
/// unless `raw`). Buffers are made once per frame size.
pub struct OnDevice {
    device: wgpu::Device,
    queue: wgpu::Queue,
    stage: Box<dyn DeviceStage>,
    raw: bool,
    buffers: Option<(usize, usize, [wgpu::Buffer; 3])>,
    traffic: HostTraffic,
    /// The same preprocessing on the host, for frame sizes the device FFT
    /// lacks (a side with a prime factor above 13): used with a warning.
    host: Box<dyn Preprocess>,
    warned: bool,
}

impl std::fmt::Debug for OnDevice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.stage.describe())
    }
}

impl OnDevice {
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        stage: Box<dyn DeviceStage>,
        raw: bool,
        host: Box<dyn Preprocess>,
    ) -> Self {
        Self {
            device: device.clone(),
            queue: queue.clone(),
            stage,
            raw,
            buffers: None,
            traffic: HostTraffic::default(),
            host,
            warned: false,
        }
    }

    fn engine(&self, reason: impl std::fmt::Display) -> PreprocessError {
        PreprocessError::Engine {
            engine: self.stage.describe(),
            reason: reason.to_string(),
        }
    }
}

impl Preprocess for OnDevice {
    fn describe(&self) -> String {
        if self.warned {
            // The last frames' sizes sent it to the host.
            format!(
                "{} (the device FFT lacked the frame's size)",
                self.host.describe()
            )
        } else {
            self.stage.describe()
        }
    }

    fn run(&mut self, input: &Image) -> Result<Image, PreprocessError> {
        check_frame(input, 3)?;
        let (w, h) = (input.width, input.height);
        if let Err(e) = nedrt_gpu::fft::radices(w).and_then(|_| nedrt_gpu::fft::radices(h)) {
            if !self.warned {
                tracing::warn!(
                    "{}: {e}; a {w}×{h} frame runs on the host: {}",
                    self.stage.describe(),
                    self.host.describe()
                );
                self.warned = true;
            }
            self.traffic = HostTraffic::default();
            return self.host.run(input);
        }
        let bytes = (input.data().len() * 4) as u64;
        if !matches!(&self.buffers, Some((bw, bh, _)) if (*bw, *bh) == (w, h)) {
            let make = |label, usage| {
                self.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size: bytes,
                    usage,
                    mapped_at_creation: false,
                })
            };
            use wgpu::BufferUsages as U;
            self.buffers = Some((
                w,
                h,
                [
                    make("prefilter input", U::STORAGE | U::COPY_DST),
                    make("prefilter output", U::STORAGE | U::COPY_SRC),
                    make("prefilter read-back", U::MAP_READ | U::COPY_DST),
                ],
            ));
        }
        let Some((_, _, [src, dst, back])) = &self.buffers else {
            return Err(self.engine("no buffers"));
        };
        let (src, dst, back) = (src.clone(), dst.clone(), back.clone());
        self.queue
            .write_buffer(&src, 0, bytemuck::cast_slice(input.data()));
        let mut enc = self.device.create_command_encoder(&Default::default());
        self.stage
            .record(&mut enc, &src, &dst, w, h)
            .map_err(|e| self.engine(e))?;
        enc.copy_buffer_to_buffer(&dst, 0, &back, 0, bytes);
        self.queue.submit([enc.finish()]);
        nedrt_gpu::map_and_wait(&self.device, &back).map_err(|e| self.engine(e))?;
        let data = nedrt_gpu::read_mapped(&back, |b| bytemuck::cast_slice::<u8, f32>(b).to_vec())
            .map_err(|e| self.engine(e))?;
        self.traffic = HostTraffic {
            to_device_bytes: bytes,
            uploads: 1,
            to_host_bytes: bytes,
            read_backs: 1,
        };
        let out = Image::rgb(w, h, data);
        Ok(if self.raw { out } else { out.clamped() })
    }

    fn last_traffic(&self) -> HostTraffic {
        self.traffic
    }
}

/// The GPU a command's prefilters run on (`--backend wgpu`).
pub type Gpu = (wgpu::Device, wgpu::Queue);

/// Whether any of `methods` with any of `prefilters` has work for a
/// device (a network, or a prefilter the device runs).
pub fn wants_gpu(methods: &[Method], prefilters: &[Prefilter]) -> bool {
    methods
        .iter()
        .any(|&m| m.uses_dcnn() || prefilters.iter().any(|&p| runs_on_device(m, p)))
}

/// `network` as [`Network::into_preprocess`] builds it, with an unrolled model on wgpu as
/// one device stage on `gpu` (its host twin for frame sizes the device
/// FFT lacks), each frame uploaded and its display image read back;
/// at f16 on a device opened without f16 shaders, as the host runs it
/// (its networks on a device of their own).
pub fn network_on(
    network: Network,
    gpu: Option<&Gpu>,
    method: Method,
    prepared: &Prepared,
) -> Result<Box<dyn Preprocess>, EngineError> {
    match (network, gpu) {
        (
            Network::Unrolled {
                manifest,
                kind: nedrt_infer::BackendKind::Wgpu,
                options,
            },
            Some((device, queue)),
        ) if options.precision == nedrt_infer::Precision::F32
            || device.features().contains(wgpu::Features::SHADER_F16) =>
        {
            let host = crate::unrolled::Unrolled::load(
                manifest,
                prepared,
                nedrt_infer::BackendKind::Wgpu,
                &options,
            )?;
            let stage = host.device_stage(device, queue, "the frame's device", &options)?;
            Ok(Box::new(OnDevice::new(
                device,
                queue,
                Box::new(stage),
                false,
                Box::new(host),
            )))
        }
        (network, _) => network.into_preprocess(method, prepared),
    }
}

/// [`crate::preprocess::for_system`] with the prefilter on `gpu` where the
/// device has it (the Wiener, `lsq`, `refine:K`, and the Wiener in front of
/// a network); `optimal` and the methods without a prefilter run as on
/// the host.
pub fn for_system_on(
    gpu: Option<&Gpu>,
    method: Method,
    prefilter: Prefilter,
    prepared: &Prepared,
    dcnns: &mut HashMap<Method, Network>,
) -> Result<Box<dyn Preprocess>, EngineError> {
    let Some((device, queue)) = gpu else {
        return crate::preprocess::for_system(method, prefilter, prepared, dcnns);
    };
    if method.uses_dcnn() && prefilter.is_native() {
        let dcnn = match dcnns.remove(&method) {
            Some(Network::Dcnn(d)) => d,
            // On wgpu its steps and corrections as one device stage.
            Some(unrolled) => return network_on(unrolled, gpu, method, prepared),
            None => {
                return Err(EngineError::Unavailable(format!(
                    "no D-CNN loaded for {method}"
                )));
            }
        };
        return Ok(match crate::preprocess::dcnn_input(&dcnn.model.path)? {
            DcnnInput::Frame => Box::new(dcnn),
            DcnnInput::WienerRaw { k_reg } => {
                let filter = Arc::new(prepared.wiener_filter(method, k_reg)?);
                let what =
                    format!("the Wiener prefilter of {method} (K = {k_reg:e}) before the clamp");
                let raw = Box::new(RawWiener {
                    method,
                    filter: filter.clone(),
                });
                let stage = wiener_stage(device, what, filter, None)?;
                Box::new(crate::Chain::new(
                    Box::new(OnDevice::new(device, queue, stage, true, raw)),
                    Box::new(dcnn),
                ))
            }
        });
    }
    let host = crate::preprocess::for_system(method, prefilter, prepared, dcnns)?;
    let what = host.describe();
    Ok(
        match prefilter_stage(device, method, prefilter, prepared, what, None, false)? {
            Some(stage) => Box::new(OnDevice::new(device, queue, stage, false, host)),
            None => host,
        },
    )
}
