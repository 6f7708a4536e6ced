//! The environment, read once at start-up into typed settings that the
//! libraries receive as values (they never read it themselves).
//!
//! - PSF cache: `$NEDRT_CACHE_DIR`, else `$XDG_CACHE_HOME/nedrt`, else
//!   `$HOME/.cache/nedrt`; none if no such variable is set.
//! - ONNX Runtime library (the `ort` backend): `$ORT_DYLIB_PATH`, else the
//!   `onnxruntime` Python package in a `.venv` here or in a parent folder,
//!   else the one `python3` imports. Looked up only when a command may run
//!   the `ort` backend (it can spawn Python).
//! - wgpu's instance: its own variables (`WGPU_BACKEND`, `WGPU_DEBUG`, …),
//!   read by wgpu's `with_env` helpers here, once. Without `WGPU_BACKEND`
//!   the backends are wgpu's primary ones (Vulkan, Metal, DX12), not GL:
//!   on a machine without a Vulkan driver, wgpu 30's GL backend panics
//!   ("Could not lock adapter context") once the D-CNN and a panel sink
//!   each hold a device (`nedrt run --backend wgpu --sink headless`, seen
//!   on llvmpipe over EGL), where no adapter at all gives a clear error and
//!   the CPU fallback. `WGPU_BACKEND=gl` still selects it.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use nedrt_gpu::GpuSettings;
use nedrt_infer::OrtLibrary;
use nedrt_infer::ort_backend::ORT_VERSION;

/// What the environment says, captured once.
#[derive(Debug, Clone, Default)]
pub struct Environment {
    pub nedrt_cache_dir: Option<OsString>,
    pub nedrt_cache_max_gb: Option<OsString>,
    pub xdg_cache_home: Option<OsString>,
    pub home: Option<OsString>,
    pub ort_dylib_path: Option<OsString>,
    pub current_dir: PathBuf,
    pub gpu: GpuSettings,
}

impl Environment {
    pub fn capture() -> Self {
        let var = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
        Self {
            nedrt_cache_dir: var("NEDRT_CACHE_DIR"),
            nedrt_cache_max_gb: var("NEDRT_CACHE_MAX_GB"),
            xdg_cache_home: var("XDG_CACHE_HOME"),
            home: var("HOME"),
            ort_dylib_path: std::env::var_os("ORT_DYLIB_PATH"),
            current_dir: std::env::current_dir().unwrap_or_default(),
            gpu: GpuSettings {
                backends: wgpu::Backends::PRIMARY.with_env(),
                flags: wgpu::InstanceFlags::default().with_env(),
                backend_options: wgpu::BackendOptions::default().with_env(),
            },
        }
    }

    /// The PSF cache's bound from `NEDRT_CACHE_MAX_GB` (GB of 2³⁰ bytes, a
    /// number > 0), if set.
    pub fn cache_max_bytes(&self) -> anyhow::Result<Option<u64>> {
        let Some(v) = &self.nedrt_cache_max_gb else {
            return Ok(None);
        };
        let text = v.to_string_lossy();
        match text.trim().parse::<f64>() {
            Ok(gb) if gb.is_finite() && gb > 0.0 => Ok(Some((gb * f64::from(1u32 << 30)) as u64)),
            _ => anyhow::bail!(
                "NEDRT_CACHE_MAX_GB={text:?}: not a number of GB above 0 (the PSF cache's bound)"
            ),
        }
    }

    /// The default PSF cache folder.
    pub fn cache_dir(&self) -> Option<PathBuf> {
        self.nedrt_cache_dir
            .clone()
            .map(PathBuf::from)
            .or_else(|| {
                self.xdg_cache_home
                    .clone()
                    .map(|d| PathBuf::from(d).join("nedrt"))
            })
            .or_else(|| {
                self.home
                    .clone()
                    .map(|d| PathBuf::from(d).join(".cache").join("nedrt"))
            })
    }

