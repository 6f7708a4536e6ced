//! The simulator on frames held in memory: what `nedrt sim` computes for
//! an image file ([`crate::sim`] reads the file and calls [`simulate`]),
//! for an [`Image`] a caller already has (the Python package's
//! `nedrt.Display`). One path, so that both give the same numbers.

use super::{AppError, CommonOptions, check_accommodation_as};
use nedrt_optics::psf::Psf;
use nedrt_optics::sim::metrics::{psnr, ssim};
use nedrt_optics::sim::{Image, Method, Optics, Simulator, ZoneRequest};
use nedrt_stages::preprocess::Prefilter;

/// PSNR and SSIM of a perceived image against one reference.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Score {
    pub psnr_db: f64,
    pub ssim: f64,
}

impl Score {
    pub fn of(perceived: &Image, reference: &Image) -> Self {
        Self {
            psnr_db: psnr(perceived, reference),
            ssim: ssim(perceived, reference),
        }
    }
}

/// What to simulate: a method's preprocessing of `input` (or a display
/// image made elsewhere, seen through `optics`), perceived at one
/// accommodation.
#[derive(Debug, Clone, Copy)]
pub struct FrameRequest<'a> {
    pub input: &'a Image,
    /// What bad-input errors call the input and the display image (their
    /// files, or the caller's argument names).
    pub input_name: &'a str,
    pub display_name: &'a str,
    /// Simulate this display image instead of the method's preprocessing
    /// (the input's size).
    pub display: Option<&'a Image>,
    /// Optics the `display` image is seen through.
    pub optics: Optics,
    pub accommodation_d: f64,
    /// What errors call the accommodation (`--accom`, or the argument).
    pub accommodation_name: &'a str,
    pub method: Method,
    pub prefilter: Prefilter,
    pub zones: ZoneRequest,
}

/// A simulated frame: the display image, what the eye perceives, its
/// references and scores, and the lines `nedrt sim` reports of the run.
#[derive(Debug)]
pub struct Simulated {
    pub display: Image,
    /// On the retinal grid (twice the panel's resolution).
    pub perceived: Image,
    pub sharp: Image,
    pub target: Image,
    pub vs_sharp: Score,
    pub vs_target: Score,
    /// The simulator it ran on (its calibration, DOE and hash).
    pub sim: Simulator,
    /// The network of the method, if it has one: file, content, engine.
    pub network_line: Option<String>,
    /// Where the prefilter ran, where the method has one.
    pub engine_line: Option<String>,
    /// The field zones' summary, where the eye's pupil is the stop or a
    /// measured bundle has zones.
    pub zones_line: Option<String>,
    /// Each PSF model's sampling report.
    pub models: Vec<(String, String)>,
}

