//! `nedrt prefilter`: the display images one method and prefilter make for
//! a folder of images, as 32-bit float TIFFs (and all in one
//! `displays.safetensors`), and the objective's kernels
//! for the trainer (docs/optimal.md). The D-CNN recipe distils the
//! `optimal` images of the training photographs and trains on the exact
//! objective through the kernels (docs/training.md).

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use safetensors::Dtype;
use safetensors::tensor::TensorView;

use super::images::{list_images, load_all};
use super::{AppError, CommonOptions, create_dir, write_text};
use nedrt_core::image_io;
use nedrt_optics::sim::{Method, Objective, Simulator};
use nedrt_stages::device_prefilter::for_system_on;
use nedrt_stages::preprocess::Prefilter;

/// Options of `nedrt prefilter`.
#[derive(Debug, Clone)]
pub struct PrefilterOptions {
    pub images: PathBuf,
    pub out_dir: PathBuf,
    pub method: Method,
    pub prefilter: Prefilter,
    /// Also write the objective's kernels for patches of these sizes.
    pub operator_sizes: Vec<(usize, usize)>,
    /// The native Wiener prefilter's output before the panel's clamp.
    pub unclamped: bool,
    /// `--psfs`'s bundle averaged with its mirror images
    /// ([`nedrt_optics::bundle::PsfBundle::mirrored`]).
    pub mirror_psfs: bool,
}

/// The objective of a prefilter (the default one for `native`).
fn objective_of(p: Prefilter) -> Objective {
    p.objective().unwrap_or(Prefilter::DEFAULT_OBJECTIVE)
}

