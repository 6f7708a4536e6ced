use super::*;
use crate::sim::perceive;
use crate::sim::wiener::WienerFilter;

/// A lopsided PSF (so a wrong adjoint cannot hide behind symmetry), Σ = 1 − veil.
fn psf(window: usize, seed: usize, veil: f64) -> Psf {
    let c = (window / 2) as f64;
    let mut cells: Vec<f64> = (0..window * window)
        .map(|i| {
            let (x, y) = ((i % window) as f64 - c, (i / window) as f64 - c);
            let spread = 1.0 + seed as f64 * 0.7;
            (-(x * x + 0.6 * y * y) / (2.0 * spread)).exp()
                * (1.0 + 0.3 * ((i * 7 + seed) % 5) as f64 / 5.0)
                * if x > 0.0 { 1.4 } else { 1.0 }
        })
        .collect();
    let s: f64 = cells.iter().sum();
    cells.iter_mut().for_each(|v| *v *= (1.0 - veil) / s);
    Psf {
        window,
        cells,
        veil,
    }
}

pub(super) fn frame(w: usize, h: usize, channels: usize) -> Image {
    let planes = (0..channels)
        .map(|c| {
            (0..w * h)
                .map(|i| {
                    let (x, y) = ((i % w) as f32, (i / w) as f32);
                    (0.5 + 0.45 * ((x * 0.9 + c as f32).sin() * (y * 0.6).cos())).clamp(0.0, 1.0)
                })
                .collect()
        })
        .collect();
    Image::from_planes(w, h, planes)
}

pub(super) fn problem(objective: Objective) -> DisplayProblem {
    let depths = vec![0.0, 0.5, 1.0];
    let psfs = vec![vec![psf(7, 0, 0.02), psf(9, 1, 0.05), psf(9, 2, 0.0)]; 1];
    let blurred = vec![false, objective == Objective::Target, false];
    DisplayProblem::new(
        objective,
        depths,
        psfs,
        blurred,
        Some(vec![psf(5, 3, 0.01)]),
        0.03,
    )
    .expect("valid problem")
}

/// The plan on the cropped (exact adjoint) path, whatever the PSFs.
fn cropped_plan(p: &DisplayProblem, w: usize, h: usize) -> ProblemPlan {
    ProblemPlan::cropped(p, w, h, linear_plan(p, w, h))
}

/// Value and gradient of channel 0 at `d` for the frame `input`.
fn evaluate(plan: &ProblemPlan, p: &DisplayProblem, input: &Image, d: &[f32]) -> (f64, Vec<f32>) {
    let targets = p.targets(input);
    let objective = plan.channel_objective(0, input.plane(0), Some(&targets));
    let mut g = Vec::new();
    let f = objective(d, Some(&mut g));
    (f, g)
}

/// A mirror-symmetric PSF, Σ = 1 − veil.
fn symmetric(window: usize, spread: f64, veil: f64) -> Psf {
    let c = (window / 2) as f64;
    let mut cells: Vec<f64> = (0..window * window)
        .map(|i| {
            let (x, y) = ((i % window) as f64 - c, (i / window) as f64 - c);
            (-(x * x + 0.5 * y * y) / spread).exp() * (1.0 + 0.2 * (x.abs() + y.abs()).cos())
        })
        .collect();
    let s: f64 = cells.iter().sum();
    cells.iter_mut().for_each(|v| *v *= (1.0 - veil) / s);
    Psf {
        window,
        cells,
        veil,
    }
}

/// A problem with mirror-symmetric PSFs (the mirrored path), windows wider
/// than the frame included.
pub(super) fn symmetric_problem(objective: Objective) -> DisplayProblem {
    DisplayProblem::new(
        objective,
        vec![0.0, 0.5, 1.0],
        vec![vec![
            symmetric(7, 2.0, 0.02),
            symmetric(31, 40.0, 0.05),
            symmetric(9, 5.0, 0.0),
        ]],
        vec![false, objective == Objective::Target, false],
        Some(vec![symmetric(5, 3.0, 0.01)]),
        0.03,
    )
    .expect("valid problem")
}

