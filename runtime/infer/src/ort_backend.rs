//! The `ort` backend: ONNX Runtime through the `ort` crate, loaded at run
//! time from a shared library (nothing is downloaded at build time) that
//! the caller found and passes in [`BackendOptions::ort_library`] (the
//! binary's rule: `ORT_DYLIB_PATH`, else the `onnxruntime` Python package in
//! `./.venv` or for `python3`). The CPU provider by default;
//! `--ort-provider cuda|tensorrt` asks for those, and a library built
//! without them is an error, never a silent fall-back to the CPU.

use std::path::PathBuf;

use ndarray::ArrayView4;
use std::sync::OnceLock;

use ort::environment::Environment;
use ort::ep;
use ort::session::Session;
use ort::value::TensorRef;

use super::{Backend, BackendOptions, InferenceError, ModelFile, OrtLibrary, OrtProvider};
use nedrt_core::Image;

/// The ONNX Runtime release the `ort` crate was built against.
pub const ORT_VERSION: &str = "1.31";

pub struct OrtBackend {
    session: Session,
    library: PathBuf,
    threads: usize,
    provider: OrtProvider,
}

impl std::fmt::Debug for OrtBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OrtBackend")
            .field("library", &self.library)
            .finish()
    }
}

fn err(reason: impl std::fmt::Display) -> InferenceError {
    InferenceError::Backend {
        backend: "ort",
        reason: reason.to_string(),
    }
}

/// ONNX Runtime allows one environment per process: it is made on first
/// use and shared by every session (the library cannot be unloaded anyway).
fn environment(library: &OrtLibrary) -> Result<&'static (PathBuf, Environment), InferenceError> {
    static ENV: OnceLock<Result<(PathBuf, Environment), String>> = OnceLock::new();
    ENV.get_or_init(|| {
        let library = match library {
            OrtLibrary::Found(path) => path.clone(),
            OrtLibrary::Missing(why) => return Err(format!("ort backend: {why}")),
        };
        let env = ort::init_from(&library)
            .map_err(|e| format!("ort backend: loading {}: {e}", library.display()))?
            .with_name("nedrt")
            .build()
            .map_err(|e| format!("ort backend: {e}"))?;
        Ok((library, env))
    })
    .as_ref()
    .map_err(|e| err(e.trim_start_matches("ort backend: ")))
}

impl OrtBackend {
    pub fn new(model: &ModelFile, options: &BackendOptions) -> Result<Self, InferenceError> {
        let (library, environment) = environment(&options.ort_library)?;
        let mut builder = Session::builder(environment).map_err(err)?;
        if options.threads > 0 {
            builder = builder
                .with_intra_threads(options.threads)
                .map_err(|e| err(e.to_string()))?;
        }
        let provider = match options.ort_provider {
            OrtProvider::Cpu => None,
            OrtProvider::Cuda => Some(ep::CUDA::default().build()),
            OrtProvider::Tensorrt => Some(ep::TensorRT::default().build()),
        };
        if let Some(p) = provider {
            let name = p.name();
            builder = builder
                .with_execution_providers([p.error_on_failure()])
                .map_err(|e| InferenceError::ProviderMissing {
                    provider: name.to_string(),
                    library: library.to_path_buf(),
                    reason: e.to_string(),
                })?;
        }
        let session =
            builder
                .commit_from_memory(&model.bytes)
                .map_err(|e| InferenceError::Model {
                    path: model.path.clone(),
                    reason: format!("ONNX Runtime cannot load it: {e}"),
                })?;
        Ok(Self {
            session,
            library: library.clone(),
            threads: options.threads,
            provider: options.ort_provider,
        })
    }
}

impl Backend for OrtBackend {
    fn describe(&self) -> String {
        let threads = if self.threads == 0 {
            "default threads".to_string()
        } else {
            format!("{} threads", self.threads)
        };
        format!("ort (ONNX Runtime {:?} provider, {threads})", self.provider)
    }

    fn run(&mut self, frame: &Image) -> Result<Image, InferenceError> {
        let shape = (1, frame.channels(), frame.height, frame.width);
        let view = ArrayView4::from_shape(shape, frame.data()).map_err(err)?;
        let input = TensorRef::from_array_view(view).map_err(err)?;
        let outputs = self.session.run(ort::inputs![input]).map_err(err)?;
        let out = outputs[0].try_extract_array::<f32>().map_err(err)?;
        if out.shape() != [1, 3, frame.height, frame.width] {
            return Err(err(format!("output shape {:?}", out.shape())));
        }
        Ok(Image::rgb(
            frame.width,
            frame.height,
            out.iter().copied().collect(),
        ))
    }
}
