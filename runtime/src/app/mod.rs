//! What the `nedrt` commands do, as library functions with typed options and
//! printable reports; the binary only parses arguments and calls these.

pub mod bench;
pub mod bench_inference;
pub mod design;
pub mod eval;
pub mod focus_cues;
pub mod plots;
pub mod run;
pub mod sim;
pub mod stability;
pub mod tradeoff;
pub mod tune;

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};

use std::collections::HashMap;

use crate::calib::{CalibError, Calibration};
use crate::inference::{BackendKind, BackendOptions, Dcnn, InferenceError};
use crate::optics::cache::PsfCache;
use crate::sim::simulator::Prepared;
use crate::sim::{Image, Method};

/// Options every command shares.
#[derive(Debug, Clone, Default)]
pub struct CommonOptions {
    /// Calibration file; `None` = the embedded `calib/default.toml`.
    pub calib: Option<PathBuf>,
    /// PSF cache folder; `None` = the default location.
    pub cache_dir: Option<PathBuf>,
    pub no_cache: bool,
    /// DOE height-map file overriding the calibration's.
    pub doe: Option<PathBuf>,
    /// A named design (`--design`): its DOE is `doe`, its K the Wiener's.
    pub design: Option<design::Design>,
    pub dcnn: DcnnOptions,
}

/// Which trained D-CNNs the `proposed` and `lens+dcnn` methods run, and how.
#[derive(Debug, Clone)]
pub struct DcnnOptions {
    /// The D-CNN co-trained with the DOE (`proposed`).
    pub path: PathBuf,
    /// A D-CNN trained for the lens alone (`lens+dcnn`).
    pub lens_path: PathBuf,
    pub backend: BackendKind,
    pub backend_options: BackendOptions,
}

impl Default for DcnnOptions {
    fn default() -> Self {
        Self {
            path: PathBuf::from("models/dcnn.onnx"),
            lens_path: PathBuf::from("models/dcnn-lens.onnx"),
            backend: BackendKind::Cpu,
            backend_options: BackendOptions::default(),
        }
    }
}

impl DcnnOptions {
    /// The DOE trained with `path`: `<stem>.doe.safetensors` beside it.
    pub fn companion_doe(&self) -> PathBuf {
        self.path.with_extension("doe.safetensors")
    }

    /// Loads (once) the D-CNN of every method in `methods` that has one.
    pub fn load_for(&self, methods: &[Method]) -> Result<HashMap<Method, Dcnn>, AppError> {
        let mut out = HashMap::new();
        for &m in methods.iter().filter(|m| m.uses_dcnn()) {
            let path = match m {
                Method::LensDcnn => &self.lens_path,
                _ => &self.path,
            };
            if !path.exists() {
                return Err(AppError::Usage(format!(
                    "{}: no D-CNN for method {m} (give --dcnn{} FILE; models/README.md says how \
                     to train one)",
                    path.display(),
                    if m == Method::LensDcnn { "-lens" } else { "" }
                )));
            }
            let dcnn = Dcnn::load(path, self.backend, &self.backend_options)?;
            tracing::info!("{m}: {} on {}", path.display(), dcnn.describe());
            out.insert(m, dcnn);
        }
        Ok(out)
    }
}

/// The frame the panel shows for `input` under `method`.
pub fn display_image(
    prepared: &Prepared,
    dcnns: &mut HashMap<Method, Dcnn>,
    method: Method,
    input: &Image,
) -> Result<Image, AppError> {
    match dcnns.get_mut(&method) {
        Some(d) => Ok(d.run_image(input)?),
        None if method.uses_dcnn() => Err(AppError::Usage(format!("no D-CNN loaded for {method}"))),
        None => Ok(prepared.display_image(method, input)),
    }
}

impl CommonOptions {
    /// The calibration, with a selected design's Wiener K (marked as tuned
    /// for the design's DOE).
    pub fn calibration(&self) -> Result<Calibration, AppError> {
        let mut calib = match &self.calib {
            Some(p) => Calibration::load(p)?,
            None => Calibration::default_embedded()?,
        };
        if let Some(d) = &self.design {
            let hash = crate::optics::doe_file::load(&d.doe, &calib)?.content_hash();
            d.apply(&mut calib, hash);
        }
        Ok(calib)
    }

    pub fn cache(&self) -> PsfCache {
        if self.no_cache {
            PsfCache::disabled()
        } else if let Some(d) = &self.cache_dir {
            PsfCache {
                dir: Some(d.clone()),
            }
        } else {
            PsfCache::default_location()
        }
    }