#[test]
fn the_operator_is_the_simulators_perception() {
    // With t_D = perceive(d, h_D), the residual is zero: A_D is exactly the
    // simulator's rendering, borders and veil included.
    let p = problem(Objective::Sharp);
    let d = frame(11, 8, 1);
    let plan = cropped_plan(&p, 11, 8);
    let Operator::Cropped(op) = &plan.operator else {
        panic!("cropped plan");
    };
    let rendered: Vec<Image> = p.psfs[0]
        .iter()
        .map(|h| perceive(&d, std::slice::from_ref(h)))
        .collect();
    let t: Vec<&[f32]> = rendered.iter().map(|r| r.plane(0)).collect();
    let f = op.value_and_gradient(0, d.plane(0), 11, 8, &t, None);
    let scale: f64 = rendered
        .iter()
        .flat_map(|r| r.plane(0))
        .map(|v| (*v as f64).powi(2))
        .sum();
    assert!(f < 1e-10 * scale, "residual {f} of {scale}");
}

#[test]
fn the_gradient_is_the_derivative_of_the_objective() {
    for objective in [Objective::Sharp, Objective::Target] {
        for mirrored in [false, true] {
            let p = if mirrored {
                symmetric_problem(objective)
            } else {
                problem(objective)
            };
            let (w, h) = (10, 7);
            let input = frame(w, h, 1);
            let plan = p.plan(w, h);
            assert_eq!(matches!(plan.operator, Operator::Mirrored(_)), mirrored);
            let d: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 11) as f32 / 11.0).collect();
            let (_, g) = evaluate(&plan, &p, &input, &d);
            for seed in 0..3 {
                let dir: Vec<f32> = (0..w * h)
                    .map(|i| (((i + 3 * seed) * 7919) % 13) as f32 / 13.0 - 0.5)
                    .collect();
                let eps = 1e-2f32;
                let shifted =
                    |s: f32| -> Vec<f32> { d.iter().zip(&dir).map(|(a, b)| a + s * b).collect() };
                let fp = evaluate(&plan, &p, &input, &shifted(eps)).0;
                let fm = evaluate(&plan, &p, &input, &shifted(-eps)).0;
                let numeric = (fp - fm) / (2.0 * eps as f64);
                let analytic: f64 = g
                    .iter()
                    .zip(&dir)
                    .map(|(a, b)| (*a as f64) * (*b as f64))
                    .sum();
                assert!(
                    (numeric - analytic).abs() < 1e-3 * analytic.abs().max(1.0),
                    "{objective:?}, mirrored {mirrored}: {numeric} vs {analytic}"
                );
            }
        }
    }
}

#[test]
fn the_mirrored_path_equals_the_cropped_path_for_symmetric_psfs() {
    // Two independent computations of the same objective and gradient: the
    // simulator's rendering with the exact adjoint, and the display-grid
    // convolutions of the mirrored frame. A PSF wider than the frame too.
    for objective in [Objective::Sharp, Objective::Target] {
        let p = symmetric_problem(objective);
        let (w, h) = (12, 9);
        let input = frame(w, h, 1);
        let mirrored = p.plan(w, h);
        let cropped = cropped_plan(&p, w, h);
        let d: Vec<f32> = (0..w * h).map(|i| ((i * 29) % 17) as f32 / 17.0).collect();
        let (fm, gm) = evaluate(&mirrored, &p, &input, &d);
        let (fc, gc) = evaluate(&cropped, &p, &input, &d);
        assert!((fm - fc).abs() < 1e-5 * fc, "{objective:?}: {fm} vs {fc}");
        let gmax = gc.iter().fold(0.0f32, |a, v| a.max(v.abs()));
        for (a, b) in gm.iter().zip(&gc) {
            assert!((a - b).abs() < 1e-4 * gmax, "{objective:?}: {a} vs {b}");
        }
        // The mirrored path's step bound is the operator's largest eigenvalue.
        let lm = mirrored.lipschitz[0];
        let Operator::Cropped(op) = &cropped.operator else {
            panic!("cropped plan");
        };
        let eig = op.largest_eigenvalue(0, w, h);
        assert!(eig <= lm * (1.0 + 1e-4) && eig > 0.98 * lm, "{eig} vs {lm}");
    }
}

