//! nedrt-command, layer 3 of nedrt: what every command shares, below the
//! commands themselves (nedrt-run: `nedrt run`; nedrt-app: the others;
//! nedrt-studies): the options common to all ([`CommonOptions`]: the
//! calibration, the named designs, the networks, the PSF cache, progress),
//! the commands' error ([`AppError`]), and small output helpers. The
//! commands take these resolved values; none of them calls back up.
//!
//! Rule: no clap, no indicatif, no environment (settings arrive as values,
//! progress through [`nedrt_core::Progress`]).

pub mod design;

use std::path::{Path, PathBuf};

use std::sync::Arc;

use nedrt_core::Progress;
use nedrt_core::progress::Silent;

use std::collections::HashMap;

use nedrt_core::calib::{CalibError, Calibration, EyeOverrides};
use nedrt_infer::{BackendKind, BackendOptions, InferenceError};
use nedrt_optics::bundle::PsfBundle;
use nedrt_optics::cache::PsfCache;
use nedrt_optics::sim::Method;
use nedrt_stages::Network;

/// Options every command shares.
#[derive(Debug, Clone)]
pub struct CommonOptions {
    /// Calibration file; `None` = the embedded `calib/default.toml`.
    pub calib: Option<PathBuf>,
    /// PSF cache folder (the binary resolves the default); `None`: no cache.
    pub cache_dir: Option<PathBuf>,
    /// Most bytes the cache folder keeps (`NEDRT_CACHE_MAX_GB`); `None`:
    /// nedrt-optics' default bound.
    pub cache_max_bytes: Option<u64>,
    /// DOE height-map file overriding the calibration's.
    pub doe: Option<PathBuf>,
    /// A named design (`--design`): its DOE is `doe`, its K the Wiener's.
    pub design: Option<design::Design>,
    /// A measured PSF bundle (`--psfs`, `calib psfs`) standing for the
    /// lens + DOE optics' computed PSFs.
    pub psfs: Option<MeasuredPsfs>,
    pub dcnn: DcnnOptions,
    /// The eye's settings given on the command line over the calibration's.
    pub eye: EyeOverrides,
    /// Where long work reports its progress.
    pub progress: Arc<dyn Progress>,
}

impl Default for CommonOptions {
    fn default() -> Self {
        Self {
            calib: None,
            cache_dir: None,
            cache_max_bytes: None,
            doe: None,
            design: None,
            psfs: None,
            dcnn: DcnnOptions::default(),
            eye: EyeOverrides::default(),
            progress: Arc::new(Silent),
        }
    }
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

    /// Loads (once) the network of every method in `methods` that has one:
    /// a D-CNN, or an unrolled model by its manifest (`NAME.unrolled.toml`).
    pub fn load_for(&self, methods: &[Method]) -> Result<HashMap<Method, Network>, AppError> {
        let mut out = HashMap::new();
        for &m in methods.iter().filter(|m| m.uses_dcnn()) {
            let path = match m {
                Method::LensDcnn => &self.lens_path,
                _ => &self.path,
            };
            if !path.exists() {
                return Err(AppError::input(
                    path.display(),
                    format!(
                        "no D-CNN for method {m} (give --dcnn{} FILE; models/README.md says how \
                         to train one)",
                        if m == Method::LensDcnn { "-lens" } else { "" }
                    ),
                ));
            }
            let network = Network::load(m, path, self.backend, &self.backend_options)?;
            tracing::info!("{m}: {}", network.line());
            out.insert(m, network);
        }
        Ok(out)
    }
}

impl CommonOptions {
    /// The calibration, with a selected design's Wiener K (marked as tuned
    /// for the design's DOE).
    /// The panel's resolution, the largest image it can show (read without
    /// loading a design's DOE).
    pub fn panel_px(&self) -> Result<(usize, usize), AppError> {
        let calib = match &self.calib {
            Some(p) => Calibration::load(p)?,
            None => Calibration::default_embedded()?,
        };
        Ok((calib.panel.width_px, calib.panel.height_px))
    }

