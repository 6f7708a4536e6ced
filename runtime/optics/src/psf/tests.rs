//! The PSF planner against docs/model.md §6–§8: converged cell integration, energy
//! kept (window plus veil), the window choice and the refusals.

use super::*;
use crate::propagate::fft_period_cells;
use crate::pupil::{PupilGrid, pupil_field};

fn calib() -> Calibration {
    Calibration::default_embedded().expect("default calibration")
}

/// The default calibration with the 2-D path forced (the lens alone would
/// otherwise take the radial path, tested in `radial_tests`).
fn calib_2d() -> Calibration {
    let mut c = calib();
    c.simulation.propagator = nedrt_core::calib::PropagatorSetting::TwoD;
    c
}

fn psfs(
    c: &Calibration,
    specs: Vec<PsfSpec>,
    doe: Option<&HeightMap>,
) -> Result<PsfSet, OpticsError> {
    compute_psfs(c, &PsfRequest { specs, doe }, &|| ())
}

#[test]
fn integrated_cells_weigh_the_in_focus_order_as_optics_md_says() {
    // Three-lens DOE, G, accommodation 0.5 D: its 0.5 D order is in focus.
    // docs/model.md §6: the central sample holds 75 % of a centre-sampled PSF but
    // 29 % of the integrated one. Those shares are of the light in a window
    // of ≈ 200 cells, computed on the DOE's own 6 µm grid.
    let c = calib();
    let doe = HeightMap::three_lens_init(&c, 6e-6);
    let spec = PsfSpec {
        channel: 1,
        psi_rad: c.psi_rad(1, 0.5),
    };
    let grid = doe.grid();
    let q = pupil_field(
        grid,
        c.aperture_radius_m,
        spec.psi_rad,
        Some(&doe.phase_on(grid, &c, 1)),
    );
    let share = |sub: usize| {
        let cells = crate::propagate::mft_cells(&q, grid, 530e-9, 201, c.retinal_step_rad(), sub);
        (
            cells[cells.len() / 2] / cells.iter().sum::<f64>(),
            cells[cells.len() / 2],
        )
    };
    let (centre_sampled, _) = share(1);
    let (integrated, integrated_of_all) = share(4);
    assert!(
        (centre_sampled - 0.75).abs() < 0.01,
        "centre-sampled share {centre_sampled}"
    );
    assert!(
        (integrated - 0.29).abs() < 0.01,
        "integrated share {integrated}"
    );

    // The planner (FFT over the period, DOE resampled onto a 5.8 µm grid,
    // normalised by all the light) agrees with the 6 µm MFT to 2 %.
    let set = psfs(&c, vec![spec], Some(&doe)).expect("psf");
    let p = &set.psfs[0];
    let planned = p.cells[p.cells.len() / 2];
    assert!(
        (planned / integrated_of_all - 1.0).abs() < 0.02,
        "{planned} vs {integrated_of_all}"
    );
}

#[test]
fn lens_psfs_keep_all_light_in_window_plus_veil() {
    let c = calib_2d();
    let specs: Vec<PsfSpec> = (0..3)
        .map(|ch| PsfSpec {
            channel: ch,
            psi_rad: c.psi_rad(ch, 1.0),
        })
        .collect();
    let set = psfs(&c, specs, None).expect("psf");
    assert!(!set.report.window_capped);
    assert!(set.report.min_window_energy >= c.simulation.window_energy);
    for p in &set.psfs {
        let inside: f64 = p.cells.iter().sum();
        assert!(
            (inside + p.veil - 1.0).abs() < 1e-12,
            "window {inside} + veil {} ≠ 1",
            p.veil
        );
        assert!(p.veil <= 1.0 - c.simulation.window_energy + 1e-12);
        assert_eq!(p.window % 2, 1);
    }
    // The smallest window: one size smaller misses the target for some PSF.
    let w = set.report.window_cells;
    let smaller_ok = set.psfs.iter().all(|p| {
        let inner = crate::propagate::crop_centred(&p.cells, w, w - 2);
        inner.iter().sum::<f64>() >= c.simulation.window_energy
    });
    assert!(!smaller_ok, "window {w} is not the smallest");
}

