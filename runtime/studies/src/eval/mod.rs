//! `nedrt eval`: the paper's Fig. 6 table for every method at 0…3 D on a
//! folder of images, against the sharp image and the multifocal target
//! (docs/model.md §17), with the headline mean and worst over 0–2.5 D; with
//! focus cues on, also each method's perceived sharpness across the whole
//! accommodation range (app::focus_cues), from the same renders.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use super::design::Design;
use super::focus_cues::{self, FocusCueDefinition, FocusCues, FocusSweep};
use super::sim::Score;
use super::{AppError, CommonOptions, create_dir, write_text};
use crate::device_prefilter::for_system_on;
use crate::preprocess::Prefilter;
pub use nedrt_app::images::{list_images, load_all, load_cropped};
use nedrt_core::Preprocess;
use nedrt_optics::sim::{Image, Method, Optics, Prepared, Simulator};

/// Upper end of the headline depth range (docs/model.md §17: 0–2.5 D).
pub const HEADLINE_MAX_D: f64 = nedrt_optics::sim::HEADLINE_MAX_D;

#[derive(Debug, Clone, Serialize)]
pub struct ImageScore {
    pub image: String,
    pub vs_sharp: Score,
    pub vs_target: Score,
}

#[derive(Debug, Clone, Serialize)]
pub struct DepthRow {
    pub accommodation_d: f64,
    pub vs_sharp: Score,
    pub vs_target: Score,
    pub per_image: Vec<ImageScore>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Headline {
    pub mean: Score,
    pub worst: Score,
}

#[derive(Debug, Clone, Serialize)]
pub struct MethodResult {
    pub method: String,
    /// Content hash of the DOE, for methods with one in the eyepiece.
    pub doe: Option<String>,
    pub rows: Vec<DepthRow>,
    pub headline_vs_sharp: Headline,
    pub headline_vs_target: Headline,
    /// Perceived sharpness across accommodation, when measured.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub focus_cues: Option<FocusCues>,
}

#[derive(Debug, Clone, Serialize)]
pub struct EvalResult {
    pub calibration: String,
    pub images: Vec<String>,
    pub methods: Vec<MethodResult>,
    /// Methods left out of this run (add them with --methods).
    pub not_evaluated: Vec<String>,
    /// The D-CNN behind each D-CNN method: file, content hash, backend.
    pub dcnn: Vec<String>,
    /// How the focus cues were measured, when they were.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub focus_cue_definition: Option<FocusCueDefinition>,
    /// Chart files written beside the tables.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub charts: Vec<String>,
    pub seconds: f64,
}

fn mean_score(s: &[Score]) -> Score {
    let n = s.len().max(1) as f64;
    Score {
        psnr_db: s.iter().map(|x| x.psnr_db).sum::<f64>() / n,
        ssim: s.iter().map(|x| x.ssim).sum::<f64>() / n,
    }
}

fn headline(rows: &[DepthRow], pick: impl Fn(&DepthRow) -> Score) -> Headline {
    let s: Vec<Score> = rows
        .iter()
        .filter(|r| r.accommodation_d <= HEADLINE_MAX_D + 1e-9)
        .map(pick)
        .collect();
    Headline {
        mean: mean_score(&s),
        worst: Score {
            psnr_db: s.iter().map(|x| x.psnr_db).fold(f64::INFINITY, f64::min),
            ssim: s.iter().map(|x| x.ssim).fold(f64::INFINITY, f64::min),
        },
    }
}

/// Display images made elsewhere (e.g. by the trainer's D-CNN): for every
/// input `NAME.ext`, `dir/NAME.ext` (same size) is shown through `optics`.
#[derive(Debug, Clone)]
pub struct ExternalDisplays {
    pub name: String,
    pub dir: PathBuf,
    pub optics: Optics,
}

impl ExternalDisplays {
    /// The built-in method whose PSFs (and no preprocessing) the row uses.
    fn psf_method(&self) -> Method {
        Method::unprocessed(self.optics)
    }

