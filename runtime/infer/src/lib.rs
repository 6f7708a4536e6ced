//! The D-CNN at run time: one ONNX file, read, checked and lowered once
//! ([`model_file`], to the layers of [`network`]), run by any of three
//! backends behind [`Backend`]: `cpu` (tract, pure Rust, always built in),
//! `ort` (ONNX Runtime loaded from a shared library at run time) and `wgpu`
//! (WGSL kernels generated from the graph, [`gpu`]). [`Dcnn`] adds what
//! every backend shares: reflection padding to the network's multiple,
//! cropping back, and the clamp to the panel's [0, 1].

pub mod content;
pub mod gpu;
mod lower;
/// The ONNX metadata key that says whether a network's output is a display
/// image (clamped) or a signed correction.
pub use lower::OUTPUT_KEY;
pub mod model_file;
pub mod network;
pub mod ort_backend;
pub mod reference;
pub mod synth;
pub mod tract_backend;

use std::path::{Path, PathBuf};

pub use model_file::ModelFile;
pub use network::Network;

use nedrt_core::preprocess::{HostTraffic, Preprocess, PreprocessError, check_frame};
use nedrt_core::{Image, Named};

/// Errors of loading or running the D-CNN.
#[derive(Debug, thiserror::Error)]
pub enum InferenceError {
    #[error("cannot read model {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("model {path}: {reason}")]
    Model { path: PathBuf, reason: String },
    #[error("{backend} backend: {reason}")]
    Backend {
        backend: &'static str,
        reason: String,
    },
    #[error("frame: {0}")]
    Frame(String),
    /// The frame's activations do not fit the adapter's largest binding,
    /// even in bands: a smaller frame or half precision needs less.
    #[error("wgpu backend: {0}")]
    FrameTooLarge(String),
    /// The requested ONNX Runtime execution provider is not in the loaded
    /// library.
    #[error(
        "ort backend: the {provider} execution provider is not available in {library} \
         ({reason}); use an ONNX Runtime build with it (ORT_DYLIB_PATH)"
    )]
    ProviderMissing {
        provider: String,
        library: PathBuf,
        reason: String,
    },
    #[error("wgpu backend: {0}")]
    Gpu(#[from] nedrt_gpu::GpuError),
    /// A tuning table (`tuning/*.toml`) that cannot be read or used.
    #[error("tuning table {path}: {reason}")]
    Tuning { path: PathBuf, reason: String },
    #[error(
        "{engine}: the network's output holds {count} non-finite values (NaN or ±inf) for a \
         {width}×{height} frame"
    )]
    NonFinite {
        engine: String,
        count: usize,
        width: usize,
        height: usize,
    },
}

/// Which engine runs the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BackendKind {
    /// tract, pure Rust, built in.
    Cpu,
    /// ONNX Runtime, loaded from a shared library at run time.
    Ort,
    /// Generated WGSL compute kernels on any wgpu adapter.
    Wgpu,
}

impl Named for BackendKind {
    const ALL: &'static [Self] = &[BackendKind::Cpu, BackendKind::Ort, BackendKind::Wgpu];
    fn name(self) -> &'static str {
        match self {
            BackendKind::Cpu => "cpu",
            BackendKind::Ort => "ort",
            BackendKind::Wgpu => "wgpu",
        }
    }
    fn help(self) -> &'static str {
        match self {
            BackendKind::Cpu => "tract, pure Rust, built in",
            BackendKind::Ort => {
                "ONNX Runtime, loaded from ORT_DYLIB_PATH or the onnxruntime Python package"
            }
            BackendKind::Wgpu => "generated WGSL compute kernels on any wgpu adapter",
        }
    }
}

impl BackendKind {
    pub fn name(self) -> &'static str {
        Named::name(self)
    }

    /// The precisions the backend offers (f16 on wgpu only).
    pub fn precisions(self) -> &'static [Precision] {
        match self {
            BackendKind::Wgpu => &[Precision::F32, Precision::F16],
            BackendKind::Cpu | BackendKind::Ort => &[Precision::F32],
        }
    }
}

/// Arithmetic precision of the GPU backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Precision {
    #[default]
    F32,
    /// Half-precision storage (weights and activations), f32 accumulation;
    /// needs the adapter's `shader-f16`.
    F16,
}

impl Named for Precision {
    const ALL: &'static [Self] = &[Precision::F32, Precision::F16];
    fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F16 => "f16",
        }
    }
    fn help(self) -> &'static str {
        match self {
            Precision::F32 => "f32 storage and arithmetic",
            Precision::F16 => {
                "f16 storage, f32 accumulation; needs the adapter's shader-f16 (wgpu only)"
            }
        }
    }
}

