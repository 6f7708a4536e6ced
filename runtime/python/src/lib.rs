//! nedrt's Python package (`import nedrt`, issue 58): the validated
//! simulator, prefilters, PSFs and evaluation on numpy arrays, for the
//! researchers who work in notebooks and PyTorch loops. The same library
//! calls as the `nedrt` commands (nedrt-app's `frames`, nedrt-studies'
//! `eval`), so that a number here is the CLI's number.
//!
//! Images are numpy arrays H×W×3 of float32 in [0, 1], the simulator's
//! frame values (a PNG loaded by `nedrt sim` is the same values). nedrt
//! holds colour planes apart, so an image crosses the boundary in one pass
//! that reorders it, and the result is handed to numpy without a copy.
//! Long calls release the GIL. Errors are Python exceptions of
//! `nedrt.NedrtError` (`nedrt.InputError` for bad arguments, also a
//! `ValueError`), with nedrt's own message.
//!
//! Like the binary (and unlike the libraries below it), this crate reads
//! the environment: the PSF cache's folder, as `nedrt` finds it.

use std::path::PathBuf;

use nedrt_app::frames::{self, FrameRequest};
use nedrt_app::{AppError, CommonOptions};
use nedrt_core::Image;
use nedrt_infer::{BackendKind, BackendOptions};
use nedrt_optics::sim::{Method, Optics, ZoneRequest};
use nedrt_stages::preprocess::Prefilter;
use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Raises `nedrt.<class>` (defined in Python, nedrt/_errors.py) with
/// `message`.
fn raise(py: Python<'_>, class: &str, message: String) -> PyErr {
    match py
        .import("nedrt._errors")
        .and_then(|m| m.getattr(class))
        .and_then(|c| c.call1((message.clone(),)))
    {
        Ok(e) => PyErr::from_value(e),
        Err(e) => e,
    }
}

/// A Rust error as the Python exception of its kind.
fn to_py(py: Python<'_>, e: AppError) -> PyErr {
    let class = match &e {
        AppError::Option { .. } | AppError::Conflict(_) | AppError::Input { .. } => "InputError",
        AppError::Calib(_) | AppError::Image(_) | AppError::Doe(_) => "InputError",
        _ => "NedrtError",
    };
    raise(py, class, e.to_string())
}

fn bad(py: Python<'_>, message: impl Into<String>) -> PyErr {
    raise(py, "InputError", message.into())
}

/// The image argument `name`: H×W×3 float32, finite, in [0, 1], as nedrt's
/// planar [`Image`] (one pass).
fn image_arg(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Image> {
    let py = obj.py();
    let Ok(array) = obj.cast::<PyArrayDyn<f32>>() else {
        let dtype = obj
            .getattr("dtype")
            .map(|d| d.to_string())
            .unwrap_or_else(|_| obj.get_type().to_string());
        return Err(bad(
            py,
            format!(
                "{name}: a numpy array of float32 is needed, not {dtype} (use \
                 image.astype(numpy.float32), values in [0, 1])"
            ),
        ));
    };
    let shape = array.shape().to_vec();
    let [h, w, 3] = shape[..] else {
        return Err(bad(
            py,
            format!("{name}: shape {shape:?}; an image is H×W×3 (RGB)"),
        ));
    };
    let readonly = array.readonly();
    let view = readonly.as_array();
    let mut planar = vec![0.0f32; 3 * w * h];
    for ((y, x, c), &v) in view.indexed_iter().map(|(i, v)| ((i[0], i[1], i[2]), v)) {
        if !v.is_finite() || !(0.0..=1.0).contains(&v) {
            return Err(bad(
                py,
                format!(
                    "{name}: value {v} at row {y}, column {x}, channel {c}; values are finite, \
                     in [0, 1]"
                ),
            ));
        }
        planar[c * w * h + y * w + x] = v;
    }
    Ok(Image::rgb(w, h, planar))
}

/// nedrt's planar image as a numpy H×W×C float32 array (one pass; numpy
/// takes the buffer).
fn image_out<'py>(py: Python<'py>, image: &Image) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let (w, h, c) = (image.width, image.height, image.channels());
    let data = image.data();
    let mut interleaved = vec![0.0f32; data.len()];
    for ch in 0..c {
        for (i, &v) in data[ch * w * h..(ch + 1) * w * h].iter().enumerate() {
            interleaved[i * c + ch] = v;
        }
    }
    PyArray1::from_vec(py, interleaved).reshape(vec![h, w, c])
}

fn method_arg(py: Python<'_>, name: Option<&str>, common: &CommonOptions) -> PyResult<Method> {
    match name {
        None => Ok(nedrt_app::sim::SimOptions::shipped_method(common)),
        Some(n) => n
            .parse::<Method>()
            .map_err(|e| bad(py, format!("method: {e}"))),
    }
}

fn prefilter_arg(py: Python<'_>, name: &str) -> PyResult<Prefilter> {
    name.parse::<Prefilter>()
        .map_err(|e| bad(py, format!("prefilter {name:?}: {e}")))
}