    /// The display image of `input_file`, cropped to multiples of 8 like
    /// its input; its size must then equal the input's.
    fn load(&self, input_file: &Path, input: &Image) -> Result<Image, AppError> {
        let name = input_file
            .file_name()
            .ok_or_else(|| AppError::input(input_file.display(), "no file name"))?;
        let path = self.dir.join(name);
        // Its size must equal the input's after cropping: nothing larger is decoded.
        let im = load_cropped(&path, (input.width + 7, input.height + 7))?;
        if (im.width, im.height) != (input.width, input.height) {
            return Err(AppError::input(
                path.display(),
                format!(
                    "display image is {}×{}, its input {} is {}×{} after cropping to multiples of 8; the sizes must match",
                    im.width,
                    im.height,
                    input_file.display(),
                    input.width,
                    input.height
                ),
            ));
        }
        Ok(im)
    }
}

/// The sorted union of two depth lists (depths within 1e-9 D are one).
fn union_d(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut all: Vec<f64> = a.iter().chain(b).copied().collect();
    all.sort_by(f64::total_cmp);
    all.dedup_by(|x, y| (*x - *y).abs() < 1e-9);
    all
}

/// What `nedrt eval` compares besides the built-in methods.
#[derive(Debug, Clone, Default)]
pub struct EvalExtras {
    /// Display images made elsewhere, as one more row.
    pub external: Option<ExternalDisplays>,
    /// Display designs, one `doe+wiener NAME` row each (its DOE, its K).
    pub designs: Vec<Design>,
    /// Also measure the focus cues.
    pub focus_cues: bool,
    /// Also write a focus sweep of every image into this folder.
    pub sweeps: Option<PathBuf>,
    /// How each method's and design's display image is made, one row per
    /// method (or design) and prefilter, in this order; empty = native.
    pub prefilters: Vec<Prefilter>,
}

/// One row of the tables: a method seen through one simulator, its display
/// image made by `engine` (none: loaded from the external folder).
struct Row<'a> {
    name: String,
    method: Method,
    prepared: &'a Prepared,
    doe_hash: Option<String>,
    engine: Option<Box<dyn Preprocess>>,
}

/// Runs the evaluation and writes `eval.md` and `eval.json` into `out_dir`;
/// with `focus_cues`, also the sharpness sweep and its chart
/// (`focus_cues.png`, `.svg`).
pub fn run(
    common: &CommonOptions,
    images_dir: &Path,
    out_dir: &Path,
    methods: &[Method],
    extras: &EvalExtras,
) -> Result<String, AppError> {
    Ok(evaluate(common, images_dir, out_dir, methods, extras)?.1)
}