    /// The ONNX Runtime shared library, or why none was found.
    pub fn ort_library(&self) -> OrtLibrary {
        if let Some(path) = &self.ort_dylib_path {
            let path = PathBuf::from(path);
            return if path.is_file() {
                OrtLibrary::Found(path)
            } else {
                OrtLibrary::Missing(format!("ORT_DYLIB_PATH={} is not a file", path.display()))
            };
        }
        for dir in self.current_dir.ancestors() {
            for site in site_packages(&dir.join(".venv/lib")) {
                if let Some(lib) = library_in(&site.join("onnxruntime/capi")) {
                    return OrtLibrary::Found(lib);
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
                if let Some(lib) = library_in(&Path::new(&dir).join("capi")) {
                    return OrtLibrary::Found(lib);
                }
            }
        }
        OrtLibrary::Missing(format!(
            "the ONNX Runtime shared library was not found: set ORT_DYLIB_PATH to \
             libonnxruntime.so (version {ORT_VERSION}), or `pip install onnxruntime=={ORT_VERSION}.1` \
             (in ./.venv or for python3); or use --backend cpu"
        ))
    }
}

/// The ONNX Runtime library in a wheel's `capi` folder: the fully
/// versioned name (the real file; the others are links to it).
fn library_in(capi: &Path) -> Option<PathBuf> {
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
    found.sort_by_key(|p| std::cmp::Reverse(p.as_os_str().len()));
    found.into_iter().next()
}

fn site_packages(lib: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(lib)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok().map(|e| e.path().join("site-packages")))
                .filter(|p| p.is_dir())
                .collect()
        })
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_folder_follows_nedrt_then_xdg_then_home() {
        let mut env = Environment {
            home: Some("/home/u".into()),
            ..Default::default()
        };
        assert_eq!(env.cache_dir(), Some(PathBuf::from("/home/u/.cache/nedrt")));
        env.xdg_cache_home = Some("/x".into());
        assert_eq!(env.cache_dir(), Some(PathBuf::from("/x/nedrt")));
        env.nedrt_cache_dir = Some("/n".into());
        assert_eq!(env.cache_dir(), Some(PathBuf::from("/n")));
        assert_eq!(Environment::default().cache_dir(), None);
    }

    #[test]
    fn the_cache_bound_is_a_number_of_gb_or_a_clear_error() {
        let with = |v: &str| Environment {
            nedrt_cache_max_gb: Some(v.into()),
            ..Default::default()
        };
        assert_eq!(
            Environment::default().cache_max_bytes().expect("unset"),
            None
        );
        assert_eq!(with("2").cache_max_bytes().expect("2"), Some(2 << 30));
        assert_eq!(with("0.5").cache_max_bytes().expect("0.5"), Some(1 << 29));
        for bad in ["0", "-1", "lots", "inf"] {
            let e = with(bad).cache_max_bytes().expect_err(bad).to_string();
            assert!(e.contains("NEDRT_CACHE_MAX_GB") && e.contains(bad), "{e}");
        }
    }

    #[test]
    fn wgpu_gl_is_used_only_when_asked_for() {
        let backends = Environment::capture().gpu.backends;
        match std::env::var("WGPU_BACKEND") {
            Err(_) => {
                assert!(!backends.contains(wgpu::Backends::GL), "{backends:?}");
                assert!(backends.contains(wgpu::Backends::VULKAN), "{backends:?}");
            }
            Ok(asked) => assert_eq!(backends, wgpu::Backends::from_comma_list(&asked), "{asked}"),
        }
    }

    #[test]
    fn a_missing_ort_library_is_a_clear_error() {
        let env = Environment {
            ort_dylib_path: Some("/nonexistent/libonnxruntime.so".into()),
            ..Default::default()
        };
        match env.ort_library() {
            OrtLibrary::Missing(why) => assert!(
                why.contains("ORT_DYLIB_PATH=/nonexistent/libonnxruntime.so is not a file"),
                "{why}"
            ),
            OrtLibrary::Found(p) => panic!("found {}", p.display()),
        }
    }

    #[test]
    fn the_versioned_library_is_preferred_over_its_links() {
        let dir = tempfile::tempdir().expect("tmp");
        for name in ["libonnxruntime.so", "libonnxruntime.so.1.31.1", "other.so"] {
            std::fs::write(dir.path().join(name), b"").expect("write");
        }
        assert_eq!(
            library_in(dir.path()),
            Some(dir.path().join("libonnxruntime.so.1.31.1"))
        );
    }
}
