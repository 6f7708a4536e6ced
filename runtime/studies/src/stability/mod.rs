//! `nedrt stability`: every method tried where it is known to fail, with
//! the numbers written to `docs/stability.md` (and `.json`) and, for each
//! failure, the error or warning that guards it and the test that checks
//! the guard. Sections: the Wiener constant K (with and without noise in
//! the frame), the D-CNN off its training distribution (accommodations,
//! content, frame sizes), the optics beyond their sampling, and f16
//! against f32 on the GPU, and a panning photograph (flicker).

//!
//! Model and report are apart: each section computes typed rows
//! ([`wiener`], [`dcnn`], [`optics`]), [`report`] renders the Markdown from
//! them, and the JSON is the same rows serialised.

pub mod dcnn;
pub mod optics;
pub mod report;
pub mod temporal;
pub mod wiener;

use std::path::PathBuf;
use std::time::Instant;

use serde::Serialize;

use super::eval::{list_images, load_all};
use super::{AppError, CommonOptions, check_output_folder, write_text};
use nedrt_infer::synth::SplitMix;
use nedrt_infer::{BackendKind, BackendOptions, Dcnn};
use nedrt_optics::sim::{Image, Method, Simulator};

/// What the study runs on.
#[derive(Debug, Clone)]
pub struct StabilityOptions {
    pub images_dir: PathBuf,
    /// The Markdown report; the JSON goes beside it.
    pub out: PathBuf,
    /// The trained D-CNN (its DOE beside it).
    pub model: PathBuf,
    /// Side of the synthetic content frames.
    pub content_size: usize,
    /// Also compare f16 with f32 on the wgpu adapter.
    pub gpu: bool,
    /// Display designs whose Wiener K is swept beside the D-CNN's DOE.
    pub designs: Vec<super::design::Design>,
    /// Eyes the Wiener sweeps are repeated for (AI and each design), beside
    /// the calibration's (`--eyes`, as `nedrt eval --eyes` names them).
    pub eyes: Vec<super::eval::eyes::EyeCase>,
}

/// Wiener K values of the sweep: decades from 1e-6 to 10.
pub const K_SWEEP: [f64; 8] = [1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0];
/// Standard deviation of the noise added to the frame for the noisy sweep.
pub const FRAME_NOISE_SIGMA: f32 = 0.02;
/// Accommodations the D-CNN was not trained at (and the trained ones).
pub const DEPTHS_D: [f64; 8] = [0.25, 0.5, 0.75, 1.5, 2.5, 2.75, 3.5, 5.0];

/// `image` with Gaussian noise of σ = [`FRAME_NOISE_SIGMA`], clamped.
fn noisy(image: &Image, seed: u64) -> Image {
    let mut rng = SplitMix::new(seed);
    let planes = image
        .planes()
        .map(|p| {
            p.iter()
                .map(|v| (v + FRAME_NOISE_SIGMA * rng.normal()).clamp(0.0, 1.0))
                .collect()
        })
        .collect();
    Image::from_planes(image.width, image.height, planes)
}

/// Everything the study measured, section by section.
#[derive(Debug, Clone, Serialize)]
pub struct StabilityStudy {
    pub images: Vec<String>,
    pub calibration: String,
    pub model: String,
    pub model_hash: String,
    pub doe_hash: String,
    pub wiener: wiener::WienerSection,
    pub dcnn: dcnn::DcnnSection,
    pub sizes: Vec<dcnn::SizeRow>,
    pub optics: optics::OpticsSection,
    pub f16: dcnn::F16Section,
    pub temporal: temporal::TemporalSection,
    pub seconds: f64,
}