#[test]
fn the_step_bound_holds_on_the_cropped_path() {
    // Lopsided PSFs on a small frame pass more than zero frequency at the
    // borders; the plan measures that and stays above it (checked by a
    // longer power iteration).
    let (w, h) = (9, 6);
    let p = problem(Objective::Sharp);
    assert!(!p.psfs[0].iter().all(mirror_symmetric));
    let plan = p.plan(w, h);
    let Operator::Cropped(op) = &plan.operator else {
        panic!("lopsided PSFs take the cropped path");
    };
    let zero = vec![0.0f32; 4 * w * h];
    let t: Vec<&[f32]> = vec![&zero; 3];
    let norm = |x: &[f32]| x.iter().map(|a| (*a as f64).powi(2)).sum::<f64>().sqrt();
    let mut v: Vec<f32> = (0..w * h)
        .map(|i| 1.0 + ((i * 13) % 7) as f32 * 0.1)
        .collect();
    let mut g = Vec::new();
    let mut eig = 0.0;
    for _ in 0..300 {
        op.value_and_gradient(0, &v, w, h, &t, Some(&mut g));
        eig = norm(&g) / norm(&v);
        let n = norm(&g) as f32;
        v = g.iter().map(|a| a / n).collect();
    }
    let dc: f64 = p.psfs[0]
        .iter()
        .map(|q| 4.0 * (q.cells.iter().sum::<f64>() + q.veil).powi(2))
        .sum();
    assert!(eig > dc, "this case should exceed the zero-frequency bound");
    assert!(eig <= plan.lipschitz[0], "{eig} > {}", plan.lipschitz[0]);
}

#[test]
fn the_optimum_satisfies_the_bounded_optimality_conditions() {
    for p in [
        problem(Objective::Target),
        symmetric_problem(Objective::Target),
    ] {
        let (w, h) = (12, 10);
        // Contrast the panel cannot show without the clamp mattering.
        let input = Image::from_planes(
            w,
            h,
            vec![
                (0..w * h)
                    .map(|i| if (i % w) < w / 2 { 0.02 } else { 0.98 })
                    .collect(),
            ],
        );
        let linear = p.linear_unclamped(&input).clamped();
        let options = SolveOptions {
            max_steps: 4000,
            tolerance_db: 1e-6,
            window: 20,
        };
        let (d, report) = p.solve(&input, &linear, &options);
        assert!(report.final_objective[0] < report.start_objective[0]);
        let plan = p.plan(w, h);
        let (f, g) = evaluate(&plan, &p, &input, d.plane(0));
        let gmax = g.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        // KKT: zero gradient inside, pointing out of the box at a bound.
        let mut at_bound = 0;
        for (x, gv) in d.plane(0).iter().zip(&g) {
            if *x <= 0.0 {
                assert!(*gv >= -1e-3 * gmax, "at 0 with gradient {gv}");
                at_bound += 1;
            } else if *x >= 1.0 {
                assert!(*gv <= 1e-3 * gmax, "at 1 with gradient {gv}");
                at_bound += 1;
            } else {
                assert!(
                    gv.abs() <= 2e-3 * gmax.max(1e-3),
                    "inside ({x}) with gradient {gv}"
                );
            }
        }
        assert!(
            at_bound > 0,
            "the bound was never active; the test shows nothing"
        );
        assert!((f - report.final_objective[0]).abs() <= 1e-6 * f);
    }
}