    pub fn calibration(&self) -> Result<Calibration, AppError> {
        let mut calib = match &self.calib {
            Some(p) => Calibration::load(p)?,
            None => Calibration::default_embedded()?,
        };
        // A DOE the calibration names must be there, whether or not this
        // run's methods look through it (the shipped system uses its D-CNN's).
        if let Some(p) = &calib.doe_file
            && let Err(e) = std::fs::metadata(p)
        {
            return Err(AppError::output(
                p,
                format!("the calibration's DOE file (doe_file) cannot be read: {e}"),
            ));
        }
        if let Some(d) = &self.design {
            let hash = nedrt_optics::doe_file::load(&d.doe, &calib)?.content_hash();
            d.apply(&mut calib, hash);
        }
        self.eye.apply(&mut calib)?;
        Ok(calib)
    }

    pub fn cache(&self) -> PsfCache {
        let cache = PsfCache::at(self.cache_dir.clone());
        match self.cache_max_bytes {
            Some(max) => cache.with_max_bytes(Some(max)),
            None => cache,
        }
    }

    /// The progress reporter, for the simulator.
    pub fn progress(&self) -> &dyn Progress {
        &*self.progress
    }

    /// A named phase of work whose length is set once known.
    pub fn phase(&self, name: &str) -> Phase<'_> {
        Phase {
            progress: &*self.progress,
            name: name.to_string(),
        }
    }

    /// The bundle of `--psfs`, read and checked once however many
    /// simulators a command builds; `None` without.
    pub fn bundle(&self) -> Result<Option<Arc<PsfBundle>>, AppError> {
        let Some(m) = &self.psfs else {
            return Ok(None);
        };
        if let Some(b) = m.loaded.get() {
            return Ok(Some(b.clone()));
        }
        let bundle = Arc::new(PsfBundle::load(&m.path).map_err(nedrt_optics::sim::SimError::from)?);
        Ok(Some(m.loaded.get_or_init(|| bundle).clone()))
    }

    /// `sim` with the measured PSFs of `--psfs` in place of the DOE
    /// optics' computed ones (docs/calibration.md); `sim` itself without.
    pub fn measured(
        &self,
        sim: nedrt_optics::sim::Simulator,
    ) -> Result<nedrt_optics::sim::Simulator, AppError> {
        match self.bundle()? {
            Some(bundle) => Ok(sim.with_measured(bundle)?),
            None => Ok(sim),
        }
    }

    /// The methods a study runs when none are named (`eval`,
    /// `tolerance`): the built-in displays and, where its model is there
    /// (`models/dcnn.onnx` is relative to the working folder), the D-CNN
    /// (`proposed`, whose DOE then serves every DOE method of the run, so
    /// doe-only and doe+wiener show that DOE without and with the Wiener).
    pub fn default_methods(&self) -> Vec<Method> {
        let mut methods = Method::BUILT_IN.to_vec();
        if self.dcnn.path.is_file() {
            methods.push(Method::Proposed);
        } else {
            tracing::warn!(
                "{}: no D-CNN here, so proposed is left out (give --dcnn FILE or --methods)",
                self.dcnn.path.display()
            );
        }
        methods
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

/// `--psfs`: a bundle's folder, read on first use and shared by every
/// clone of the options.
#[derive(Debug, Clone)]
pub struct MeasuredPsfs {
    pub path: PathBuf,
    loaded: Arc<std::sync::OnceLock<Arc<PsfBundle>>>,
}

impl MeasuredPsfs {
    pub fn new(path: PathBuf) -> Self {
        Self {
            path,
            loaded: Default::default(),
        }
    }
}

/// One phase of a command's progress (see [`CommonOptions::phase`]).
#[derive(Debug)]
pub struct Phase<'a> {
    progress: &'a dyn Progress,
    name: String,
}

impl Phase<'_> {
    /// Starts the phase with `total` steps.
    pub fn set_length(&self, total: u64) {
        self.progress.start(&self.name, total);
    }
    pub fn inc(&self, n: u64) {
        self.progress.advance(n);
    }
    pub fn finish_and_clear(&self) {
        self.progress.finish();
    }
}