/// One layer's device time on one frame, with what it computes and moves
/// (`nedrt bench inference --per-layer`).
#[derive(Debug, Clone, PartialEq)]
pub struct LayerTiming {
    /// Index into the lowered network's layers.
    pub layer: usize,
    /// "conv 3×3 + relu", "max pool 2×2", …
    pub kind: String,
    /// Output channels, height, width.
    pub output: [usize; 3],
    /// Multiply-adds.
    pub macs: u64,
    /// Activations read and written and weights read, at their storage
    /// precision: the least memory traffic the layer can have.
    pub bytes: u64,
    pub gpu_ns: u64,
    /// Whether the layer ran on cooperative matrices (the tensor cores or
    /// matrix units), so that its floor is the matrix rate's, not the
    /// general cores'.
    pub tensor_cores: bool,
}

/// An engine that runs the lowered network on frames whose sides are
/// multiples of the network's multiple.
pub trait Backend: Send + std::fmt::Debug {
    /// What runs it, for reports: "cpu (tract)", "wgpu f16 on <adapter>".
    fn describe(&self) -> String;
    /// Runs the network; the result may or may not be clamped.
    fn run(&mut self, frame: &Image) -> Result<Image, InferenceError>;
    /// The device's own time for the last run (GPU timestamp queries), where
    /// the device can measure it.
    fn last_gpu_ns(&self) -> Option<u64> {
        None
    }
    /// Host↔device traffic of the last run (none for a host engine).
    fn last_traffic(&self) -> HostTraffic {
        HostTraffic::default()
    }
    /// Each layer's device time on `frame` (engines with timestamp queries).
    fn layer_timings(&mut self, _frame: &Image) -> Result<Vec<LayerTiming>, InferenceError> {
        Err(InferenceError::Backend {
            backend: "per-layer",
            reason: format!("{} cannot time single layers (wgpu can)", self.describe()),
        })
    }
    /// Which kernel each convolution runs on and why (wgpu: tiled or
    /// cooperative matrix); empty for engines without a choice.
    fn conv_paths(&self) -> Vec<String> {
        Vec::new()
    }
}

/// ONNX Runtime execution provider of the `ort` backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum OrtProvider {
    #[default]
    Cpu,
    /// Needs an ONNX Runtime build with CUDA (the onnxruntime-gpu wheel).
    Cuda,
    /// Needs an ONNX Runtime build with TensorRT.
    Tensorrt,
}

impl Named for OrtProvider {
    const ALL: &'static [Self] = &[OrtProvider::Cpu, OrtProvider::Cuda, OrtProvider::Tensorrt];
    fn name(self) -> &'static str {
        match self {
            OrtProvider::Cpu => "cpu",
            OrtProvider::Cuda => "cuda",
            OrtProvider::Tensorrt => "tensorrt",
        }
    }
    fn help(self) -> &'static str {
        match self {
            OrtProvider::Cpu => "ONNX Runtime's CPU provider",
            OrtProvider::Cuda => {
                "needs an ONNX Runtime build with CUDA (the onnxruntime-gpu wheel)"
            }
            OrtProvider::Tensorrt => "needs an ONNX Runtime build with TensorRT",
        }
    }
}

/// The ONNX Runtime shared library for the `ort` backend, as the caller
/// found it (the binary's rule is in its settings), or why there is none.
#[derive(Debug, Clone)]
pub enum OrtLibrary {
    Found(PathBuf),
    Missing(String),
}

impl Default for OrtLibrary {
    fn default() -> Self {
        OrtLibrary::Missing("no ONNX Runtime library was given".into())
    }
}

/// Which convolution kernels the wgpu backend may run (docs/inference.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ConvPath {
    /// The tensor cores (cooperative matrices) for the layers whose shape
    /// the adapter lists, at f16; the register-tiled kernels elsewhere.
    #[default]
    Auto,
    /// The register-tiled kernels for every layer.
    Tiled,
}

impl Named for ConvPath {
    const ALL: &'static [Self] = &[ConvPath::Auto, ConvPath::Tiled];
    fn name(self) -> &'static str {
        match self {
            ConvPath::Auto => "auto",
            ConvPath::Tiled => "tiled",
        }
    }
    fn help(self) -> &'static str {
        match self {
            ConvPath::Auto => {
                "cooperative matrices (tensor cores) where the adapter lists their f16 shape, \
                 register-tiled kernels elsewhere"
            }
            ConvPath::Tiled => "the register-tiled kernels for every layer",
        }
    }
}

/// How the wgpu backend's register-tiled kernels sum at `--precision f16`
/// (docs/inference.md): the storage is f16 either way.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum F16Math {
    /// f16 FMAs on a GPU other than NVIDIA's, f32 on NVIDIA's (faster on
    /// the H200) and on a CPU adapter (lavapipe converts every f16
    /// operation): `gpu::f16_arithmetic_by_default`.
    #[default]
    Auto,
    /// f16 FMAs (into f32 accumulators) on every adapter.
    F16,
    /// f32 FMAs on f16 storage on every adapter (on the H200, 2026-11-27,
    /// the f16 FMAs ran the tiled kernels 1.2–1.3× slower than this).
    F32,
}