#[test]
fn doe_window_is_capped_by_its_period_and_the_rest_is_veil() {
    let c = calib();
    let doe = HeightMap::three_lens_init(&c, 6e-6);
    let specs: Vec<PsfSpec> = (0..3)
        .map(|ch| PsfSpec {
            channel: ch,
            psi_rad: c.psi_rad(ch, 1.0),
        })
        .collect();
    let set = psfs(&c, specs, Some(&doe)).expect("psf");
    let r = &set.report;
    // Blue's period at ≤ 6 µm is ≥ 491 cells: rule 3 bounds the window there.
    let blue = r.channels.iter().find(|c| c.name == "B").expect("blue");
    assert!(r.window_cells <= blue.period_cells);
    for p in &set.psfs {
        let inside: f64 = p.cells.iter().sum();
        assert!((inside + p.veil - 1.0).abs() < 1e-12);
    }
    // The higher diffraction orders reach the edge of the period.
    if r.window_capped {
        assert!(r.max_veil > 1.0 - c.simulation.window_energy);
    }
}

#[test]
fn planner_cells_are_the_limit_of_the_midpoint_sums() {
    // docs/model.md §6's m×m sums converge to the planner's exactly integrated
    // cells at second order. (Its stopping rule, a change below 0.5 % from
    // m−1 to m, stops at m = 6 here with 0.75 % still left to go.)
    let c = calib_2d();
    let spec = PsfSpec {
        channel: 1,
        psi_rad: c.psi_rad(1, 1.5),
    };
    let set = psfs(&c, vec![spec], None).expect("psf");
    let p = &set.psfs[0];
    let ch = &set.report.channels[0];
    let grid = PupilGrid::covering(c.aperture_radius_m, ch.pupil_step_um * 1e-6);
    let q = pupil_field(grid, c.aperture_radius_m, spec.psi_rad, None);
    let error = |m: usize| {
        let full = fft_period_cells(&q, grid, 530e-9, c.retinal_step_rad(), m).expect("period");
        let cells = crop_centred(&full, ch.period_cells, p.window);
        cells
            .iter()
            .zip(&p.cells)
            .map(|(x, y)| (x - y).abs())
            .sum::<f64>()
    };
    let (e6, e12) = (error(6), error(12));
    assert!(e12 < 0.0025, "m = 12 is {e12} from the exact cells");
    assert!((e6 / e12 - 4.0).abs() < 0.5, "second order: {e6} / {e12}");
}

#[test]
fn large_defocus_refines_the_pupil_instead_of_aliasing() {
    let mut c = calib_2d();
    c.simulation.min_pupil_samples = 64;
    // Far beyond the design range: the blur outgrows a coarse period.
    let spec = PsfSpec {
        channel: 2,
        psi_rad: 600.0,
    };
    let set = psfs(&c, vec![spec], None).expect("psf");
    assert!(set.report.min_window_energy >= c.simulation.window_energy);
    assert!(set.report.window_cells <= set.report.channels[0].period_cells);
}

#[test]
fn forced_step_breaking_a_rule_is_an_error() {
    let mut c = calib();
    c.simulation.pupil_step_m = Some(30e-6);
    let spec = PsfSpec {
        channel: 2,
        psi_rad: c.psi_rad(2, 3.0),
    };
    let e = psfs(&c, vec![spec], None).expect_err("rule 2");
    assert!(e.to_string().contains("rule 2"), "{e}");
    let doe = HeightMap::three_lens_init(&c, 6e-6);
    c.simulation.pupil_step_m = Some(8e-6);
    let e = psfs(
        &c,
        vec![PsfSpec {
            channel: 1,
            psi_rad: 0.0,
        }],
        Some(&doe),
    )
    .expect_err("rule 1");
    assert!(e.to_string().contains("rule 1"), "{e}");
}

#[test]
fn psi_beyond_the_largest_pupil_grid_is_an_error_not_an_alias() {
    let c = calib();
    // ≈ 140 D of defocus: rule 2 asks for a 0.2 µm step, 51 000 samples.
    let spec = PsfSpec {
        channel: 1,
        psi_rad: 20_000.0,
    };
    let e = psfs(&c, vec![spec], None).expect_err("grid too large");
    let text = e.to_string();
    assert!(matches!(e, OpticsError::GridTooLarge { .. }), "{text}");
    assert!(text.contains("max_pupil_samples"), "{text}");
}