pub fn run(common: &CommonOptions, o: &PrefilterOptions) -> Result<String, AppError> {
    let start = Instant::now();
    if o.method.uses_dcnn() && o.prefilter.is_native() {
        return Err(AppError::Conflict(format!(
            "nedrt prefilter makes display images without a network; {} needs --prefilter lsq, \
             refine:K, admm:K or optimal",
            o.method
        )));
    }
    if o.unclamped && !(o.prefilter.is_native() && o.method.uses_wiener()) {
        return Err(AppError::Conflict(format!(
            "--unclamped writes a Wiener prefilter's output before the clamp; {} {} has none \
             (use a Wiener method with --prefilter native)",
            o.method, o.prefilter
        )));
    }
    if o.mirror_psfs && common.psfs.is_none() {
        return Err(AppError::option(
            "--mirror-psfs",
            "averages a measured bundle's PSFs: give the bundle with --psfs",
        ));
    }
    let files = list_images(&o.images)?;
    let images = load_all(&files, common.panel_px()?)?;
    let sim = Simulator::new(
        common.calibration()?,
        common.doe_path_for(&[o.method]).as_deref(),
        common.cache(),
    )?;
    // What optics the outputs were made for: the design's, a bundle's, or
    // a bundle's mirror average (and the share of a PSF that removed).
    let (sim, psfs) = match (common.bundle()?, o.mirror_psfs) {
        (None, _) => (sim, serde_json::Value::Null),
        (Some(bundle), mirror) => {
            let (used, asymmetry) = if mirror {
                let (m, a) = bundle.mirrored();
                (std::sync::Arc::new(m), Some(a))
            } else {
                (bundle.clone(), None)
            };
            let record = serde_json::json!({
                "bundle": bundle.path.display().to_string(),
                "psfs_blake3": bundle.card.psfs_blake3,
                "made_by": bundle.card.made_by,
                "mirrored": mirror,
                "asymmetry": asymmetry,
            });
            (sim.with_measured(used)?, record)
        }
    };
    let depths = nedrt_optics::sim::objective_depths_d(&sim.calib);
    let prepared = sim.prepare(&[o.method], &depths, common.progress())?;
    create_dir(&o.out_dir)?;
    let objective = objective_of(o.prefilter);
    let problem = prepared.display_problem(o.method, objective)?;
    let mut operators = Vec::new();
    for &(w, h) in &o.operator_sizes {
        let kernels = problem.mirrored_kernels(w, h).ok_or_else(|| {
            AppError::input(
                o.method,
                if psfs.is_null() {
                    "its PSFs are not mirror-symmetric, so the objective has no kernel form \
                     (--operator needs a rotationally symmetric system)"
                } else {
                    "the measured PSFs (--psfs) are not mirror-symmetric, so the objective has \
                     no kernel form: add --mirror-psfs to train on their mirror average"
                },
            )
        })?;
        let per_depth = problem
            .mirrored_depth_kernels(w, h)
            .ok_or_else(|| AppError::input(o.method, "no per-depth kernels"))?;
        let path = o.out_dir.join(format!("operator-{w}x{h}.safetensors"));
        let linear = problem.mirrored_linear_kernels(w, h);
        let kernels = Kernels {
            summed: &kernels,
            per_depth: &per_depth,
            linear: &linear,
            width: w,
            height: h,
        };
        write_kernels(&path, &kernels, &sim, o, &problem.depths_d, problem.k_reg)?;
        operators.push(path);
    }
    // On the device where `--backend wgpu` asks and the device runs the
    // prefilter (the device check's teacher: refine:K on the GPU).
    let gpu = crate::gpu_for(common, &[o.method], &[o.prefilter])?;
    let mut engine = for_system_on(
        gpu.as_ref(),
        o.method,
        o.prefilter,
        &prepared,
        &mut Default::default(),
    )?;
    let wiener = if o.unclamped {
        let filter = prepared.wiener(o.method).ok_or_else(|| {
            AppError::Unavailable(format!(
                "the Wiener filter of {} was not prepared",
                o.method
            ))
        })?;
        Some(filter)
    } else {
        None
    };
    let bar = common.phase("display images");
    bar.set_length(images.len() as u64);
    let mut written = Vec::new();
    let mut tensors: Vec<(String, Vec<u8>, Vec<usize>)> = Vec::new();
    for (file, input) in files.iter().zip(&images) {
        let display = match wiener {
            Some(filter) => filter.apply_unclamped(input),
            None => engine.run(input)?,
        };
        let stem = file
            .file_stem()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned();
        let path = o.out_dir.join(format!("{stem}.tif"));
        image_io::save(&display, &path, &["tif"])?;
        written.push(path);
        tensors.push((
            stem,
            display
                .data()
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect(),
            vec![display.channels(), display.height, display.width],
        ));
        bar.inc(1);
    }
    bar.finish_and_clear();
    // All of them in one file for the trainer (planar f32, by file stem).
    let path = o.out_dir.join("displays.safetensors");
    let views = tensors
        .iter()
        .map(|(name, bytes, shape)| {
            TensorView::new(Dtype::F32, shape.clone(), bytes)
                .map(|v| (name.clone(), v))
                .map_err(|e| AppError::output(&path, e.to_string()))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let data =
        safetensors::serialize(views, None).map_err(|e| AppError::output(&path, e.to_string()))?;
    nedrt_core::util::write_atomic(&path, &data).map_err(|e| AppError::output(&path, e))?;
    let manifest = serde_json::json!({
        "method": o.method.name(),
        "prefilter": o.prefilter.to_string(),
        "engine": engine.describe(),
        "unclamped": o.unclamped,
        "wiener_k": wiener.map(|f| f.k_reg),
        "calibration": sim.calib.source,
        "doe": sim.doe_hash,
        "psfs": psfs,
        "images": files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>(),
        "operators": operators.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "seconds": start.elapsed().as_secs_f64(),
    });
    let manifest_path = o.out_dir.join("prefilter.json");
    write_text(
        &manifest_path,
        &serde_json::to_string_pretty(&manifest)
            .map_err(|e| AppError::output(&manifest_path, e))?,
    )?;
    let mut t = String::new();
    let _ = writeln!(
        t,
        "nedrt prefilter: {} {}{} ({}), {} images → {}",
        o.method,
        o.prefilter,
        if o.unclamped { " unclamped" } else { "" },
        engine.describe(),
        written.len(),
        o.out_dir.display()
    );
    if let Some(bundle) = psfs["bundle"].as_str() {
        let _ = match psfs["asymmetry"].as_f64() {
            Some(a) => writeln!(
                t,
                "psfs      {bundle}, mirror-averaged: {:.1} % of its least symmetric PSF dropped{}",
                100.0 * a,
                if a > 0.05 {
                    " (the outputs are for optics that differ from the measured ones by that much)"
                } else {
                    ""
                }
            ),
            None => writeln!(t, "psfs      {bundle}"),
        };
    }
    for p in &operators {
        let _ = writeln!(t, "operator  {}", p.display());
    }
    let _ = write!(t, "time      {:.1} s", start.elapsed().as_secs_f64());
    Ok(t)
}

/// The objective's kernels for one patch size: summed over the depths, and
/// per depth; and the `lsq` prefilter's (the split solver's start).
struct Kernels<'a> {
    summed: &'a [[Vec<f32>; 3]],
    per_depth: &'a [Vec<[Vec<f32>; 3]>],
    linear: &'a [Vec<f32>],
    width: usize,
    height: usize,
}

fn write_kernels(
    path: &Path,
    k: &Kernels,
    sim: &Simulator,
    o: &PrefilterOptions,
    depths_d: &[f64],
    k_reg: f64,
) -> Result<(), AppError> {
    let names = ["normal", "adjoint_target", "target_gram"];
    let (w, h) = (k.width, k.height);
    let channels = k.summed.len();
    let mut tensors: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    for (i, name) in names.iter().enumerate() {
        let bytes = |per_channel: &[[Vec<f32>; 3]]| -> Vec<u8> {
            per_channel
                .iter()
                .flat_map(|c| c[i].iter().flat_map(|v| v.to_le_bytes()))
                .collect()
        };
        tensors.push((
            name.to_string(),
            vec![channels, 2 * h, 2 * w],
            bytes(k.summed),
        ));
        tensors.push((
            format!("{name}_per_depth"),
            vec![k.per_depth.len(), channels, 2 * h, 2 * w],
            k.per_depth.iter().flat_map(|d| bytes(d)).collect(),
        ));
    }
    tensors.push((
        "linear".to_string(),
        vec![channels, 2 * h, 2 * w],
        k.linear
            .iter()
            .flat_map(|c| c.iter().flat_map(|v| v.to_le_bytes()))
            .collect(),
    ));
    let views = tensors
        .iter()
        .map(|(n, shape, b)| {
            TensorView::new(Dtype::F32, shape.clone(), b)
                .map(|v| (n.clone(), v))
                .map_err(|e| AppError::output(path, e.to_string()))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let meta: HashMap<String, String> = [
        ("format", "nedrt objective kernels 1".to_string()),
        ("method", o.method.name().to_string()),
        ("objective", objective_of(o.prefilter).name().to_string()),
        ("doe", sim.doe_hash.clone()),
        ("calibration", sim.calib.source.clone()),
        ("depths_d", format!("{depths_d:?}")),
        ("k_reg", k_reg.to_string()),
        ("width", w.to_string()),
        ("height", h.to_string()),
        (
            "definition",
            "per channel, on the mirrored 2h×2w display grid (periodic, origin at [0, 0]): \
             ½ Σ_D ‖A_D d − t_D‖² = ¼ (½ d̃·(normal ⊛ d̃) − d̃·(adjoint_target ⊛ Ĩ) + ½ Ĩ·(target_gram ⊛ Ĩ)); \
             the *_per_depth tensors (depth × channel × 2h × 2w) give each depth's ½ ‖A_D d − t_D‖² alike; \
             linear (channel × 2h × 2w): the lsq prefilter before the clamp, lsq(I) = first quadrant of linear ⊛ Ĩ"
                .to_string(),
        ),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    let data = safetensors::serialize(views, Some(meta))
        .map_err(|e| AppError::output(path, e.to_string()))?;
    nedrt_core::util::write_atomic(path, &data).map_err(|e| AppError::output(path, e))
}