/// A display of nedrt: its calibration, design (a DOE with its Wiener K),
/// eye and networks, as the `nedrt` command's global options give them.
#[pyclass(module = "nedrt", frozen)]
struct Display {
    common: CommonOptions,
}

impl Display {
    /// An image call's arguments: the image, the method (the shipped one
    /// by default) and the prefilter.
    fn frame_args(
        &self,
        image: &Bound<'_, PyAny>,
        method: Option<&str>,
        prefilter: &str,
    ) -> PyResult<(Image, Method, Prefilter)> {
        let py = image.py();
        Ok((
            image_arg(image, "image")?,
            method_arg(py, method, &self.common)?,
            prefilter_arg(py, prefilter)?,
        ))
    }
}

/// The PSF cache's folder as `nedrt` finds it: $NEDRT_CACHE_DIR,
/// $XDG_CACHE_HOME/nedrt or ~/.cache/nedrt.
fn default_cache_dir() -> Option<PathBuf> {
    let var = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
    var("NEDRT_CACHE_DIR")
        .map(PathBuf::from)
        .or_else(|| var("XDG_CACHE_HOME").map(|d| PathBuf::from(d).join("nedrt")))
        .or_else(|| var("HOME").map(|d| PathBuf::from(d).join(".cache").join("nedrt")))
}

