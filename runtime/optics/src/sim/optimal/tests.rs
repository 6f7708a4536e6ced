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

fn frame(w: usize, h: usize, channels: usize) -> Image {
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

fn problem(objective: Objective) -> DisplayProblem {
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

fn targets_of<'a>(t: &'a [Arc<Image>]) -> Vec<&'a [f32]> {
    t.iter().map(|t| t.plane(0)).collect()
}

#[test]
fn the_operator_is_the_simulators_perception() {
    // With t_D = perceive(d, h_D), the residual is zero: A_D is exactly the
    // simulator's rendering, borders and veil included.
    let p = problem(Objective::Sharp);
    let d = frame(11, 8, 1);
    let plan = p.plan(11, 8);
    let rendered: Vec<Image> = p.psfs[0]
        .iter()
        .map(|h| perceive(&d, std::slice::from_ref(h)))
        .collect();
    let t: Vec<&[f32]> = rendered.iter().map(|r| r.plane(0)).collect();
    let f = plan.value_and_gradient(0, d.plane(0), &t, None);
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
        let p = problem(objective);
        let (w, h) = (10, 7);
        let input = frame(w, h, 1);
        let targets = p.targets(&input);
        let t = targets_of(&targets);
        let plan = p.plan(w, h);
        let d: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 11) as f32 / 11.0).collect();
        let mut g = Vec::new();
        plan.value_and_gradient(0, &d, &t, Some(&mut g));
        // Directional derivatives along a few directions, central differences in f64 terms.
        for seed in 0..3 {
            let dir: Vec<f32> = (0..w * h)
                .map(|i| (((i + 3 * seed) * 7919) % 13) as f32 / 13.0 - 0.5)
                .collect();
            let eps = 1e-2f32;
            let shifted =
                |s: f32| -> Vec<f32> { d.iter().zip(&dir).map(|(a, b)| a + s * b).collect() };
            let fp = plan.value_and_gradient(0, &shifted(eps), &t, None);
            let fm = plan.value_and_gradient(0, &shifted(-eps), &t, None);
            let numeric = (fp - fm) / (2.0 * eps as f64);
            let analytic: f64 = g
                .iter()
                .zip(&dir)
                .map(|(a, b)| (*a as f64) * (*b as f64))
                .sum();
            assert!(
                (numeric - analytic).abs() < 1e-3 * analytic.abs().max(1.0),
                "{objective:?}: {numeric} vs {analytic}"
            );
        }
    }
}

/// Largest eigenvalue of Σ A_Dᵀ A_D by 200 power-iteration steps.
fn measured_eigenvalue(p: &DisplayProblem, w: usize, h: usize) -> f64 {
    let plan = p.plan(w, h);
    let zero = vec![0.0f32; 4 * w * h];
    let t: Vec<&[f32]> = vec![&zero; p.depths_d.len()];
    let mut v: Vec<f32> = (0..w * h)
        .map(|i| 1.0 + ((i * 13) % 7) as f32 * 0.1)
        .collect();
    let mut g = Vec::new();
    let mut eig = 0.0;
    let norm = |x: &[f32]| x.iter().map(|a| (*a as f64).powi(2)).sum::<f64>().sqrt();
    for _ in 0..200 {
        plan.value_and_gradient(0, &v, &t, Some(&mut g));
        eig = norm(&g) / norm(&v);
        let n = norm(&g) as f32;
        v = g.iter().map(|a| a / n).collect();
    }
    eig
}

#[test]
fn the_step_bound_holds_for_the_operator() {
    let (w, h) = (9, 6);
    // Mirror-symmetric PSFs: the zero-frequency bound is the eigenvalue.
    let symmetric = |window: usize, spread: f64, veil: f64| {
        let c = (window / 2) as f64;
        let mut cells: Vec<f64> = (0..window * window)
            .map(|i| {
                let (x, y) = ((i % window) as f64 - c, (i / window) as f64 - c);
                (-(x * x + y * y) / spread).exp()
            })
            .collect();
        let s: f64 = cells.iter().sum();
        cells.iter_mut().for_each(|v| *v *= (1.0 - veil) / s);
        Psf {
            window,
            cells,
            veil,
        }
    };
    let p = DisplayProblem::new(
        Objective::Sharp,
        vec![0.0, 1.0],
        vec![vec![symmetric(7, 3.0, 0.02), symmetric(9, 8.0, 0.1)]],
        vec![false, false],
        None,
        0.03,
    )
    .expect("valid");
    assert!(p.psfs[0].iter().all(mirror_symmetric));
    let bound = p.plan(w, h).lipschitz[0];
    let eig = measured_eigenvalue(&p, w, h);
    assert!(eig <= bound * (1.0 + 1e-4), "{eig} > {bound}");
    assert!(eig > 0.999 * bound, "the bound is loose: {eig} vs {bound}");
    // Lopsided PSFs on a small frame pass more than zero frequency at the
    // borders; the plan measures that and stays above it.
    let p = problem(Objective::Sharp);
    assert!(!p.psfs[0].iter().all(mirror_symmetric));
    let bound = p.plan(w, h).lipschitz[0];
    let eig = measured_eigenvalue(&p, w, h);
    let dc: f64 = p.psfs[0]
        .iter()
        .map(|q| 4.0 * (q.cells.iter().sum::<f64>() + q.veil).powi(2))
        .sum();
    assert!(eig > dc, "this case should exceed the zero-frequency bound");
    assert!(eig <= bound, "{eig} > {bound}");
}

#[test]
fn the_optimum_satisfies_the_bounded_optimality_conditions() {
    let p = problem(Objective::Target);
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
    let targets = p.targets(&input);
    let plan = p.plan(w, h);
    let mut g = Vec::new();
    let f = plan.value_and_gradient(0, d.plane(0), &targets_of(&targets), Some(&mut g));
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
    assert!(f <= report.final_objective[0] * (1.0 + 1e-9));
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