/// Errors of the commands.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    #[error(transparent)]
    Calib(#[from] CalibError),
    #[error(transparent)]
    Sim(#[from] nedrt_optics::sim::SimError),
    #[error(transparent)]
    Optics(#[from] nedrt_optics::OpticsError),
    #[error(transparent)]
    Doe(#[from] nedrt_optics::doe_file::DoeError),
    #[error(transparent)]
    Image(#[from] nedrt_core::image_io::ImageError),
    #[error(transparent)]
    Inference(#[from] InferenceError),
    #[error(transparent)]
    Preprocess(#[from] nedrt_core::PreprocessError),
    #[error(transparent)]
    Source(#[from] nedrt_service::pipeline::source::SourceError),
    #[error(transparent)]
    Present(#[from] nedrt_service::present::PresentError),
    #[error(transparent)]
    Fft(#[from] nedrt_gpu::fft::FftError),
    #[error(transparent)]
    Gpu(#[from] nedrt_gpu::GpuError),
    /// An output file or folder that cannot be written or made as asked
    /// (a missing folder, a full disk, a report that does not serialize, a
    /// sweep too large to hold); `path` names it.
    #[error("{path}: {reason}")]
    Output { path: String, reason: String },
    /// A command-line value out of range or not a number: `option` is the
    /// option as given (`--accom 25`, `--crop 600x10+0+0`), so that the user
    /// sees which one to change.
    #[error("{option}: {reason}")]
    Option { option: String, reason: String },
    /// Options that do not go together, or one that needs another
    /// (`--headless` needs `--screenshot`): no single value is wrong, the
    /// combination is.
    #[error("{0}")]
    Conflict(String),
    /// An input the command reads that is unusable: an image too small, a
    /// folder without images, a display image of the wrong size, an
    /// unreadable model card or report, a missing model, or a system whose
    /// PSFs lack a property the request needs; `path` names the file, folder
    /// or system.
    #[error("{path}: {reason}")]
    Input { path: String, reason: String },
    /// A part the request needs was not loaded or prepared (a method's
    /// D-CNN, its Wiener filter) or there is nothing to work on (no methods,
    /// no accommodations): the options named too little.
    #[error("{0}")]
    Unavailable(String),
    /// A worker thread could not start or panicked; `what` names it as the
    /// subject of the sentence ("the source thread"), `reason` says what
    /// happened ("panicked").
    #[error("{what} {reason}")]
    Thread { what: String, reason: String },
    /// Drawing the viewer's picture (text and slider) failed, usually for
    /// want of a font.
    #[error("drawing the viewer's picture: {0}")]
    Draw(String),
    /// A state the commands do not reach unless the code is wrong (an
    /// invariant broken); reported rather than panicking.
    #[error("{0}")]
    Internal(String),
}

/// An engine's error as the command's: the same variants, so that every
/// message and hint stays as it was when the engines lived in nedrt-app.
impl From<nedrt_stages::EngineError> for AppError {
    fn from(e: nedrt_stages::EngineError) -> Self {
        use nedrt_stages::EngineError as E;
        match e {
            E::Unavailable(what) => AppError::Unavailable(what),
            E::Input { path, reason } => AppError::Input { path, reason },
            E::Optics(e) => e.into(),
            E::Sim(e) => e.into(),
            E::Fft(e) => e.into(),
            E::Gpu(e) => e.into(),
            E::Inference(e) => e.into(),
        }
    }
}

/// The GPU of `--backend wgpu` for `methods` with `prefilters`, where one
/// of them has work for a device ([`nedrt_stages::device_prefilter::wants_gpu`]);
/// `None` on the other backends (the prefilters then run on the CPU, as
/// the network does).
pub fn gpu_for(
    common: &CommonOptions,
    methods: &[nedrt_optics::sim::Method],
    prefilters: &[nedrt_stages::preprocess::Prefilter],
) -> Result<Option<nedrt_stages::device_prefilter::Gpu>, AppError> {
    let wanted = nedrt_stages::device_prefilter::wants_gpu(methods, prefilters);
    if common.dcnn.backend != BackendKind::Wgpu || !wanted {
        return Ok(None);
    }
    let (_, device, queue) = nedrt_gpu::open_device(&common.dcnn.backend_options.gpu, false)?;
    Ok(Some((device, queue)))
}

impl AppError {
    pub fn output(path: &Path, reason: impl std::fmt::Display) -> Self {
        AppError::Output {
            path: path.display().to_string(),
            reason: reason.to_string(),
        }
    }

    /// A bad command-line value: `option` as given (flag and value).
    pub fn option(option: impl std::fmt::Display, reason: impl std::fmt::Display) -> Self {
        AppError::Option {
            option: option.to_string(),
            reason: reason.to_string(),
        }
    }

    /// An unusable input: `path` (a file, folder or named system) and why.
    pub fn input(path: impl std::fmt::Display, reason: impl std::fmt::Display) -> Self {
        AppError::Input {
            path: path.to_string(),
            reason: reason.to_string(),
        }
    }

    /// A worker thread that could not start or panicked.
    pub fn thread(what: impl std::fmt::Display, reason: impl std::fmt::Display) -> Self {
        AppError::Thread {
            what: what.to_string(),
            reason: reason.to_string(),
        }
    }
}

/// Writes a text file atomically, naming the file on failure.
pub fn write_text(path: &Path, text: &str) -> Result<(), AppError> {
    nedrt_core::util::write_atomic(path, text.as_bytes()).map_err(|e| AppError::output(path, e))
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

/// Checks an accommodation given as `--accom`: finite and in [0, 20] D
/// (errors), inside the calibrated range (else a warning, returned for
/// printing).
pub fn check_accommodation(
    calib: &Calibration,
    accommodation_d: f64,
) -> Result<Option<String>, AppError> {
    check_accommodation_as(calib, accommodation_d, "--accom")
}

/// `check_accommodation` of a value the user gave as `name` (a flag, or a
/// Python argument): errors name it.
pub fn check_accommodation_as(
    calib: &Calibration,
    accommodation_d: f64,
    name: &str,
) -> Result<Option<String>, AppError> {
    if !accommodation_d.is_finite() {
        return Err(AppError::option(
            format!("{name} {accommodation_d}"),
            "not a number of diopters",
        ));
    }
    if accommodation_d < 0.0 {
        return Err(AppError::option(
            format!("{name} {accommodation_d}"),
            "accommodation must be ≥ 0 D (0 D is focus at infinity; an eye cannot focus beyond it)",
        ));
    }
    if accommodation_d > MAX_ACCOMMODATION_D {
        return Err(AppError::option(
            format!("{name} {accommodation_d:e}"),
            format!(
                "beyond what an eye accommodates (at most {MAX_ACCOMMODATION_D} D, a child's \
                 near point of 5 cm)"
            ),
        ));
    }
    let [lo, hi] = calib.range_d;
    Ok((accommodation_d < lo || accommodation_d > hi).then(|| {
        format!(
            "accommodation {accommodation_d} D lies outside the calibrated range [{lo}, {hi}] D of {}; simulating anyway",
            calib.source
        )
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn option_and_input_errors_name_what_to_fix_first() {
        let e = AppError::option("--fps 0", "frames a second must lie in [0.1, 100]");
        assert_eq!(
            e.to_string(),
            "--fps 0: frames a second must lie in [0.1, 100]"
        );
        assert!(matches!(e, AppError::Option { ref option, .. } if option == "--fps 0"));
        let e = AppError::input(
            Path::new("in/tiny.png").display(),
            "smaller than 8×8 pixels",
        );
        assert_eq!(e.to_string(), "in/tiny.png: smaller than 8×8 pixels");
        assert!(matches!(e, AppError::Input { ref path, .. } if path == "in/tiny.png"));
    }
}