#[test]
fn refinement_steps_only_improve_on_the_linear_prefilter() {
    let p = problem(Objective::Target);
    let input = frame(16, 12, 1);
    let linear = p.linear_unclamped(&input).clamped();
    let f0 = p.objective_value(&input, &linear)[0];
    let mut last = f0;
    for k in [1, 3, 10, 30] {
        let (d, r) = p.solve(&input, &linear, &SolveOptions::steps(k));
        let f = p.objective_value(&input, &d)[0];
        assert_eq!(r.steps, vec![k]);
        assert!(d.plane(0).iter().all(|v| (0.0..=1.0).contains(v)));
        assert!(f < last, "refine:{k}: {f} not below {last}");
        last = f;
    }
    let mut optimal = SolvedPrefilter::new("test", Arc::new(p), SolveMode::Optimal);
    let d = optimal.run(&input).expect("solves");
    let problem = &optimal.problem;
    assert!(problem.objective_value(&input, &d)[0] <= last * 1.0001);
    assert!(optimal.describe().contains("optimum"));
}

#[test]
fn one_depth_sharp_lsq_is_the_wiener_prefilter() {
    // With one depth and the sharp image as its target, Σ K*T/(Σ|K|² + K)
    // is the Wiener gain H̄*/(|H̄|² + K).
    let h = psf(9, 1, 0.04);
    let p = DisplayProblem::new(
        Objective::Sharp,
        vec![1.0],
        vec![vec![h.clone()]],
        vec![false],
        None,
        0.02,
    )
    .expect("valid");
    let input = frame(14, 10, 1);
    let lsq = p.linear_unclamped(&input);
    let wiener = WienerFilter::new(std::slice::from_ref(&h), 0.02).apply_unclamped(&input);
    for (a, b) in lsq.data().iter().zip(wiener.data()) {
        assert!((a - b).abs() < 1e-5, "{a} vs {b}");
    }
}

#[test]
fn inconsistent_problems_are_refused() {
    let ok = || vec![vec![psf(5, 0, 0.0)]];
    assert!(DisplayProblem::new(Objective::Sharp, vec![], vec![], vec![], None, 0.1).is_err());
    assert!(
        DisplayProblem::new(
            Objective::Sharp,
            vec![0.0, 1.0],
            ok(),
            vec![false],
            None,
            0.1
        )
        .is_err()
    );
    assert!(
        DisplayProblem::new(Objective::Target, vec![0.0], ok(), vec![true], None, 0.1).is_err()
    );
    assert!(
        DisplayProblem::new(
            Objective::Sharp,
            vec![0.0],
            ok(),
            vec![false],
            None,
            f64::NAN
        )
        .is_err()
    );
    assert!(
        "blurry"
            .parse::<Objective>()
            .unwrap_err()
            .contains("sharp or target")
    );
}

#[test]
fn the_golden_optimum_is_what_the_solver_gives() {
    // tests/golden/optimal.json (examples/make_optimal_golden.rs), which
    // models/tests/test_optimal.py checks against scipy's L-BFGS-B: the
    // solver still finds that optimum.
    let g: serde_json::Value =
        serde_json::from_str(include_str!("../../../../../tests/golden/optimal.json"))
            .expect("golden json");
    let floats = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .expect("array")
            .iter()
            .map(|x| x.as_f64().expect("number"))
            .collect()
    };
    let psf = |v: &serde_json::Value| Psf {
        window: v["window"].as_u64().expect("window") as usize,
        cells: floats(&v["cells"]),
        veil: v["veil"].as_f64().expect("veil"),
    };
    let (w, h) = (
        g["width"].as_u64().expect("w") as usize,
        g["height"].as_u64().expect("h") as usize,
    );
    let psfs: Vec<Vec<Psf>> = g["psfs"]
        .as_array()
        .expect("psfs")
        .iter()
        .map(|ch| ch.as_array().expect("depths").iter().map(psf).collect())
        .collect();
    let blurred: Vec<bool> = g["blurred"]
        .as_array()
        .expect("blurred")
        .iter()
        .map(|b| b.as_bool().expect("bool"))
        .collect();
    let blur: Vec<Psf> = g["blur"]
        .as_array()
        .expect("blur")
        .iter()
        .map(psf)
        .collect();
    let p = DisplayProblem::new(
        Objective::Target,
        floats(&g["depths_d"]),
        psfs,
        blurred,
        Some(blur),
        g["k_reg"].as_f64().expect("k"),
    )
    .expect("valid");
    let f32s = |v: &serde_json::Value| floats(v).into_iter().map(|x| x as f32).collect();
    let input = Image::from_data(w, h, 3, f32s(&g["input"]));
    let golden = Image::from_data(w, h, 3, f32s(&g["optimum"]));
    let start = p.linear_unclamped(&input).clamped();
    let options = SolveOptions {
        max_steps: 20_000,
        tolerance_db: 1e-6,
        window: 50,
    };
    let (d, _) = p.solve(&input, &start, &options);
    let ours = p.objective_value(&input, &d);
    for (c, want) in floats(&g["objective_value"]).iter().enumerate() {
        assert!(
            (ours[c] - want).abs() <= 1e-5 * want,
            "channel {c}: {} vs {want}",
            ours[c]
        );
    }
    let worst = d
        .data()
        .iter()
        .zip(golden.data())
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(worst < 1e-2, "display differs by {worst}");
    // The shipped solver settings reach the same optimum.
    let (d, _) = p.solve(&input, &start, &SolveOptions::CONVERGED);
    let quick = p.objective_value(&input, &d);
    for (c, want) in floats(&g["objective_value"]).iter().enumerate() {
        let db = 10.0 * (quick[c] / want).log10();
        assert!(db < 0.01, "channel {c}: CONVERGED stops {db} dB short");
    }
}

