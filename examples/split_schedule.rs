//! Chooses the split solver's schedule (`admm:K`, docs/optimal.md) on
//! training photographs, against projected gradient (`refine:K`) and the
//! optimum, by the objective itself:
//!
//!     cargo run --release --example split_schedule [-- DESIGN [EVERY [STEPS]]]
//!
//! DESIGN (default `multifocal`) is a design name or `shipped` (the DOE
//! beside models/dcnn.onnx); every EVERY-th image of data/images/train
//! (default 4; never the validation or reserved photographs) at its own
//! 256×256 size. For each K of 1, 2, 3, 5, 10, 20 (up to STEPS) it prints
//! the gain of the objective ½ Σ_D ‖A_D d − t_D‖² over the clamped `lsq`
//! image, as 10·log10(f_lsq / f) dB summed over the channels and averaged
//! over the images, for refine:K, for each schedule of a grid (ρ as a
//! share of L, its growth per step, the relaxation), and for the optimum
//! (the ceiling). The design's PSFs must be in the PSF cache or are
//! computed (minutes).

use std::path::{Path, PathBuf};

use nedrt_core::image::Image;
use nedrt_optics::sim::optimal::{FistaState, SplitSchedule};
use nedrt_optics::sim::{DisplayProblem, Method, Objective, SolveOptions, objective_depths_d};

const KS: [usize; 6] = [1, 2, 3, 5, 10, 20];

fn gain_db(problem: &DisplayProblem, input: &Image, start: f64, display: &Image) -> f64 {
    let f: f64 = problem.objective_value(input, display).iter().sum();
    10.0 * (start / f).log10()
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let design = args.first().map_or("multifocal", String::as_str);
    let every: usize = args.get(1).map_or(Ok(4), |s| s.parse())?;
    let max_k: usize = args.get(2).map_or(Ok(20), |s| s.parse())?;
    let ks: Vec<usize> = KS.iter().copied().filter(|&k| k <= max_k).collect();
    let calib = nedrt_core::calib::Calibration::default_embedded()?;
    let cache = nedrt_optics::cache::PsfCache::at(
        std::env::var_os("NEDRT_CACHE_DIR")
            .map(PathBuf::from)
            .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/nedrt"))),
    );
    let sim = if design == "shipped" {
        nedrt_optics::sim::Simulator::new(
            calib,
            Some(Path::new("models/dcnn.doe.safetensors")),
            cache,
        )?
    } else {
        nedrt_app::design::Design::resolve(design)?.simulator(calib, cache)?
    };
    let depths = objective_depths_d(&sim.calib);
    let prepared = sim.prepare(&[Method::DoeWiener], &depths, &nedrt_core::progress::Silent)?;
    let problem = prepared.display_problem(Method::DoeWiener, Objective::Target)?;
    let mut files: Vec<PathBuf> = std::fs::read_dir("data/images/train")?
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<_, _>>()?;
    files.retain(|f| f.extension().is_some_and(|e| e == "png"));
    files.sort();
    let files: Vec<PathBuf> = files.into_iter().step_by(every.max(1)).collect();
    let images: Vec<Image> = files
        .iter()
        .map(|f| nedrt_core::image_io::load(f).map(|l| l.image))
        .collect::<Result<_, _>>()?;
    let mut schedules = Vec::new();
    for rho in [0.003, 0.01, 0.02, 0.03, 0.05, 0.1] {
        for growth in [1.0, 1.3] {
            for relaxation in [1.0, 1.3, 1.6, 1.8] {
                schedules.push(SplitSchedule {
                    rho,
                    growth,
                    relaxation,
                });
            }
        }
    }
    // [row][k]: refine, each schedule; then the optimum (one value).
    let mut sums = vec![vec![0.0f64; ks.len()]; 1 + schedules.len()];
    let mut optimum = 0.0f64;
    for (file, input) in files.iter().zip(&images) {
        let linear = problem.linear_unclamped(input).clamped();
        let start: f64 = problem.objective_value(input, &linear).iter().sum();
        let mut states: Vec<FistaState> = linear.planes().map(FistaState::at).collect();
        let mut done = 0;
        for (i, &k) in ks.iter().enumerate() {
            let (d, _, s) = problem.solve_from(input, states, &SolveOptions::steps(k - done));
            states = s;
            done = k;
            sums[0][i] += gain_db(&problem, input, start, &d);
        }
        for (row, schedule) in schedules.iter().enumerate() {
            let mut states = problem.split_start(input);
            let mut done = 0;
            for (i, &k) in ks.iter().enumerate() {
                let (d, s) = problem.solve_split(input, states, k - done, schedule)?;
                states = s;
                done = k;
                sums[1 + row][i] += gain_db(&problem, input, start, &d);
            }
        }
        let (best, _) = problem.solve(input, &linear, &SolveOptions::CONVERGED);
        optimum += gain_db(&problem, input, start, &best);
        eprintln!("{}", file.display());
    }
    let n = images.len() as f64;
    println!(
        "design {design}, {} training images (every {every}th), objective gain over lsq in dB, \
         mean; optimum {:.3} dB",
        images.len(),
        optimum / n
    );
    let header: Vec<String> = ks.iter().map(|k| format!("K={k}")).collect();
    println!("| solver | {} |", header.join(" | "));
    println!("| --- |{}", " ---: |".repeat(ks.len()));
    let row = |name: String, v: &[f64]| {
        let cells: Vec<String> = v.iter().map(|x| format!("{:.3}", x / n)).collect();
        println!("| {name} | {} |", cells.join(" | "));
    };
    row("refine (FISTA)".into(), &sums[0]);
    for (s, v) in schedules.iter().zip(&sums[1..]) {
        row(
            format!("admm ρ={} L, ×{}/step, α={}", s.rho, s.growth, s.relaxation),
            v,
        );
    }
    Ok(())
}