impl Named for F16Math {
    const ALL: &'static [Self] = &[F16Math::Auto, F16Math::F16, F16Math::F32];
    fn name(self) -> &'static str {
        match self {
            F16Math::Auto => "auto",
            F16Math::F16 => "f16",
            F16Math::F32 => "f32",
        }
    }
    fn help(self) -> &'static str {
        match self {
            F16Math::Auto => {
                "f16 arithmetic on a GPU other than NVIDIA's, f32 on NVIDIA's and on a CPU adapter"
            }
            F16Math::F16 => "f16 arithmetic (f32 accumulators) on every adapter",
            F16Math::F32 => "f32 arithmetic on f16 storage on every adapter",
        }
    }
}

/// Options for building a backend.
#[derive(Debug, Clone, Default)]
pub struct BackendOptions {
    /// Threads for CPU engines (0: the engine's default).
    pub threads: usize,
    pub precision: Precision,
    pub ort_provider: OrtProvider,
    pub ort_library: OrtLibrary,
    /// How the wgpu backend opens its device.
    pub gpu: nedrt_gpu::GpuSettings,
    /// Which convolution kernels the wgpu backend may use.
    pub conv_path: ConvPath,
    /// How its tiled kernels sum at f16.
    pub f16_math: F16Math,
    /// The wgpu backend's tuned conv tiles (docs/tuning.md); None: heuristics.
    pub tuning_dir: Option<PathBuf>,
}

/// The D-CNN ready to preprocess frames of any size.
#[derive(Debug)]
pub struct Dcnn {
    pub model: ModelFile,
    pub network: Network,
    backend: Box<dyn Backend>,
}

impl Dcnn {
    /// Reads, validates and prepares `path` for `kind`.
    pub fn load(
        path: &Path,
        kind: BackendKind,
        options: &BackendOptions,
    ) -> Result<Self, InferenceError> {
        let model = ModelFile::read(path)?;
        let mut dcnn = Self::from_model(model, kind, options)?;
        if let Some(w) = flat_field_warning(&path.display().to_string(), dcnn.flat_field_shift()?) {
            tracing::warn!("{w}");
        }
        Ok(dcnn)
    }

    /// The largest mean |D-CNN(I) − I| over flat black, mid-grey and white
    /// 16×16 fields. A flat field is seen unchanged through any
    /// energy-conserving optics, so a network that moves it changes the
    /// frame's brightness for nothing (docs/stability.md).
    /// Zero for a network that does not take an image (other than 3
    /// input channels).
    pub fn flat_field_shift(&mut self) -> Result<f32, InferenceError> {
        let mut worst = 0.0f32;
        if self.input_channels() != 3 {
            return Ok(worst);
        }
        for level in [0.0f32, 0.5, 1.0] {
            let frame = Image::rgb(16, 16, vec![level; 3 * 256]);
            let out = self.run_frame(&frame)?;
            let shift =
                out.data().iter().map(|v| (v - level).abs()).sum::<f32>() / out.data().len() as f32;
            worst = worst.max(shift);
        }
        Ok(worst)
    }

    pub fn from_model(
        model: ModelFile,
        kind: BackendKind,
        options: &BackendOptions,
    ) -> Result<Self, InferenceError> {
        if kind != BackendKind::Wgpu && options.precision == Precision::F16 {
            return Err(InferenceError::Backend {
                backend: kind.name(),
                reason: "f16 is offered by the wgpu backend only".into(),
            });
        }
        let network = model.lower()?;
        let backend: Box<dyn Backend> = match kind {
            BackendKind::Cpu => Box::new(tract_backend::TractBackend::new(&model, options)?),
            BackendKind::Ort => Box::new(ort_backend::OrtBackend::new(&model, options)?),
            BackendKind::Wgpu => Box::new(gpu::GpuBackend::new_default(&network, options)?),
        };
        Ok(Self {
            model,
            network,
            backend,
        })
    }

    /// The wgpu backend on a device the caller opened (the window's, so
    /// that inference and present share one GPU context).
    pub fn on_device(
        model: ModelFile,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        adapter_name: String,
        options: &BackendOptions,
    ) -> Result<Self, InferenceError> {
        let network = model.lower()?;
        let backend = Box::new(gpu::GpuBackend::with_options(
            device,
            queue,
            adapter_name,
            &network,
            options,
        )?);
        Ok(Self {
            model,
            network,
            backend,
        })
    }

    pub fn describe(&self) -> String {
        self.backend.describe()
    }