#[test]
fn the_exported_kernels_give_the_objective() {
    // What the trainer computes from `mirrored_kernels`, by direct sums here.
    let p = symmetric_problem(Objective::Target);
    let (w, h) = (8, 6);
    let input = frame(w, h, 1);
    let d = frame(w, h, 1).map_planes(|q| q.iter().map(|v| 1.0 - v * 0.7).collect());
    let kernels = p.mirrored_kernels(w, h).expect("symmetric PSFs");
    let (mw, mh) = (2 * w, 2 * h);
    let mirror = |x: &[f32]| extend_plane(x, w, h, 0, 0, mw, mh);
    let (dm, im) = (mirror(d.plane(0)), mirror(input.plane(0)));
    // x·(κ ⊛ y) on the periodic grid.
    let form = |x: &[f32], k: &[f32], y: &[f32]| -> f64 {
        let mut acc = 0.0f64;
        for n in 0..mh {
            for m in 0..mw {
                let mut conv = 0.0f64;
                for a in 0..mh {
                    for b in 0..mw {
                        let (ky, kx) = ((n + mh - a) % mh, (m + mw - b) % mw);
                        conv += k[ky * mw + kx] as f64 * y[a * mw + b] as f64;
                    }
                }
                acc += x[n * mw + m] as f64 * conv;
            }
        }
        acc
    };
    let [km, kc, kt] = &kernels[0];
    let value = 0.25 * (0.5 * form(&dm, km, &dm) - form(&dm, kc, &im) + 0.5 * form(&im, kt, &im));
    let want = p.objective_value(&input, &d)[0];
    assert!((value - want).abs() < 1e-4 * want, "{value} vs {want}");
    assert!(problem(Objective::Sharp).mirrored_kernels(w, h).is_none());
    // The per-depth kernels sum to these.
    let per_depth = p.mirrored_depth_kernels(w, h).expect("symmetric PSFs");
    assert_eq!(per_depth.len(), 3);
    for i in 0..3 {
        for (j, want) in kernels[0][i].iter().enumerate() {
            let sum: f32 = per_depth.iter().map(|d| d[0][i][j]).sum();
            assert!(
                (sum - want).abs() < 1e-4 * want.abs().max(1e-2),
                "kernel {i}[{j}]: {sum} vs {want}"
            );
        }
    }
}