/// The method's display image of `req.input` and what the eye perceives of
/// it at `req.accommodation_d`, scored against the sharp image and the
/// multifocal target. Warnings (accommodation range, padding) go to
/// `tracing`.
pub fn simulate(common: &CommonOptions, req: &FrameRequest<'_>) -> Result<Simulated, AppError> {
    let calib = common.calibration()?;
    if let Some(w) = check_accommodation_as(&calib, req.accommodation_d, req.accommodation_name)? {
        tracing::warn!("{w}");
    }
    let input = req.input;
    // Below 8 pixels a side the scores mean nothing (SSIM needs an 11×11
    // window on the 2× retinal grid); `eval` refuses the same images.
    if input.width < 8 || input.height < 8 {
        return Err(AppError::input(
            req.input_name,
            format!("{}×{} pixels, smaller than 8×8", input.width, input.height),
        ));
    }
    if input.channels() != calib.channels.len() {
        return Err(AppError::Conflict(format!(
            "the input has {} channels, the calibration {}",
            input.channels(),
            calib.channels.len()
        )));
    }
    if let Some(d) = req.display {
        if (d.width, d.height, d.channels()) != (input.width, input.height, input.channels()) {
            return Err(AppError::input(
                req.display_name,
                format!(
                    "display image is {}×{}×{}, the input {} is {}×{}×{}; they must match",
                    d.width,
                    d.height,
                    d.channels(),
                    req.input_name,
                    input.width,
                    input.height,
                    input.channels()
                ),
            ));
        }
        if !req.prefilter.is_native() {
            return Err(AppError::Conflict(format!(
                "--prefilter {} makes a display image, --display-image gives one; use one of them",
                req.prefilter
            )));
        }
    }
    let method = match req.display {
        Some(_) => Method::unprocessed(req.optics),
        None => req.method,
    };
    let mut system = System::new(
        common,
        calib,
        method,
        req.prefilter,
        Some(req.accommodation_d),
    )?;
    let network_line = system.dcnns.get(&method).map(|n| match n.dcnn() {
        Some(d) => format!(
            "D-CNN     {} ({}, {:.0} MAC/pixel) on {}{}",
            d.model.path.display(),
            d.model.hash,
            d.network.macs_per_pixel,
            d.describe(),
            nedrt_stages::preprocess::stage_note(&d.model.path)
        ),
        None => format!("network   {}", n.line()),
    });
    if let Some(d) = system.dcnns.get(&method).and_then(|n| n.dcnn()) {
        let m = d.network.multiple;
        if !input.width.is_multiple_of(m) || !input.height.is_multiple_of(m) {
            tracing::warn!(
                "the input's {}×{} is not a multiple of {m}; the D-CNN pads it to {}×{} by \
                 reflection and crops its output back",
                input.width,
                input.height,
                input.width.div_ceil(m) * m,
                input.height.div_ceil(m) * m
            );
        }
    }
    let mut engine_line = None;
    let display = match req.display {
        Some(d) => d.clone(),
        None => {
            let mut engine = system.engine(common, method, req.prefilter)?;
            let display = engine.run(input)?;
            if !req.prefilter.is_native() || method.uses_wiener() {
                engine_line = Some(engine.describe());
            }
            display
        }
    };
    let System { sim, prepared, .. } = system;
    // Where the eye's pupil is the stop, the PSF changes across the field:
    // rendered by zones (the display image stays the centre's).
    let zoned = sim.field_zones(
        &prepared,
        method,
        &display,
        req.accommodation_d,
        req.zones,
        common.progress(),
    )?;
    let perceived = zoned.perceived(&prepared, method, &display, req.accommodation_d)?;
    let target = zoned.target(&prepared, input, req.accommodation_d)?;
    let sharp = input.up2();
    let vs_sharp = Score::of(&perceived, &sharp);
    let vs_target = Score::of(&perceived, &target);
    let zones_line = (sim.calib.eye.pupil_diameter_m.is_some()
        || sim
            .measured_bundle()
            .is_some_and(|b| b.card.zones.is_some()))
    .then(|| zoned.summary());
    let models = prepared
        .reports
        .iter()
        .map(|(name, r)| (name.clone(), r.summary()))
        .collect();
    Ok(Simulated {
        display,
        perceived,
        sharp,
        target,
        vs_sharp,
        vs_target,
        sim,
        network_line,
        engine_line,
        zones_line,
        models,
    })
}

/// The PSFs of `method`'s optics with the eye accommodated at
/// `accommodation_d`, one per colour channel, on the retinal grid (each
/// the fraction of the light in each cell; the window's centre is the
/// axis), as the simulator convolves the display image with. Errors call
/// the accommodation `accommodation_name` (`--at`, or the argument).
pub fn psfs(
    common: &CommonOptions,
    method: Method,
    accommodation_d: f64,
    accommodation_name: &str,
) -> Result<(Vec<Psf>, Simulator), AppError> {
    let (mut at, sim) = psfs_at(common, method, &[accommodation_d], accommodation_name)?;
    Ok((at.remove(0), sim))
}

/// [`psfs`] at each of `depths_d`, from one simulator prepared once.
pub fn psfs_at(
    common: &CommonOptions,
    method: Method,
    depths_d: &[f64],
    accommodation_name: &str,
) -> Result<(Vec<Vec<Psf>>, Simulator), AppError> {
    let calib = common.calibration()?;
    for &d in depths_d {
        if let Some(w) = check_accommodation_as(&calib, d, accommodation_name)? {
            tracing::warn!("{w}");
        }
    }
    let sim = common.measured(Simulator::new(
        calib,
        common.doe_path_for(&[method]).as_deref(),
        common.cache(),
    )?)?;
    let prepared = sim.prepare(&[method], depths_d, common.progress())?;
    let psfs = depths_d
        .iter()
        .map(|&d| prepared.system_psfs(method, d))
        .collect::<Result<Vec<_>, _>>()?;
    Ok((psfs, sim))
}

/// The display image `method` makes of `input` with `prefilter` (what
/// `nedrt sim --display-out` writes), without simulating the eye.
pub fn display_image(
    common: &CommonOptions,
    input: &Image,
    method: Method,
    prefilter: Prefilter,
) -> Result<Image, AppError> {
    let calib = common.calibration()?;
    if input.channels() != calib.channels.len() || input.width == 0 || input.height == 0 {
        return Err(AppError::Conflict(format!(
            "the input is {}×{} with {} channels; the calibration has {}",
            input.width,
            input.height,
            input.channels(),
            calib.channels.len()
        )));
    }
    let mut system = System::new(common, calib, method, prefilter, None)?;
    Ok(system.engine(common, method, prefilter)?.run(input)?)
}