    /// Which kernel each convolution runs on and why (wgpu), one line a
    /// layer; empty for the other engines.
    pub fn conv_paths(&self) -> Vec<String> {
        self.backend.conv_paths()
    }

    /// GPU time of the last frame's network, if the backend measures it.
    pub fn last_gpu_ns(&self) -> Option<u64> {
        self.backend.last_gpu_ns()
    }

    /// Host↔device traffic of the last frame's network.
    pub fn last_traffic(&self) -> HostTraffic {
        self.backend.last_traffic()
    }

    /// Each layer's device time on `frame`, whose sides must be multiples
    /// of the network's (no padding here: the layers' sizes are the frame's).
    pub fn layer_timings(&mut self, frame: &Image) -> Result<Vec<LayerTiming>, InferenceError> {
        let m = self.network.multiple;
        if !frame.width.is_multiple_of(m) || !frame.height.is_multiple_of(m) {
            return Err(InferenceError::Frame(format!(
                "{}×{} is not a multiple of {m}",
                frame.width, frame.height
            )));
        }
        self.backend.layer_timings(frame)
    }

    /// Preprocesses one frame: [`Dcnn::run_unclamped`]'s network, then the
    /// panel's clamp to [0, 1].
    pub fn run_frame(&mut self, frame: &Image) -> Result<Image, InferenceError> {
        self.run_checked(frame, true)
    }

    /// The network's input channels (3 for a D-CNN).
    pub fn input_channels(&self) -> usize {
        self.network.values[0].channels
    }

    /// The network on one frame of [`Dcnn::input_channels`] planes, padded
    /// to the network's multiple by reflection ([`Image::pad_reflect`], the
    /// trainer's rule), run and cropped back, not clamped (a step
    /// correction of the unrolled preprocessor is signed).
    pub fn run_unclamped(&mut self, frame: &Image) -> Result<Image, InferenceError> {
        self.run_checked(frame, false)
    }

    fn run_checked(&mut self, frame: &Image, clamp: bool) -> Result<Image, InferenceError> {
        check_frame(frame, self.input_channels()).map_err(|e| match e {
            PreprocessError::Frame(reason) => InferenceError::Frame(reason),
            other => InferenceError::Frame(other.to_string()),
        })?;
        let m = self.network.multiple;
        let (pw, ph) = (frame.width.div_ceil(m) * m, frame.height.div_ceil(m) * m);
        let mut out = if (pw, ph) == (frame.width, frame.height) {
            self.backend.run(frame)?
        } else {
            self.backend
                .run(&frame.pad_reflect(pw, ph))?
                .crop(0, 0, frame.width, frame.height)
        };
        // The clamp would turn ±inf into 0 or 1 and pass NaN on: a network
        // that overflows is a failure of the engine, said and counted, not
        // a black or white pixel. Counted in the clamp's own pass.
        let mut non_finite = 0;
        for v in out.data_mut() {
            non_finite += usize::from(!v.is_finite());
            if clamp {
                *v = v.clamp(0.0, 1.0);
            }
        }
        if non_finite > 0 {
            return Err(InferenceError::NonFinite {
                engine: self.backend.describe(),
                count: non_finite,
                width: frame.width,
                height: frame.height,
            });
        }
        Ok(out)
    }
}

impl Preprocess for Dcnn {
    fn describe(&self) -> String {
        format!(
            "D-CNN {} on {}",
            self.model.path.display(),
            self.backend.describe()
        )
    }
    fn run(&mut self, input: &Image) -> Result<Image, PreprocessError> {
        self.run_frame(input).map_err(|e| match e {
            InferenceError::Frame(reason) => PreprocessError::Frame(reason),
            other => PreprocessError::Engine {
                engine: self.backend.describe(),
                reason: other.to_string(),
            },
        })
    }
    fn last_gpu_ns(&self) -> Option<u64> {
        self.backend.last_gpu_ns()
    }
    fn last_traffic(&self) -> HostTraffic {
        self.backend.last_traffic()
    }
}

/// Flat-field shift above which loading a D-CNN warns: one 8-bit code.
pub const FLAT_FIELD_TOLERANCE: f32 = 1.0 / 255.0;

/// The warning for a D-CNN that moves flat fields by `shift` on average.
pub fn flat_field_warning(model: &str, shift: f32) -> Option<String> {
    (shift > FLAT_FIELD_TOLERANCE).then(|| {
        format!(
            "{model}: the D-CNN moves flat black/grey/white fields by {shift:.4} on average ({:.1} 8-bit codes); it changes the brightness of flat content, which needs no preprocessing (docs/stability.md)",
            shift * 255.0
        )
    })
}

#[cfg(test)]
mod gpu_fused_tests;
#[cfg(test)]
pub(crate) mod gpu_tests;
#[cfg(test)]
mod gpu_tuning_tests;
#[cfg(test)]
mod tests;