/// The frame budget's warm start (issue 54): refine:1 on a still frame
/// goes on from where the last frame's solve stopped, momentum and all,
/// so ten frames of it are refine:10.
#[test]
fn warm_started_refine_one_on_a_still_frame_is_refine_ten_after_ten_frames() {
    let p = Arc::new(problem(Objective::Target));
    let input = frame(16, 12, 1);
    let mut warm = SolvedPrefilter::new("test", p.clone(), SolveMode::Refine(1)).warm_started();
    assert!(warm.describe().contains("still"), "{}", warm.describe());
    let mut shown = Vec::new();
    for _ in 0..10 {
        shown.push(warm.run(&input).expect("runs"));
    }
    assert_eq!(warm.warm_frames(), 9);
    let ten = SolvedPrefilter::new("test", p.clone(), SolveMode::Refine(10))
        .run(&input)
        .expect("runs");
    let objective = |d: &Image| p.objective_value(&input, d)[0];
    let (f_warm, f_ten) = (objective(&shown[9]), objective(&ten));
    let apart_db = 10.0 * (f_warm / f_ten).log10();
    assert!(apart_db.abs() < 0.1, "{apart_db} dB from refine:10");
    let worst = shown[9]
        .data()
        .iter()
        .zip(ten.data())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-5, "{worst} from refine:10's display image");
    // Each frame is better than the last: the scene converges.
    for w in shown.windows(2) {
        assert!(objective(&w[1]) < objective(&w[0]));
    }
    // A frame that changed starts again from the linear prefilter; one
    // whose change is below a quarter of an 8-bit code goes on.
    let mut moved = input.clone();
    moved
        .data_mut()
        .iter_mut()
        .for_each(|v| *v = (*v * 0.9).max(0.0));
    let again = warm.run(&moved).expect("runs");
    assert_eq!(warm.warm_frames(), 0);
    let one = SolvedPrefilter::new("test", p.clone(), SolveMode::Refine(1))
        .run(&moved)
        .expect("runs");
    assert!(
        again.data() == one.data(),
        "a changed frame is refine:1 from the start"
    );
    let mut noisy = moved.clone();
    noisy
        .data_mut()
        .iter_mut()
        .enumerate()
        .for_each(|(i, v)| *v += if i % 2 == 0 { 5e-4 } else { -5e-4 });
    warm.run(&noisy).expect("runs");
    assert_eq!(warm.warm_frames(), 1, "a renderer's noise is a still frame");
}

/// A frame of a pan changes by more than a still frame's noise: the warm
/// start gives it refine:K from the linear prefilter, so it flickers as
/// much as refine:K and no more (the stability study measures both).
#[test]
fn warm_started_refine_on_a_pan_is_refine_from_the_start_every_frame() {
    let p = Arc::new(problem(Objective::Target));
    let pan = |t: usize| {
        let (w, h) = (16, 12);
        let plane = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32 + 0.37 * t as f32, (i / w) as f32);
                (0.5 + 0.4 * (x * 0.8).sin() * (y * 0.5).cos()).clamp(0.0, 1.0)
            })
            .collect();
        Image::from_planes(w, h, vec![plane])
    };
    let mut warm = SolvedPrefilter::new("test", p.clone(), SolveMode::Refine(3)).warm_started();
    let mut cold = SolvedPrefilter::new("test", p.clone(), SolveMode::Refine(3));
    for t in 0..6 {
        let f = pan(t);
        let (a, b) = (warm.run(&f).expect("warm"), cold.run(&f).expect("cold"));
        assert_eq!(warm.warm_frames(), 0, "frame {t}");
        assert!(a.data() == b.data(), "frame {t}");
    }
}

#[test]
fn the_split_data_step_solves_its_penalised_problem() {
    // (N + ρ) x = b + ρ v: the penalised objective's gradient, N x − b +
    // ρ (x − v), vanishes at the data step's x.
    let p = symmetric_problem(Objective::Target);
    let input = frame(14, 10, 1);
    let plan = p.plan(14, 10);
    let Operator::Mirrored(op) = &plan.operator else {
        panic!("symmetric PSFs take the mirrored path");
    };
    let b = op.adjoint_target_spectrum(0, input.plane(0), 14, 10);
    let v: Vec<f32> = (0..140).map(|i| ((i * 37) % 11) as f32 / 10.0).collect();
    for rho in [0.01f32, 0.3, 2.0] {
        let x = op.penalised_solve(0, &b, &v, rho, 14, 10);
        let (_, g) = evaluate(&plan, &p, &input, &x);
        let worst = g
            .iter()
            .zip(x.iter().zip(&v))
            .map(|(g, (x, v))| (g + rho * (x - v)).abs())
            .fold(0.0f32, f32::max);
        let scale = g.iter().fold(rho, |m, g| m.max(g.abs()));
        assert!(worst < 1e-4 * scale.max(1.0), "ρ = {rho}: residual {worst}");
    }
}

