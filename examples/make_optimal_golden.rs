//! Writes tests/golden/optimal.json: a small bounded least-squares display
//! problem and nedrt's optimum of it, for the independent check with
//! scipy's L-BFGS-B (models/tests/test_optimal.py) and for
//! `the_golden_optimum_is_what_the_solver_gives` (nedrt-optics):
//!
//!     cargo run --release --example make_optimal_golden [-- OUT.json]
//!
//! The problem is the multifocal design's: its system PSFs at the headline
//! depths and the target blur, every channel, each cut to a 21-cell window
//! (the light outside joins the veil, so each stays a valid PSF), and a
//! 24×16 crop of a training photograph. The design's PSFs must be in the
//! PSF cache or are computed (minutes).
//!
//! Layout: `width`, `height`, `objective`, `depths_d`, `blurred` (per
//! depth), `k_reg`; `input` and `optimum`: planes (channel-major, row-major,
//! values in [0, 1]); `psfs[channel][depth]` and `blur[channel]`: `window`,
//! `cells` (row-major, rows along y), `veil`; `objective_value[channel]`:
//! ½ Σ_D ‖A_D d − t_D‖² at `optimum`, A_D d = crop(up2(d) ∗ h_D) +
//! veil_D · mean(d) with symmetric (half-sample) extension, t_D = up2(I) or,
//! where `blurred`, crop(up2(I) ∗ h_b) + veil_b · mean(I); `kernels`: the
//! same objective as `nedrt prefilter --operator` writes it for the trainer
//! (`normal`, `adjoint_target`, `target_gram`, each [channel][2h][2w],
//! and each per depth, `NAME_per_depth`, [depth][channel][2h][2w]).

use std::path::PathBuf;

use nedrt_optics::Psf;
use nedrt_optics::sim::{DisplayProblem, Method, Objective, SolveOptions, objective_depths_d};
use serde_json::json;

/// Window of the golden's PSFs, cells.
const WINDOW: usize = 21;
const INPUT: &str = "data/images/train/butterfly.png";
const CROP: (usize, usize, usize, usize) = (120, 96, 24, 16);

/// The centre `WINDOW` cells of a PSF; the rest of its light becomes veil.
fn cut(p: &Psf) -> Psf {
    let (w, half) = (p.window, WINDOW / 2);
    let c = w / 2;
    let mut cells = Vec::with_capacity(WINDOW * WINDOW);
    for y in c - half..=c + half {
        cells.extend_from_slice(&p.cells[y * w + c - half..=y * w + c + half]);
    }
    let kept: f64 = cells.iter().sum();
    let total: f64 = p.cells.iter().sum::<f64>() + p.veil;
    Psf {
        window: WINDOW,
        cells,
        veil: total - kept,
    }
}

fn psf_json(p: &Psf) -> serde_json::Value {
    json!({"window": p.window, "cells": p.cells, "veil": p.veil})
}

fn main() -> anyhow::Result<()> {
    let out = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("tests/golden/optimal.json"));
    let calib = nedrt_core::calib::Calibration::default_embedded()?;
    let cache = nedrt_optics::cache::PsfCache::at(
        std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/nedrt")),
    );
    let sim = nedrt_app::design::Design::resolve("multifocal")?.simulator(calib, cache)?;
    let depths = objective_depths_d(&sim.calib);
    let prepared = sim.prepare(&[Method::DoeWiener], &depths, &nedrt_core::progress::Silent)?;
    let full = prepared.display_problem(Method::DoeWiener, Objective::Target)?;
    let channels = sim.calib.channels.len();
    let mut psfs = vec![Vec::new(); channels];
    for d in &depths {
        for (c, p) in prepared
            .system_psfs(Method::DoeWiener, *d)?
            .iter()
            .enumerate()
        {
            psfs[c].push(cut(p));
        }
    }
    let blur: Vec<Psf> = prepared.target_blur_psfs()?.iter().map(cut).collect();
    let blurred: Vec<bool> = depths
        .iter()
        .map(|d| !sim.calib.is_main_depth(*d))
        .collect();
    let problem = DisplayProblem::new(
        Objective::Target,
        depths.clone(),
        psfs.clone(),
        blurred.clone(),
        Some(blur.clone()),
        full.k_reg,
    )
    .map_err(anyhow::Error::msg)?;
    let photo = nedrt_core::image_io::load(std::path::Path::new(INPUT))?.image;
    let (x, y, w, h) = CROP;
    let input = photo.crop(x, y, w, h);
    let start = problem.linear_unclamped(&input).clamped();
    let options = SolveOptions {
        max_steps: 20_000,
        tolerance_db: 1e-6,
        window: 50,
    };
    let (optimum, report) = problem.solve(&input, &start, &options);
    let value = problem.objective_value(&input, &optimum);
    println!(
        "steps {:?}, objective {:?} (start {:?})",
        report.steps, value, report.start_objective
    );
    let kernels = problem
        .mirrored_kernels(w, h)
        .ok_or_else(|| anyhow::anyhow!("the design's PSFs are not mirror-symmetric"))?;
    let kernel = |i: usize| -> Vec<f32> { kernels.iter().flat_map(|k| k[i].clone()).collect() };
    let per_depth = problem
        .mirrored_depth_kernels(w, h)
        .ok_or_else(|| anyhow::anyhow!("the design's PSFs are not mirror-symmetric"))?;
    let depth_kernel = |i: usize| -> Vec<f32> {
        per_depth
            .iter()
            .flat_map(|d| d.iter().flat_map(|k| k[i].clone()))
            .collect()
    };
    let v = json!({
        "source": format!("{INPUT} crop {w}x{h}+{x}+{y}; multifocal design, PSFs cut to {WINDOW} cells"),
        "width": w,
        "height": h,
        "objective": "target",
        "depths_d": depths,
        "blurred": blurred,
        "k_reg": full.k_reg,
        "input": input.data(),
        "optimum": optimum.data(),
        "objective_value": value,
        "psfs": psfs.iter().map(|ch| ch.iter().map(psf_json).collect::<Vec<_>>()).collect::<Vec<_>>(),
        "blur": blur.iter().map(psf_json).collect::<Vec<_>>(),
        "kernels": {
            "normal": kernel(0),
            "adjoint_target": kernel(1),
            "target_gram": kernel(2),
            "normal_per_depth": depth_kernel(0),
            "adjoint_target_per_depth": depth_kernel(1),
            "target_gram_per_depth": depth_kernel(2),
            "linear": problem.mirrored_linear_kernels(w, h).concat(),
        },
    });
    nedrt_core::util::write_atomic(&out, serde_json::to_string(&v)?.as_bytes())?;
    println!("wrote {}", out.display());
    Ok(())
}