/// [`run`], with the typed result beside the report.
pub fn evaluate(
    common: &CommonOptions,
    images_dir: &Path,
    out_dir: &Path,
    methods: &[Method],
    extras: &EvalExtras,
) -> Result<(EvalResult, String), AppError> {
    let external = extras.external.as_ref();
    let start = Instant::now();
    let files = list_images(images_dir)?;
    let images = load_all(&files, common.panel_px()?)?;
    create_dir(out_dir)?;
    if let Some(dir) = &extras.sweeps {
        create_dir(dir)?;
    }
    let methods: Vec<Method> = if methods.is_empty() {
        common.default_methods()
    } else {
        methods.to_vec()
    };
    let mut dcnns = common.dcnn.load_for(&methods)?;
    let dcnn_lines = crate::preprocess::dcnn_lines(&dcnns, &methods);
    let sim = common
        .measured(Simulator::new(
            common.calibration()?,
            common.doe_path_for(&methods).as_deref(),
            common.cache(),
        )?)?
        .with_wiener_stages(crate::preprocess::wiener_stages(&dcnns)?);
    let design_sims = extras
        .designs
        .iter()
        .map(|d| d.simulator(sim.calib.clone(), common.cache()))
        .collect::<Result<Vec<_>, _>>()?;
    let prefilters = if extras.prefilters.is_empty() {
        vec![Prefilter::Native]
    } else {
        extras.prefilters.clone()
    };
    let depths = sim.calib.evaluation_depths_d();
    let rows =
        (methods.len() + design_sims.len()) * prefilters.len() + usize::from(external.is_some());
    let mut sweep = extras.focus_cues.then(|| FocusSweep::new(&sim.calib, rows));
    // Every depth rendered: the table's, and the sweep's; the PSFs of both
    // (and of the prefilters' objective) go into one request per optics, so
    // a later run loads them.
    let rendered = match &sweep {
        Some(s) => union_d(&depths, &s.depths_d),
        None => depths.clone(),
    };
    let prepared_depths = union_d(&rendered, &Prefilter::all_depths_d(&prefilters, &sim.calib));
    let mut needed = methods.clone();
    needed.extend(external.map(|e| e.psf_method()));
    let prepared = sim.prepare(&needed, &prepared_depths, common.progress())?;
    let design_prepared = design_sims
        .iter()
        .map(|s| s.prepare(&[Method::DoeWiener], &prepared_depths, common.progress()))
        .collect::<Result<Vec<_>, _>>()?;
    let doe_hash = |optics: Optics| (optics == Optics::Doe).then(|| sim.doe_hash.clone());
    // With --backend wgpu the prefilters run on the device too.
    let mut all_methods = methods.clone();
    if !design_prepared.is_empty() {
        all_methods.push(Method::DoeWiener);
    }
    let gpu = crate::gpu_for(common, &all_methods, &prefilters)?;
    let mut row_specs: Vec<Row> = Vec::with_capacity(rows);
    for &m in &methods {
        for &p in &prefilters {
            row_specs.push(Row {
                name: p.label(m.name()),
                method: m,
                prepared: &prepared,
                doe_hash: doe_hash(m.optics()),
                engine: Some(for_system_on(gpu.as_ref(), m, p, &prepared, &mut dcnns)?),
            });
        }
    }
    if let Some(e) = external {
        row_specs.push(Row {
            name: e.name.clone(),
            method: e.psf_method(),
            prepared: &prepared,
            doe_hash: doe_hash(e.optics),
            engine: None,
        });
    }
    for ((d, s), p) in extras
        .designs
        .iter()
        .zip(&design_sims)
        .zip(&design_prepared)
    {
        for &pf in &prefilters {
            row_specs.push(Row {
                name: pf.label(&format!("{} {}", Method::DoeWiener.name(), d.name)),
                method: Method::DoeWiener,
                prepared: p,
                doe_hash: Some(s.doe_hash.clone()),
                engine: Some(for_system_on(
                    gpu.as_ref(),
                    Method::DoeWiener,
                    pf,
                    p,
                    &mut dcnns,
                )?),
            });
        }
    }

    let bar = common.phase(if sweep.is_some() {
        "focus sweep"
    } else {
        "images"
    });
    bar.set_length((images.len() * rows * rendered.len()) as u64);
    // scores[row][depth][image], rows in `row_specs` order.
    let mut scores = vec![vec![Vec::new(); depths.len()]; rows];
    for (file, input) in files.iter().zip(&images) {
        let sharp = input.up2();
        if let Some(s) = &mut sweep {
            s.start_image(&sharp);
        }
        let targets: Vec<Image> = depths
            .iter()
            .map(|d| prepared.target(input, *d))
            .collect::<Result<_, _>>()?;
        let displays: Vec<Image> = row_specs
            .iter_mut()
            .map(|row| match &mut row.engine {
                Some(engine) => Ok(engine.run(input)?),
                None => match external {
                    Some(e) => e.load(file, input),
                    None => Err(AppError::Internal("a row without a display image".into())),
                },
            })
            .collect::<Result<_, AppError>>()?;
        for (mi, (row, display)) in row_specs.iter().zip(&displays).enumerate() {
            for &d in &rendered {
                let perceived = row.prepared.perceived(row.method, display, d)?;
                if let Some(di) = depths.iter().position(|x| (x - d).abs() < 1e-9) {
                    scores[mi][di].push(ImageScore {
                        image: file.display().to_string(),
                        vs_sharp: Score::of(&perceived, &sharp),
                        vs_target: Score::of(&perceived, &targets[di]),
                    });
                }
                if let Some(s) = &mut sweep
                    && let Some(si) = s.index_of(d)
                {
                    s.record(mi, si, &perceived);
                }
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    let mut cues: Vec<Option<FocusCues>> = match sweep {
        Some(s) => s.finish(&sim.calib.main_d).into_iter().map(Some).collect(),
        None => vec![None; rows],
    };

    let results: Vec<MethodResult> = row_specs
        .iter()
        .zip(scores)
        .zip(cues.iter_mut())
        .map(|((row, per_depth), cues)| {
            let rows: Vec<DepthRow> = depths
                .iter()
                .zip(per_depth)
                .map(|(d, per_image)| DepthRow {
                    accommodation_d: *d,
                    vs_sharp: mean_score(&per_image.iter().map(|s| s.vs_sharp).collect::<Vec<_>>()),
                    vs_target: mean_score(
                        &per_image.iter().map(|s| s.vs_target).collect::<Vec<_>>(),
                    ),
                    per_image,
                })
                .collect();
            MethodResult {
                method: row.name.clone(),
                doe: row.doe_hash.clone(),
                headline_vs_sharp: headline(&rows, |r| r.vs_sharp),
                headline_vs_target: headline(&rows, |r| r.vs_target),
                rows,
                focus_cues: cues.take(),
            }
        })
        .collect();
    let cue_rows: Vec<(&str, &FocusCues)> = results
        .iter()
        .filter_map(|m| m.focus_cues.as_ref().map(|c| (m.method.as_str(), c)))
        .collect();
    let charts = if cue_rows.is_empty() {
        Vec::new()
    } else {
        focus_cues::write_chart(out_dir, &cue_rows, &sim.calib.main_d, sim.calib.range_d)?
    };
    let result = EvalResult {
        calibration: sim.calib.source.clone(),
        images: files.iter().map(|f| f.display().to_string()).collect(),
        methods: results,
        not_evaluated: Method::ALL
            .iter()
            .filter(|m| !methods.contains(m))
            .map(|m| m.name().to_string())
            .collect(),
        dcnn: dcnn_lines,
        focus_cue_definition: extras.focus_cues.then(FocusCueDefinition::current),
        charts,
        seconds: start.elapsed().as_secs_f64(),
    };
    let mut md = markdown(&result, &sim);
    for (d, s) in extras.designs.iter().zip(&design_sims) {
        let _ = writeln!(
            md,
            "- Design {}: {} (DOE {}, {}), Wiener K {}.",
            d.name,
            d.source.display(),
            s.doe_hash,
            s.doe.description,
            s.calib.wiener.doe_k
        );
    }
    for (name, r) in &prepared.reports {
        let _ = writeln!(md, "- PSF model, {name}: {}", r.summary());
    }
    for (d, p) in extras.designs.iter().zip(&design_prepared) {
        for (name, r) in &p.reports {
            let _ = writeln!(md, "- PSF model, {name} ({}): {}", d.name, r.summary());
        }
    }
    let md_path = out_dir.join("eval.md");
    let json_path = out_dir.join("eval.json");
    write_text(&md_path, &md)?;
    let json =
        serde_json::to_string_pretty(&result).map_err(|e| AppError::output(&json_path, e))?;
    write_text(&json_path, &json)?;
    let mut written = vec![
        md_path.display().to_string(),
        json_path.display().to_string(),
    ];
    written.extend(result.charts.iter().cloned());
    if let Some(dir) = &extras.sweeps {
        let stem = |f: &PathBuf| {
            f.file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "image".into())
        };
        for (file, image) in files.iter().zip(&images) {
            // a.png and a.jpg would share a stem: then the whole name.
            let shared = files.iter().filter(|f| stem(f) == stem(file)).count() > 1;
            let name = if shared {
                file.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_else(|| stem(file))
            } else {
                stem(file)
            };
            let out = dir.join(format!("{name}.png"));
            let opts = crate::viewer::SweepOptions {
                from_d: sim.calib.range_d[0],
                to_d: sim.calib.range_d[1],
                step_d: 0.1,
                fps: 8.0,
                out: out.clone(),
            };
            let name = file.display().to_string();
            crate::viewer::sweep_image(common, &sim.calib, image.clone(), name, &methods, &opts)?;
            written.push(out.display().to_string());
        }
    }
    Ok((result, format!("{md}\nwrote {}\n", written.join(", "))))
}

pub mod eyes;
mod report;
pub use report::markdown;