#[test]
fn split_steps_improve_on_lsq_and_reach_the_optimum() {
    let p = symmetric_problem(Objective::Target);
    let input = frame(16, 12, 1);
    let linear = p.linear_unclamped(&input).clamped();
    let f0 = p.objective_value(&input, &linear)[0];
    let schedule = SplitSchedule::SHIPPED;
    for k in [1, 3, 10] {
        let (d, _) = p
            .solve_split(&input, p.split_start(&input), k, &schedule)
            .expect("mirrored");
        assert!(d.plane(0).iter().all(|v| (0.0..=1.0).contains(v)));
        let f = p.objective_value(&input, &d)[0];
        assert!(f < f0, "admm:{k}: {f} not below lsq's {f0}");
    }
    // K steps and K more are 2K steps.
    let (once, _) = p
        .solve_split(&input, p.split_start(&input), 8, &schedule)
        .expect("mirrored");
    let (_, half) = p
        .solve_split(&input, p.split_start(&input), 4, &schedule)
        .expect("mirrored");
    let (twice, _) = p.solve_split(&input, half, 4, &schedule).expect("mirrored");
    assert_eq!(once.data(), twice.data());
    let (best, _) = p.solve(&input, &linear, &SolveOptions::CONVERGED);
    let optimum = p.objective_value(&input, &best)[0];
    let (d, _) = p
        .solve_split(&input, p.split_start(&input), 400, &schedule)
        .expect("mirrored");
    let f = p.objective_value(&input, &d)[0];
    assert!(
        (f - optimum).abs() <= 1e-3 * optimum,
        "admm:400 {f} against the optimum {optimum}"
    );
    let mut admm = SolvedPrefilter::new("test", Arc::new(p), SolveMode::Admm(3));
    let d = admm.run(&input).expect("solves");
    assert!(admm.problem.objective_value(&input, &d)[0] < f0);
    assert!(admm.describe().contains("split-solver"));
}

#[test]
fn the_split_solver_refuses_psfs_without_the_mirrored_form() {
    let p = problem(Objective::Target);
    assert!(!p.has_split());
    let input = frame(10, 8, 1);
    let e = p
        .solve_split(&input, p.split_start(&input), 2, &SplitSchedule::SHIPPED)
        .expect_err("no exact data step");
    assert!(e.to_string().contains("mirror-symmetric"), "{e}");
    let mut admm = SolvedPrefilter::new("test", Arc::new(p), SolveMode::Admm(2));
    assert!(admm.run(&input).is_err());
}

#[test]
fn warm_started_admm_on_a_still_frame_goes_on_and_a_changed_one_starts_afresh() {
    let p = Arc::new(symmetric_problem(Objective::Target));
    let input = frame(16, 12, 1);
    let mut warm = SolvedPrefilter::new("test", p.clone(), SolveMode::Admm(1)).warm_started();
    assert!(warm.describe().contains("still"), "{}", warm.describe());
    let mut shown = Vec::new();
    for _ in 0..5 {
        shown.push(warm.run(&input).expect("runs"));
    }
    assert_eq!(warm.warm_frames(), 4);
    // Five frames of one step are admm:5.
    let five = SolvedPrefilter::new("test", p.clone(), SolveMode::Admm(5))
        .run(&input)
        .expect("runs");
    assert_eq!(shown[4].data(), five.data());
    let mut moved = input.clone();
    moved
        .data_mut()
        .iter_mut()
        .for_each(|v| *v = (*v * 0.9).max(0.0));
    let again = warm.run(&moved).expect("runs");
    assert_eq!(warm.warm_frames(), 0);
    let one = SolvedPrefilter::new("test", p.clone(), SolveMode::Admm(1))
        .run(&moved)
        .expect("runs");
    assert_eq!(again.data(), one.data(), "a changed frame starts afresh");
}