/// A method's optics made ready for its display image: its networks, the
/// simulator (with their Wiener stages) and the PSFs of the prefilter's
/// depths (the objective's for an unrolled model), and of `extra_d`.
struct System {
    sim: Simulator,
    prepared: nedrt_optics::sim::Prepared,
    dcnns: std::collections::HashMap<Method, nedrt_stages::network::Network>,
}

impl System {
    fn new(
        common: &CommonOptions,
        calib: nedrt_core::calib::Calibration,
        method: Method,
        prefilter: Prefilter,
        extra_d: Option<f64>,
    ) -> Result<Self, AppError> {
        let dcnns = common.dcnn.load_for(&[method])?;
        let sim = common
            .measured(Simulator::new(
                calib,
                common.doe_path_for(&[method]).as_deref(),
                common.cache(),
            )?)?
            .with_wiener_stages(nedrt_stages::preprocess::wiener_stages(&dcnns)?);
        let mut depths = prefilter.depths_d(&sim.calib);
        if dcnns.values().any(|n| n.needs_objective_depths()) {
            depths = nedrt_optics::sim::objective_depths_d(&sim.calib);
        }
        depths.extend(extra_d);
        let prepared = sim.prepare(&[method], &depths, common.progress())?;
        Ok(Self {
            sim,
            prepared,
            dcnns,
        })
    }

    /// The engine that makes the display image: on the device with
    /// `--backend wgpu`, where the prefilter has a device stage.
    fn engine(
        &mut self,
        common: &CommonOptions,
        method: Method,
        prefilter: Prefilter,
    ) -> Result<Box<dyn nedrt_core::Preprocess>, AppError> {
        let gpu = crate::gpu_for(common, &[method], &[prefilter])?;
        Ok(nedrt_stages::device_prefilter::for_system_on(
            gpu.as_ref(),
            method,
            prefilter,
            &self.prepared,
            &mut self.dcnns,
        )?)
    }
}

/// `nedrt psf --at D`: [`psfs`] written to `out_dir/psfs.safetensors`
/// (tensor `psfs`, channel × N × N float64, and each channel's `veil`),
/// the file a notebook or `nedrt.Display.psfs` reads the same values from.
pub fn write_psfs(
    common: &CommonOptions,
    method: Method,
    accommodation_d: f64,
    out_dir: &std::path::Path,
) -> Result<String, AppError> {
    use safetensors::{Dtype, tensor::TensorView};
    // Computed first: a refused request leaves no folder behind.
    let (psfs, sim) = psfs(common, method, accommodation_d, "--at")?;
    crate::create_dir(out_dir)?;
    let path = out_dir.join("psfs.safetensors");
    let n = psfs.first().map_or(0, |p| p.window);
    let cells: Vec<u8> = psfs
        .iter()
        .flat_map(|p| p.cells.iter().flat_map(|v| v.to_le_bytes()))
        .collect();
    let veils: Vec<u8> = psfs.iter().flat_map(|p| p.veil.to_le_bytes()).collect();
    let out_err = |e: safetensors::SafeTensorError| AppError::output(&path, e.to_string());
    let tensors = vec![
        (
            "psfs".to_string(),
            TensorView::new(Dtype::F64, vec![psfs.len(), n, n], &cells).map_err(out_err)?,
        ),
        (
            "veil".to_string(),
            TensorView::new(Dtype::F64, vec![psfs.len()], &veils).map_err(out_err)?,
        ),
    ];
    let cell_arcmin = sim.calib.retinal_step_rad().to_degrees() * 60.0;
    let meta: std::collections::HashMap<String, String> = [
        ("format", "nedrt psfs 1".to_string()),
        ("method", method.name().to_string()),
        ("accommodation_d", accommodation_d.to_string()),
        ("doe", sim.doe_hash.clone()),
        ("calibration", sim.calib.source.clone()),
        ("cell_arcmin", cell_arcmin.to_string()),
        (
            "definition",
            "psfs[c, y, x]: the fraction of channel c's light in retinal cell (x, y), the axis \
             at the centre cell; veil[c]: the fraction outside the window (a uniform veil)"
                .to_string(),
        ),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    let data = safetensors::serialize(tensors, Some(meta))
        .map_err(|e| AppError::output(&path, e.to_string()))?;
    nedrt_core::util::write_atomic(&path, &data).map_err(|e| AppError::output(&path, e))?;
    Ok(format!(
        "wrote {} ({} PSFs of {} at {accommodation_d} D, {n}×{n} cells of {cell_arcmin:.3} arcmin; DOE {})\n",
        path.display(),
        psfs.len(),
        method.name(),
        sim.doe_hash
    ))
}
