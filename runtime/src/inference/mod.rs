//! The D-CNN at run time: one ONNX file, read and checked once
//! ([`network`]), run by any of three backends behind [`Backend`]:
//! `cpu` (tract, pure Rust, always built in), `ort` (ONNX Runtime loaded
//! from a shared library at run time) and `wgpu` (WGSL kernels generated
//! from the graph, [`gpu`]). [`Dcnn`] adds what every backend shares:
//! reflection padding to the network's multiple, cropping back, and the
//! clamp to the panel's [0, 1].

pub mod gpu;
mod lower;
pub mod network;
pub mod ort_backend;
pub mod reference;
pub mod synth;
pub mod tract_backend;

use std::path::{Path, PathBuf};

pub use network::{ModelFile, Network};

use crate::sim::image::Image;

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
}

/// Which engine runs the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, clap::ValueEnum)]
pub enum BackendKind {
    /// tract, pure Rust, built in.
    Cpu,
    /// ONNX Runtime, loaded from ORT_DYLIB_PATH or the onnxruntime Python package.
    Ort,
    /// Generated WGSL compute kernels on any wgpu adapter.
    Wgpu,
}

impl BackendKind {
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Cpu => "cpu",
            BackendKind::Ort => "ort",
            BackendKind::Wgpu => "wgpu",
        }
    }
}

/// Arithmetic precision of the GPU backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, clap::ValueEnum)]
pub enum Precision {
    #[default]
    F32,
    /// Half-precision storage (weights and activations), f32 accumulation;
    /// needs the adapter's `shader-f16`.
    F16,
}

/// A CHW float tensor of 3 channels.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    /// Planar: all of channel 0, then 1, then 2.
    pub data: Vec<f32>,
}

impl Frame {
    pub fn from_image(image: &Image) -> Result<Self, InferenceError> {
        if image.channels() != 3 {
            return Err(InferenceError::Frame(format!(
                "{} channels; the D-CNN takes RGB",
                image.channels()
            )));
        }
        Ok(Self {
            width: image.width,
            height: image.height,
            data: image.planes.concat(),
        })
    }

    pub fn into_image(self) -> Image {
        let plane = self.width * self.height;
        let planes = self
            .data
            .chunks(plane.max(1))
            .map(<[f32]>::to_vec)
            .collect();
        Image::from_planes(self.width, self.height, planes)
    }

    /// Extends right and bottom to `width`×`height` by reflection about the
    /// last row and column (PyTorch's and ONNX's "reflect"), falling back to
    /// edge replication where the frame is smaller than the pad.
    pub fn pad_reflect(&self, width: usize, height: usize) -> Frame {
        let index = |i: usize, n: usize| {
            if i < n {
                i
            } else if i - n + 1 < n {
                2 * (n - 1) - i
            } else {
                n - 1
            }
        };
        let mut data = Vec::with_capacity(3 * width * height);
        for c in 0..3 {
            for y in 0..height {
                let row = (c * self.height + index(y, self.height)) * self.width;
                data.extend((0..width).map(|x| self.data[row + index(x, self.width)]));
            }
        }
        Frame {
            width,
            height,
            data,
        }
    }

    pub fn crop(&self, width: usize, height: usize) -> Frame {
        let mut data = Vec::with_capacity(3 * width * height);
        for c in 0..3 {
            for y in 0..height {
                let row = (c * self.height + y) * self.width;
                data.extend_from_slice(&self.data[row..row + width]);
            }
        }
        Frame {
            width,
            height,
            data,
        }
    }
}

/// An engine that runs the lowered network on frames whose sides are
/// multiples of the network's multiple.
pub trait Backend: Send + std::fmt::Debug {
    /// What runs it, for reports: "cpu (tract)", "wgpu f16 on <adapter>".
    fn describe(&self) -> String;
    /// Runs the network; the result may or may not be clamped.
    fn run(&mut self, frame: &Frame) -> Result<Frame, InferenceError>;
    /// The device's own time for the last run (GPU timestamp queries), where
    /// the device can measure it.
    fn last_gpu_ns(&self) -> Option<u64> {
        None
    }
}

/// ONNX Runtime execution provider of the `ort` backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, clap::ValueEnum)]
pub enum OrtProvider {
    #[default]
    Cpu,
    /// Needs an ONNX Runtime build with CUDA (the onnxruntime-gpu wheel).
    Cuda,
    /// Needs an ONNX Runtime build with TensorRT.
    Tensorrt,
}

/// Options for building a backend.
#[derive(Debug, Clone, Default)]
pub struct BackendOptions {
    /// Threads for CPU engines (0: the engine's default).
    pub threads: usize,
    pub precision: Precision,
    pub ort_provider: OrtProvider,
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
    pub fn flat_field_shift(&mut self) -> Result<f32, InferenceError> {
        let mut worst = 0.0f32;
        for level in [0.0f32, 0.5, 1.0] {
            let frame = Frame {
                width: 16,
                height: 16,
                data: vec![level; 3 * 256],
            };
            let out = self.run_frame(&frame)?;
            let shift =
                out.data.iter().map(|v| (v - level).abs()).sum::<f32>() / out.data.len() as f32;
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
        precision: Precision,
    ) -> Result<Self, InferenceError> {
        let network = model.lower()?;
        let backend = Box::new(gpu::GpuBackend::new(
            device,
            queue,
            adapter_name,
            &network,
            precision,
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

    /// GPU time of the last frame's network, if the backend measures it.
    pub fn last_gpu_ns(&self) -> Option<u64> {
        self.backend.last_gpu_ns()
    }

    /// Preprocesses one frame: pad to the network's multiple, run, crop,
    /// clamp to [0, 1].
    pub fn run_frame(&mut self, frame: &Frame) -> Result<Frame, InferenceError> {
        if frame.width == 0
            || frame.height == 0
            || frame.data.len() != 3 * frame.width * frame.height
        {
            return Err(InferenceError::Frame(format!(
                "{}×{} frame with {} values",
                frame.width,
                frame.height,
                frame.data.len()
            )));
        }
        if let Some(bad) = frame.data.iter().find(|v| !v.is_finite()) {
            return Err(InferenceError::Frame(format!("frame contains {bad}")));
        }
        let m = self.network.multiple;
        let (pw, ph) = (frame.width.div_ceil(m) * m, frame.height.div_ceil(m) * m);
        let mut out = if (pw, ph) == (frame.width, frame.height) {
            self.backend.run(frame)?
        } else {
            self.backend
                .run(&frame.pad_reflect(pw, ph))?
                .crop(frame.width, frame.height)
        };
        for v in &mut out.data {
            *v = v.clamp(0.0, 1.0);
        }
        Ok(out)
    }

    pub fn run_image(&mut self, image: &Image) -> Result<Image, InferenceError> {
        Ok(self.run_frame(&Frame::from_image(image)?)?.into_image())
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
pub(crate) mod gpu_tests;
#[cfg(test)]
mod tests;