    pub fn doe_path(&self) -> Option<&Path> {
        self.doe.as_deref()
    }

    /// The DOE for a run of `methods`: `--doe` if given; else, when the
    /// co-designed `proposed` system is among them, the DOE trained with its
    /// D-CNN (so every DOE method of the run sees the same element); else
    /// the calibration's.
    pub fn doe_path_for(&self, methods: &[Method]) -> Option<PathBuf> {
        if let Some(p) = &self.doe {
            return Some(p.clone());
        }
        let companion = self.dcnn.companion_doe();
        (methods.contains(&Method::Proposed) && companion.exists()).then_some(companion)
    }
}

/// A progress bar on stderr (hidden when stderr is not a terminal).
pub fn progress_bar(message: &str) -> ProgressBar {
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template(
            "{msg:>12} [{bar:40}] {pos}/{len} {elapsed_precise} (eta {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    bar.set_message(message.to_string());
    bar
}

/// Errors of the commands.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    #[error(transparent)]
    Calib(#[from] CalibError),
    #[error(transparent)]
    Sim(#[from] crate::sim::SimError),
    #[error(transparent)]
    Optics(#[from] crate::optics::OpticsError),
    #[error(transparent)]
    Doe(#[from] crate::optics::doe_file::DoeError),
    #[error(transparent)]
    Image(#[from] crate::sim::image_io::ImageError),
    #[error(transparent)]
    Inference(#[from] InferenceError),
    #[error(transparent)]
    Source(#[from] crate::pipeline::source::SourceError),
    #[error(transparent)]
    Present(#[from] crate::present::PresentError),
    #[error("{path}: {reason}")]
    Output { path: String, reason: String },
    #[error("{0}")]
    Usage(String),
}

impl AppError {
    pub fn output(path: &Path, reason: impl std::fmt::Display) -> Self {
        AppError::Output {
            path: path.display().to_string(),
            reason: reason.to_string(),
        }
    }
}

/// Writes a text file atomically, naming the file on failure.
pub fn write_text(path: &Path, text: &str) -> Result<(), AppError> {
    crate::util::write_atomic(path, text.as_bytes()).map_err(|e| AppError::output(path, e))
}

/// Creates an output folder, naming it on failure.
pub fn create_dir(path: &Path) -> Result<(), AppError> {
    std::fs::create_dir_all(path)
        .map_err(|e| AppError::output(path, format!("cannot create folder: {e}")))
}

/// Refuses an output file whose folder does not exist, so that a long run
/// fails at its start rather than losing its report at the end.
pub fn check_output_folder(file: &Path) -> Result<(), AppError> {
    match file.parent() {
        Some(dir) if !dir.as_os_str().is_empty() && !dir.is_dir() => Err(AppError::output(
            file,
            format!("cannot write: folder {} does not exist", dir.display()),
        )),
        _ => Ok(()),
    }
}

/// The largest accommodation `--accom` takes: a young child's amplitude
/// (near point 5 cm); past it the request is a typo, not an eye.
pub const MAX_ACCOMMODATION_D: f64 = 20.0;

/// Checks an accommodation: finite and in [0, 20] D (errors), inside the
/// calibrated range (else a warning, returned for printing).
pub fn check_accommodation(
    calib: &Calibration,
    accommodation_d: f64,
) -> Result<Option<String>, AppError> {
    if !accommodation_d.is_finite() {
        return Err(AppError::Usage(format!(
            "--accom {accommodation_d}: not a number of diopters"
        )));
    }
    if accommodation_d < 0.0 {
        return Err(AppError::Usage(format!(
            "--accom {accommodation_d}: accommodation must be ≥ 0 D (0 D is focus at infinity; an eye cannot focus beyond it)"
        )));
    }
    if accommodation_d > MAX_ACCOMMODATION_D {
        return Err(AppError::Usage(format!(
            "--accom {accommodation_d:e}: beyond what an eye accommodates (at most \
             {MAX_ACCOMMODATION_D} D, a child's near point of 5 cm)"
        )));
    }
    let [lo, hi] = calib.range_d;
    Ok((accommodation_d < lo || accommodation_d > hi).then(|| {
        format!(
            "accommodation {accommodation_d} D lies outside the calibrated range [{lo}, {hi}] D of {}; simulating anyway",
            calib.source
        )
    }))
}