#[pymethods]
impl Display {
    /// Display(calib=None, design=None, eye=None, doe=None, dcnn=None,
    /// backend="cpu", cache=True)
    ///
    /// calib: a calibration TOML (default: nedrt's embedded one); design: a
    /// design by name (designs/NAME.toml under the working directory) or
    /// file; eye: "paper", "4mm", "3mm+lca", "4mm@10" (docs/model.md §4a);
    /// doe: a DOE file over the calibration's; dcnn: the network of
    /// `proposed` (an ONNX file or an unrolled model's manifest; default
    /// models/dcnn.onnx); backend: "cpu", "ort" or "wgpu"; cache: keep PSFs
    /// in nedrt's cache folder.
    #[new]
    #[pyo3(signature = (calib=None, design=None, eye=None, doe=None, dcnn=None, backend="cpu", cache=true))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        calib: Option<PathBuf>,
        design: Option<String>,
        eye: Option<String>,
        doe: Option<PathBuf>,
        dcnn: Option<PathBuf>,
        backend: &str,
        cache: bool,
    ) -> PyResult<Self> {
        let design = design
            .as_deref()
            .map(nedrt_app::design::Design::resolve)
            .transpose()
            .map_err(|e| to_py(py, e))?;
        let backend = <BackendKind as nedrt_core::named::Named>::from_name(backend)
            .map_err(|e| bad(py, format!("backend: {e}")))?;
        let eye = match eye.as_deref() {
            None => Default::default(),
            Some(e) => {
                e.parse::<nedrt_studies::eval::eyes::EyeCase>()
                    .map_err(|why| bad(py, format!("eye: {why}")))?
                    .overrides
            }
        };
        let mut dcnn_options = nedrt_app::DcnnOptions {
            backend,
            backend_options: BackendOptions::default(),
            ..Default::default()
        };
        if let Some(p) = dcnn {
            dcnn_options.path = p;
        }
        let common = CommonOptions {
            calib,
            cache_dir: if cache { default_cache_dir() } else { None },
            doe: design.as_ref().map(|d| d.doe.clone()).or(doe),
            design,
            dcnn: dcnn_options,
            eye,
            ..Default::default()
        };
        // A bad calibration or eye is reported here, not at the first call.
        common.calibration().map_err(|e| to_py(py, e))?;
        Ok(Self { common })
    }

    /// The panel's size in pixels, (width, height).
    #[getter]
    fn panel(&self, py: Python<'_>) -> PyResult<(usize, usize)> {
        let c = self.common.calibration().map_err(|e| to_py(py, e))?;
        Ok((c.panel.width_px, c.panel.height_px))
    }

    /// perceived(image, accommodation_d, method=None, prefilter="native")
    /// -> numpy.ndarray
    ///
    /// What the eye sees of `image` (H×W×3 float32 in [0, 1]) through the
    /// display, accommodated at `accommodation_d` diopters: the method's
    /// display image (its preprocessing: the Wiener, a network, or
    /// `prefilter`, e.g. "refine:10") through its optics, on the retinal
    /// grid (2H×2W×3), as `nedrt sim --out` writes it. `method`: the
    /// shipped one by default ("proposed" where its network is here).
    #[pyo3(signature = (image, accommodation_d, method=None, prefilter="native"))]
    fn perceived<'py>(
        &self,
        py: Python<'py>,
        image: &Bound<'py, PyAny>,
        accommodation_d: f64,
        method: Option<&str>,
        prefilter: &str,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let (input, method, prefilter) = self.frame_args(image, method, prefilter)?;
        let common = &self.common;
        let frame = py
            .detach(|| {
                frames::simulate(
                    common,
                    &FrameRequest {
                        input: &input,
                        input_name: "image",
                        display_name: "display",
                        display: None,
                        optics: Optics::Doe,
                        accommodation_d,
                        accommodation_name: "accommodation_d",
                        method,
                        prefilter,
                        zones: ZoneRequest::default(),
                    },
                )
            })
            .map_err(|e| to_py(py, e))?;
        image_out(py, &frame.perceived)
    }

    /// prefilter(image, method=None, prefilter="refine:10") -> numpy.ndarray
    ///
    /// The display image (H×W×3, in [0, 1]) the method's optics get from
    /// `image` with `prefilter` ("native": the method's own), as `nedrt
    /// sim --display-out` writes it.
    #[pyo3(signature = (image, method=None, prefilter="refine:10"))]
    fn prefilter<'py>(
        &self,
        py: Python<'py>,
        image: &Bound<'py, PyAny>,
        method: Option<&str>,
        prefilter: &str,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let (input, method, prefilter) = self.frame_args(image, method, prefilter)?;
        let common = &self.common;
        let display = py
            .detach(|| frames::display_image(common, &input, method, prefilter))
            .map_err(|e| to_py(py, e))?;
        image_out(py, &display)
    }

    /// psfs(accommodation_d, method=None) -> numpy.ndarray
    ///
    /// The PSFs of the method's optics with the eye accommodated at
    /// `accommodation_d` diopters: one N×N float64 array per colour channel
    /// (C×N×N), each cell the fraction of the light that falls in it on the
    /// retinal grid, the axis at the centre; the light outside the window
    /// (a uniform veil) is `1 − psfs.sum(axis=(1, 2))`.
    #[pyo3(signature = (accommodation_d, method=None))]
    fn psfs<'py>(
        &self,
        py: Python<'py>,
        accommodation_d: f64,
        method: Option<&str>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let method = method_arg(py, method, &self.common)?;
        let common = &self.common;
        let (psfs, _) = py
            .detach(|| frames::psfs(common, method, accommodation_d, "accommodation_d"))
            .map_err(|e| to_py(py, e))?;
        let n = psfs.first().map_or(0, |p| p.window);
        let cells: Vec<f64> = psfs.iter().flat_map(|p| p.cells.iter().copied()).collect();
        PyArray1::from_vec(py, cells).reshape(vec![psfs.len(), n, n])
    }

    /// evaluate(images, methods=None, prefilters=("native",), designs=(),
    /// out_dir=None) -> dict
    ///
    /// `nedrt eval` on the images of a folder: every method (and design)
    /// with every prefilter, scored at the evaluation's depths. Returns
    /// its eval.json as a dict (the same numbers); with `out_dir`, also
    /// writes eval.md and eval.json there.
    #[pyo3(signature = (images, methods=None, prefilters=vec!["native".to_string()], designs=vec![], out_dir=None))]
    fn evaluate<'py>(
        &self,
        py: Python<'py>,
        images: PathBuf,
        methods: Option<Vec<String>>,
        prefilters: Vec<String>,
        designs: Vec<String>,
        out_dir: Option<PathBuf>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let methods = methods
            .unwrap_or_default()
            .iter()
            .map(|m| {
                m.parse::<Method>()
                    .map_err(|e| bad(py, format!("method: {e}")))
            })
            .collect::<PyResult<Vec<_>>>()?;
        let prefilters = prefilters
            .iter()
            .map(|p| prefilter_arg(py, p))
            .collect::<PyResult<Vec<_>>>()?;
        let designs = designs
            .iter()
            .map(|d| nedrt_app::design::Design::resolve(d).map_err(|e| to_py(py, e)))
            .collect::<PyResult<Vec<_>>>()?;
        let extras = nedrt_studies::eval::EvalExtras {
            designs,
            prefilters,
            ..Default::default()
        };
        let scratch = match &out_dir {
            Some(_) => None,
            None => Some(
                tempfile::tempdir()
                    .map_err(|e| raise(py, "NedrtError", format!("a temporary folder: {e}")))?,
            ),
        };
        let out = out_dir
            .clone()
            .or_else(|| scratch.as_ref().map(|d| d.path().to_path_buf()))
            .unwrap_or_default();
        let common = &self.common;
        let (result, _) = py
            .detach(|| nedrt_studies::eval::evaluate(common, &images, &out, &methods, &extras))
            .map_err(|e| to_py(py, e))?;
        let json = serde_json::to_string(&result)
            .map_err(|e| raise(py, "NedrtError", format!("the evaluation's result: {e}")))?;
        let parsed = py.import("json")?.call_method1("loads", (json,))?;
        Ok(parsed.cast_into::<PyDict>()?)
    }

    fn __repr__(&self) -> String {
        let c = &self.common;
        format!(
            "nedrt.Display(calib={}, design={}, doe={}, backend={:?})",
            c.calib.as_ref().map_or("embedded".into(), |p| format!(
                "{:?}",
                p.display().to_string()
            )),
            c.design
                .as_ref()
                .map_or("None".into(), |d| format!("{:?}", d.name)),
            c.doe
                .as_ref()
                .map_or("None".into(), |p| format!("{:?}", p.display().to_string())),
            c.dcnn.backend.name()
        )
    }
}

/// The extension module `nedrt._nedrt` (the package `nedrt` re-exports it).
#[pymodule]
fn _nedrt(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Display>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