#[test]
fn the_weighted_sum_centres_smaller_windows_and_weights_the_veil() {
    let wide = Psf {
        window: 3,
        cells: vec![1.0; 9],
        veil: 0.5,
    };
    let point = Psf {
        window: 1,
        cells: vec![4.0],
        veil: 0.0,
    };
    let sum = Psf::weighted_sum([(&wide, 0.25), (&point, 0.5)]).expect("terms");
    assert_eq!(sum.window, 3);
    let mut want = vec![0.25; 9];
    want[4] += 2.0;
    assert_eq!(sum.cells, want);
    assert_eq!(sum.veil, 0.125);
    assert!(Psf::weighted_sum(std::iter::empty::<(&Psf, f64)>()).is_none());
}

#[test]
fn trimming_moves_only_the_far_light_to_the_veil_and_padding_undoes_it() {
    let p = Psf::gaussian(2.0, 0.01).padded(41);
    assert_eq!(p.window, 41);
    let far: f64 = (0..41 * 41)
        .filter(|i: &usize| (i % 41).abs_diff(20).max((i / 41).abs_diff(20)) > 6)
        .map(|i| p.cells[i])
        .sum();
    let t = p.trimmed(1e-9);
    // ±3σ is the Gaussian's own window: nothing lies beyond it.
    assert_eq!(t.window, 13);
    assert!(far == 0.0 && t.veil == p.veil);
    assert_eq!(t.padded(41), p);
    // A looser bound drops the outer ring, whose light joins the veil.
    let ring: f64 = (0..13 * 13)
        .filter(|i: &usize| (i % 13).abs_diff(6).max((i / 13).abs_diff(6)) == 6)
        .map(|i| t.cells[i])
        .sum();
    let loose = t.trimmed(ring * 1.0001);
    assert_eq!(loose.window, 11);
    assert!((loose.veil - t.veil - ring).abs() < 1e-15);
    let total = |q: &Psf| q.cells.iter().sum::<f64>() + q.veil;
    assert!((total(&loose) - total(&t)).abs() < 1e-15);
}

#[test]
fn a_request_over_the_memory_budget_gives_the_same_psfs_in_two_passes() {
    // The lens alone (the window inside the period) and the three-lens DOE
    // (the window capped by the period): held whole and in two passes.
    let c = calib_2d();
    let doe = HeightMap::three_lens_init(&c, 6e-6);
    for doe in [None, Some(&doe)] {
        let specs: Vec<PsfSpec> = [(0, 0.0), (1, 1.0), (2, 2.5)]
            .iter()
            .map(|&(ch, d)| PsfSpec {
                channel: ch,
                psi_rad: c.psi_rad(ch, d),
            })
            .collect();
        let request = PsfRequest { specs, doe };
        let counted = |budget: usize| {
            let ticks = std::sync::atomic::AtomicUsize::new(0);
            let tick = || {
                ticks.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            };
            let set = two_d::compute_within(&c, &request, &tick, std::time::Instant::now(), budget)
                .expect("psfs");
            (set, ticks.into_inner())
        };
        let (whole, whole_ticks) = counted(usize::MAX);
        let (passes, passes_ticks) = counted(0);
        // The same PSFs, to the rounding of parallel sums (whose order the
        // threads' timing decides).
        assert_eq!(whole.psfs.len(), passes.psfs.len());
        for (p, q) in whole.psfs.iter().zip(&passes.psfs) {
            assert_eq!(p.window, q.window);
            let worst = p
                .cells
                .iter()
                .zip(&q.cells)
                .chain(std::iter::once((&p.veil, &q.veil)))
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(
                worst < 1e-14,
                "doe: {}: cells {worst:e} apart",
                doe.is_some()
            );
        }
        let (a, b) = (&whole.report, &passes.report);
        assert_eq!(
            (a.window_cells, a.window_capped, a.refinements),
            (b.window_cells, b.window_capped, b.refinements)
        );
        // One tick per PSF made (the silent first pass makes none).
        assert_eq!(whole_ticks, request.specs.len() * (1 + a.refinements));
        assert_eq!(passes_ticks, request.specs.len());
    }
}
