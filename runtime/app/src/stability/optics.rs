//! The optics beyond their sampling: Ψ past what a pupil grid can sample,
//! PSF windows too small for the energy rule, DOE heights outside the
//! fabrication range. Each case is run and its outcome (refinement, veil
//! or error) reported.

use std::fmt::Write as _;

use serde_json::{Value, json};

use crate::AppError;
use nedrt_optics::sampling::{channel_sampling, max_pupil_step};
use nedrt_optics::sim::Simulator;
use nedrt_optics::{HeightMap, PsfRequest, PsfSpec, compute_psfs, doe_file};

/// Accommodations of the pupil-sampling sweep (lens alone, G), D.
const SWEEP_D: [f64; 7] = [0.0, 3.0, 10.0, 20.0, 30.0, 40.0, 100.0];

pub fn section(sim: &Simulator) -> Result<(String, Value), AppError> {
    let c = &sim.calib;
    let g = c.design_channel;
    let mut md = format!(
        "\n## Optics beyond their sampling\n\n### Ψ beyond what a pupil grid can sample\n\n\
         Lens alone, channel {}: the step rule 2 asks for, and the grid it needs (limit `simulation.max_pupil_samples` = {}).\n\n\
         | D | Ψ rad | pupil step µm | samples | outcome |\n| --- | --- | --- | --- | --- |\n",
        c.channels[g].name, c.simulation.max_pupil_samples
    );
    let mut rows = Vec::new();
    let mut first_error = None;
    for d in SWEEP_D {
        let spec = PsfSpec {
            channel: g,
            psi_rad: c.psi_rad(g, d),
        };
        let (step, rule) = max_pupil_step(c, &[spec], None);
        let outcome = match channel_sampling(c, g, step, 1) {
            Ok(s) => {
                let _ = writeln!(
                    md,
                    "| {d} | {:.0} | {:.3} | {} | sampled ({rule}) |",
                    spec.psi_rad,
                    s.grid.step_m * 1e6,
                    s.grid.samples
                );
                "sampled".to_string()
            }
            Err(e) => {
                // The planner itself must refuse it the same way.
                let planner = compute_psfs(
                    c,
                    &PsfRequest {
                        specs: vec![spec],
                        doe: None,
                    },
                    &|| (),
                )
                .err()
                .map_or("**computed anyway**".into(), |e| format!("error: {e}"));
                let _ = writeln!(
                    md,
                    "| {d} | {:.0} | {:.3} | {:.0} | {planner} |",
                    spec.psi_rad,
                    step * 1e6,
                    2.0 * c.aperture_radius_m / step
                );
                first_error.get_or_insert(d);
                e.to_string()
            }
        };
        rows.push(json!({"accommodation_d": d, "psi_rad": spec.psi_rad, "step_m": step, "outcome": outcome}));
    }
    let _ = writeln!(
        md,
        "\nFindings:\n- Up to the grid limit the planner refines the pupil step automatically (rule 2, and rule 3 by halving when the blur outgrows the period); \
         from {} D on the request is refused with an error naming `max_pupil_samples`, never aliased.\n\
         - Guards: tests `large_defocus_refines_the_pupil_instead_of_aliasing` and `psi_beyond_the_largest_pupil_grid_is_an_error_not_an_alias` (nedrt_optics::psf).",
        first_error.map_or("no swept".into(), |d| format!("{d}"))
    );

    // Windows too small for the energy rule.
    let _ = writeln!(
        md,
        "\n### PSF windows too small for the energy rule\n\n\
         Rule 5 wants {:.1} % of the light in the window. With the DOE, rule 3 caps the window at one period λ/Δs of the pupil step; \
         what the window cannot hold becomes a uniform veil, reported. R, G and B at 0.5 / 1.5 / 2.5 D (pupil step of the first channel shown):\n\n\
         | DOE, pupil step | window cells | light in window | veil | capped |\n| --- | --- | --- | --- | --- |",
        100.0 * c.simulation.window_energy,
    );
    // Every channel: the shortest wavelength has the shortest period.
    let specs: Vec<PsfSpec> = (0..c.channels.len())
        .flat_map(|ch| {
            c.main_d.iter().map(move |&d| PsfSpec {
                channel: ch,
                psi_rad: c.psi_rad(ch, d),
            })
        })
        .collect();
    let mut windows = Vec::new();
    let init = HeightMap::three_lens_init(c, c.doe_design_pitch_m);
    let mut any_capped = false;
    for (label, doe, forced) in [
        ("trained", &sim.doe, None),
        ("trained", &sim.doe, Some(c.doe_fabrication_pitch_m)),
        ("three-lens initial", &init, None),
    ] {
        let mut cc = c.clone();
        // Never coarser than rule 2 allows at the shortest wavelength.
        cc.simulation.pupil_step_m =
            forced.map(|f| f.min(max_pupil_step(c, &specs, Some(doe)).0 * (1.0 - 1e-9)));
        let set = compute_psfs(
            &cc,
            &PsfRequest {
                specs: specs.clone(),
                doe: Some(doe),
            },
            &|| (),
        )?;
        let r = &set.report;
        any_capped |= r.window_capped;
        let _ = writeln!(
            md,
            "| {label} DOE, {} ({:.2} µm) | {} | ≥ {:.3} % | ≤ {:.3} % | {} |",
            forced.map_or("auto".into(), |s| format!("forced ≤ {:.0} µm", s * 1e6)),
            r.channels[0].pupil_step_um,
            r.window_cells,
            100.0 * r.min_window_energy,
            100.0 * r.max_veil,
            if r.window_capped { "yes (veil)" } else { "no" }
        );
        windows.push(json!({"forced_step_m": forced, "report": r}));
    }
    let mut lens = c.clone();
    lens.simulation.pupil_step_m = Some(30e-6);
    let lens_error = compute_psfs(
        &lens,
        &PsfRequest {
            specs: vec![PsfSpec {
                channel: g,
                psi_rad: c.psi_rad(g, 3.0),
            }],
            doe: None,
        },
        &|| (),
    )
    .err()
    .map_or("**computed anyway**".into(), |e| e.to_string());
    let _ = writeln!(
        md,
        "\nFindings:\n- {}\n\
         - For the lens alone the planner refines the step until the window holds the light; a forced step that cannot is refused: \
         `simulation.pupil_step_um = 30` at 3 D gives \"{lens_error}\".\n\
         - Guards: tests `doe_window_is_capped_by_its_period_and_the_rest_is_veil`, `lens_psfs_keep_all_light_in_window_plus_veil`, \
         `forced_step_breaking_a_rule_is_an_error` (nedrt_optics::psf).",
        if any_capped {
            "Where a DOE spreads light beyond one period (every row marked capped: its higher orders fall off only as 1/m²), \
             the window is capped by the period and the light it cannot hold is kept as a uniform veil, reported with every result, \
             never dropped or renormalised away."
        } else {
            "No DOE here needs more than one period: every window holds the energy rule's share."
        }
    );

    // DOE heights outside the fabrication range.
    let _ = writeln!(
        md,
        "\n### DOE profiles with heights outside the fabrication range\n\n\
         The trained DOE with its heights scaled or shifted, written as a height-map file and loaded back:\n\n| profile | outcome |\n| --- | --- |"
    );
    let mut doe_rows = Vec::new();
    let peak = sim.doe.height_m.iter().copied().fold(0.0, f64::max);
    let max = sim.doe.max_height_m;
    let peak_at = sim
        .doe
        .height_m
        .iter()
        .position(|h| *h == peak)
        .unwrap_or(0);
    for name in [
        "heights × 1.5 (beyond max_height_um)",
        "heights − 0.5 µm (negative)",
        "one sample at max + 10 %",
    ] {
        let mut map = sim.doe.clone();
        match name.chars().next() {
            Some('o') => map.height_m[peak_at] = 1.1 * max,
            _ if name.contains('×') => map.height_m.iter_mut().for_each(|h| *h *= 1.5),
            _ => map.height_m.iter_mut().for_each(|h| *h -= 0.5e-6),
        }
        let outcome = doe_file::to_bytes(&map)
            .map_err(|e| e.to_string())
            .and_then(|b| {
                doe_file::parse(&b, "edited.safetensors", c)
                    .map(|_| "**accepted**".to_string())
                    .map_err(|e| format!("refused: {e}"))
            })
            .unwrap_or_else(|e| e);
        let _ = writeln!(md, "| {name} | {outcome} |");
        doe_rows.push(json!({"profile": name, "outcome": outcome}));
    }
    md.push_str(
        "\nFindings:\n- Every out-of-range profile is refused when the file loads, with the row, column and height named; \
         the trainer keeps heights inside [0, max] by construction (a sigmoid), so only hand-made files reach this check.\n\
         - Guard: test `inconsistent_files_are_rejected_with_reasons` (nedrt_optics::doe_file) and the file fuzz tests beside it.\n",
    );
    Ok((
        md,
        json!({"pupil_sweep": rows, "windows": windows, "lens_forced_step_error": lens_error, "doe_heights": doe_rows}),
    ))
}
