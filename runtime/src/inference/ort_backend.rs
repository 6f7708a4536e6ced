//! The `ort` backend: ONNX Runtime through the `ort` crate, loaded at run
//! time from a shared library (nothing is downloaded at build time). The
//! library is `ORT_DYLIB_PATH` if set, else the one shipped in the
//! `onnxruntime` Python package (`pip install onnxruntime==1.31.1`), looked
//! for in `./.venv` and through `python3`. The CPU provider by default;
//! `--ort-provider cuda|tensorrt` asks for those, and a library built
//! without them is an error, never a silent fall-back to the CPU.

use std::path::{Path, PathBuf};

use ndarray::ArrayView4;
use std::sync::OnceLock;

use ort::environment::Environment;
use ort::ep;
use ort::session::Session;
use ort::value::TensorRef;

use super::{Backend, BackendOptions, Frame, InferenceError, ModelFile, OrtProvider};

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

fn lib_in(capi: &Path) -> Option<PathBuf> {
    let mut found: Vec<PathBuf> = std::fs::read_dir(capi)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name().and_then(|n| n.to_str()).is_some_and(|n| {
                n.starts_with("libonnxruntime.so")
                    || n == "onnxruntime.dll"
                    || n.starts_with("libonnxruntime") && n.ends_with(".dylib")
            })
        })
        .collect();
    // The fully versioned name is the real file; the others are links.
    found.sort_by_key(|p| std::cmp::Reverse(p.as_os_str().len()));
    found.into_iter().next()
}

/// Where the ONNX Runtime shared library is, or why it was not found.
pub fn find_library() -> Result<PathBuf, InferenceError> {
    find_library_in(std::env::var_os("ORT_DYLIB_PATH"))
}

/// [`find_library`] with the value of `ORT_DYLIB_PATH` given.
pub fn find_library_in(env_path: Option<std::ffi::OsString>) -> Result<PathBuf, InferenceError> {
    if let Some(path) = env_path {
        let path = PathBuf::from(path);
        return if path.is_file() {
            Ok(path)
        } else {
            Err(err(format!(
                "ORT_DYLIB_PATH={} is not a file",
                path.display()
            )))
        };
    }
    // A project virtual environment here or in a parent folder, then
    // whatever python3 imports.
    let cwd = std::env::current_dir().unwrap_or_default();
    for dir in cwd.ancestors() {
        if let Ok(sites) = glob_site_packages(&dir.join(".venv/lib")) {
            for site in sites {
                if let Some(lib) = lib_in(&site.join("onnxruntime/capi")) {
                    return Ok(lib);
                }
            }
        }
    }
    for python in ["python3", "python"] {
        let out = std::process::Command::new(python)
            .args([
                "-c",
                "import onnxruntime, os; print(os.path.dirname(onnxruntime.__file__))",
            ])
            .stderr(std::process::Stdio::null())
            .output();
        if let Ok(out) = out
            && out.status.success()
        {
            let dir = String::from_utf8_lossy(&out.stdout).trim().to_string();
            if let Some(lib) = lib_in(&Path::new(&dir).join("capi")) {
                return Ok(lib);
            }
        }
    }
    Err(err(format!(
        "the ONNX Runtime shared library was not found: set ORT_DYLIB_PATH to \
         libonnxruntime.so (version {ORT_VERSION}), or `pip install onnxruntime=={ORT_VERSION}.1` \
         (in ./.venv or for python3); or use --backend cpu"
    )))
}

fn glob_site_packages(lib: &Path) -> std::io::Result<Vec<PathBuf>> {
    Ok(std::fs::read_dir(lib)?
        .filter_map(|e| e.ok().map(|e| e.path().join("site-packages")))
        .filter(|p| p.is_dir())
        .collect())
}

/// ONNX Runtime allows one environment per process: it is made on first
/// use and shared by every session (the library cannot be unloaded anyway).
fn environment() -> Result<&'static (PathBuf, Environment), InferenceError> {
    static ENV: OnceLock<Result<(PathBuf, Environment), String>> = OnceLock::new();
    ENV.get_or_init(|| {
        let library = find_library().map_err(|e| e.to_string())?;
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
        let (library, environment) = environment()?;
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
                .map_err(|e| {
                    err(format!(
                        "the {name} execution provider is not available in {} ({e}); use an \
                         ONNX Runtime build with it (ORT_DYLIB_PATH) or --ort-provider cpu",
                        library.display()
                    ))
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

    fn run(&mut self, frame: &Frame) -> Result<Frame, InferenceError> {
        let shape = (1, 3, frame.height, frame.width);
        let view = ArrayView4::from_shape(shape, &frame.data).map_err(err)?;
        let input = TensorRef::from_array_view(view).map_err(err)?;
        let outputs = self.session.run(ort::inputs![input]).map_err(err)?;
        let out = outputs[0].try_extract_array::<f32>().map_err(err)?;
        if out.shape() != [1, 3, frame.height, frame.width] {
            return Err(err(format!("output shape {:?}", out.shape())));
        }
        Ok(Frame {
            width: frame.width,
            height: frame.height,
            data: out.iter().copied().collect(),
        })
    }
}