/// Runs every section and writes the report.
pub fn run(common: &CommonOptions, o: &StabilityOptions) -> Result<String, AppError> {
    let start = Instant::now();
    let files = list_images(&o.images_dir)?;
    let inputs = load_all(&files, common.panel_px()?)?;
    let doe = o.model.with_extension("doe.safetensors");
    if !doe.exists() {
        return Err(AppError::input(
            o.model.display(),
            format!("no DOE beside this D-CNN ({} is missing)", doe.display()),
        ));
    }
    check_output_folder(&o.out)?;
    let wiener_k = match crate::preprocess::dcnn_input(&o.model)? {
        crate::preprocess::DcnnInput::Frame => None,
        crate::preprocess::DcnnInput::WienerRaw { k_reg } => Some(k_reg),
    };
    let sim = common
        .measured(Simulator::new(
            common.calibration()?,
            Some(&doe),
            common.cache(),
        )?)?
        .with_wiener_stages(if wiener_k.is_some() {
            vec![Method::Proposed]
        } else {
            Vec::new()
        });
    let mut dcnn = Dcnn::load(&o.model, BackendKind::Cpu, &BackendOptions::default())?;
    let bar = common.phase("sections");
    bar.set_length(6);
    let design_sims = o
        .designs
        .iter()
        .map(|d| {
            Ok((
                d.name.as_str(),
                d.simulator(sim.calib.clone(), common.cache())?,
            ))
        })
        .collect::<Result<Vec<_>, AppError>>()?;
    // Each eye: the AI display and every design through it.
    let eye_sims = o
        .eyes
        .iter()
        .map(|eye| {
            // Each simulator keeps its own calibration (a design's K) with the eye.
            let through = |s: &Simulator| -> Result<Simulator, AppError> {
                let mut calib = s.calib.clone();
                eye.overrides.apply(&mut calib)?;
                Ok(s.with_calibration(calib))
            };
            let designs = design_sims
                .iter()
                .map(|(n, s)| Ok((*n, through(s)?)))
                .collect::<Result<Vec<_>, AppError>>()?;
            Ok((eye.label.as_str(), through(&sim)?, designs))
        })
        .collect::<Result<Vec<_>, AppError>>()?;
    let case = |design, eye, sim, method| wiener::SweepCase {
        design,
        eye,
        sim,
        method,
    };
    let mut sweeps = vec![
        case("", None, &sim, Method::Ai),
        case("", None, &sim, Method::DoeWiener),
    ];
    sweeps.extend(
        design_sims
            .iter()
            .map(|(n, s)| case(n, None, s, Method::DoeWiener)),
    );
    for (label, eye_sim, designs) in &eye_sims {
        sweeps.push(case("", Some(label), eye_sim, Method::Ai));
        sweeps.extend(
            designs
                .iter()
                .map(|(n, s)| case(n, Some(label), s, Method::DoeWiener)),
        );
    }
    let wiener = wiener::sweep(&sweeps, &inputs)?;
    bar.inc(1);
    let (dcnn_section, base) =
        dcnn::depths_and_content(&sim, &mut dcnn, wiener_k, &inputs, o.content_size)?;
    bar.inc(1);
    let sizes = dcnn::sizes(&mut dcnn, &base.network_input(&inputs[0]))?;
    bar.inc(1);
    let optics = optics::section(&sim)?;
    bar.inc(1);
    let f16 = if o.gpu {
        dcnn::f16_against_f32(&o.model, &base, &inputs[0], o.content_size)?
    } else {
        dcnn::F16Section::Skipped
    };
    // The pan: every method on a moving photograph (the first image).
    let depths = nedrt_optics::sim::objective_depths_d(&sim.calib);
    let temporal_prepared = sim.prepare(
        &[
            Method::Conventional,
            Method::Ai,
            Method::DoeOnly,
            Method::DoeWiener,
            Method::Proposed,
        ],
        &depths,
        common.progress(),
    )?;
    let network = Dcnn::load(&o.model, BackendKind::Cpu, &BackendOptions::default())?;
    let proposed = crate::preprocess::dcnn_system(Method::Proposed, network, &temporal_prepared)?;
    let temporal = temporal::section(
        &temporal_prepared,
        depths,
        &files[0].display().to_string(),
        &inputs[0],
        Some(proposed),
    )?;
    bar.inc(1);
    bar.finish_and_clear();
    let study = StabilityStudy {
        images: files.iter().map(|f| f.display().to_string()).collect(),
        calibration: sim.calib.source.clone(),
        model: o.model.display().to_string(),
        model_hash: dcnn.model.hash.clone(),
        doe_hash: sim.doe_hash.clone(),
        wiener,
        dcnn: dcnn_section,
        sizes,
        optics,
        f16,
        temporal,
        seconds: start.elapsed().as_secs_f64(),
    };
    let md = report::markdown(&study);
    let json_path = o.out.with_extension("json");
    let text = serde_json::to_string_pretty(&study).map_err(|e| AppError::output(&json_path, e))?;
    write_text(&json_path, &text)?;
    write_text(&o.out, &md)?;
    Ok(format!(
        "{md}\nwrote {} and {}\n",
        o.out.display(),
        json_path.display()
    ))
}
