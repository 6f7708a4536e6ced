//! The planner's radial path: rotationally symmetric pupils (the lens
//! alone, radial DOE profiles) by the Hankel transform of
//! [`crate::radial`], with the same window rule as the 2-D path.
//!
//! - Pupil step Δρ = r / N_ρ, N_ρ = ⌈r / Δρ_max⌉, Δρ_max the smallest of
//!   rules 1, 2 and 4 (or the configured step) and the kernel's Nyquist
//!   limit at the window's corner, λ_min / (2 θ_corner), θ_corner =
//!   √2 (H + ½) Δθ: beyond it the sampled Hankel sum aliases, as the 2-D
//!   transform does beyond its period.
//! - Window: the smallest odd W whose centred block holds
//!   `simulation.window_energy` for every PSF. With a DOE its half-width is
//!   capped at the 2-D path's (the DOE's period at the step the 2-D path
//!   would choose), so both paths report the same window and a comparable
//!   veil; the lens alone has no period: the window grows until the energy
//!   holds, up to [`MAX_HALF_WIDTH_CELLS`].

use std::f64::consts::SQRT_2;

use super::*;
use crate::radial::{ANNULI_PER_CELL, RadialGrid, WindowCells, angular_density, pupil_profile};

/// Largest half-width (cells) the lens-alone window may grow to: 1024 cells
/// is ≈ 9° off axis at the default retinal step, far past any blur of the
/// display's range (0–3 D needs ≈ 170) and the paraxial model's reach; the
/// cell weights alone would take ≈ 100 MB.
pub const MAX_HALF_WIDTH_CELLS: usize = 1024;

/// Computes the PSFs of `request` by the radial path (see the module doc).
pub(super) fn compute(
    calib: &Calibration,
    request: &PsfRequest,
    tick: &(dyn Fn() + Sync),
    start: Instant,
) -> Result<PsfSet, OpticsError> {
    let (cap, cap_rule) = step_cap(calib, request)?;
    let r = calib.aperture_radius_m;
    let dtheta = calib.retinal_step_rad();
    let channels = request_channels(request);
    let target = calib.simulation.window_energy;
    let shortest = channels
        .iter()
        .copied()
        .min_by(|a, b| {
            calib.channels[*a]
                .wavelength_m
                .total_cmp(&calib.channels[*b].wavelength_m)
        })
        .ok_or(OpticsError::EmptyRequest)?;
    let lambda_min = calib.channels[shortest].wavelength_m;

    // With a DOE, the 2-D path's periods (and so its window cap).
    let periods: Option<Vec<usize>> = match request.doe {
        Some(_) => {
            let min_period = predicted_min_period(calib, request);
            Some(
                channels
                    .iter()
                    .map(|&ch| channel_sampling(calib, ch, cap, min_period).map(|s| s.period_cells))
                    .collect::<Result<_, _>>()?,
            )
        }
        None => None,
    };
    let mut half = match &periods {
        Some(p) => p.iter().map(|p| (p - 1) / 2).min().unwrap_or(0),
        None => {
            let predicted = request
                .specs
                .iter()
                .map(|s| predicted_half_width_cells(calib, *s))
                .fold(0.0, f64::max);
            ((1.15 * predicted).ceil() as usize + 2).min(MAX_HALF_WIDTH_CELLS)
        }
    };

    for growth in 0.. {
        let corner_rad = SQRT_2 * (half as f64 + 0.5) * dtheta;
        let nyquist = lambda_min / (2.0 * corner_rad);
        let (step_max, rule) = if nyquist < cap {
            (nyquist, StepRule::KernelNyquist)
        } else {
            (cap, cap_rule)
        };
        let nodes = (r / step_max - 1e-9).ceil().max(1.0) as usize;
        let grid = RadialGrid::with_nodes(r, nodes);
        if 2 * nodes > calib.simulation.max_pupil_samples {
            return Err(OpticsError::GridTooLarge {
                channel: calib.channels[shortest].name.clone(),
                samples: 2 * nodes,
                step_um: grid.step_m * 1e6,
                limit: calib.simulation.max_pupil_samples,
            });
        }
        let window_cells = WindowCells::new(half, dtheta, ANNULI_PER_CELL);
        let cells = radial_cells(calib, request, &channels, grid, &window_cells, tick)?;
        let w = window_cells.window();

        let energies: Vec<Vec<f64>> = cells
            .iter()
            .map(|c| centred_window_energies(c, w))
            .collect();
        let needed: Option<usize> = energies.iter().try_fold(0usize, |acc, e| {
            e.iter().position(|&v| v >= target).map(|k| acc.max(k))
        });
        let chosen = match (needed, request.doe) {
            (Some(k), _) => k,
            // A DOE's light beyond the 2-D period stays a veil, as there.
            (None, Some(_)) => half,
            (None, None) => {
                if half >= MAX_HALF_WIDTH_CELLS {
                    return Err(OpticsError::RuleViolated(format!(
                        "no window up to {} cells holds {:.3}% of the light (rule 5); \
                         lower simulation.window_energy",
                        2 * MAX_HALF_WIDTH_CELLS + 1,
                        100.0 * target
                    )));
                }
                half = (half + half / 2 + 8).min(MAX_HALF_WIDTH_CELLS);
                tracing::debug!("radial window grows to {} cells", 2 * half + 1);
                continue;
            }
        };
        let window = 2 * chosen + 1;
        let psfs: Vec<Psf> = cells
            .iter()
            .zip(&energies)
            .map(|(c, e)| Psf {
                window,
                cells: crop_centred(c, w, window),
                veil: (1.0 - e[chosen]).max(0.0),
            })
            .collect();
        let report = SamplingReport {
            propagator: Propagator::Radial,
            annuli_per_cell: window_cells.annuli_per_cell(),
            channels: channels
                .iter()
                .enumerate()
                .map(|(i, &ch)| {
                    let (grid, _) = channel_grid(calib, ch, grid);
                    ChannelReport {
                        name: calib.channels[ch].name.clone(),
                        pupil_step_um: grid.step_m * 1e6,
                        pupil_samples: grid.nodes(),
                        period_cells: periods.as_ref().map_or(0, |p| p[i]),
                    }
                })
                .collect(),
            step_rule: rule,
            window_cells: window,
            min_window_energy: energies.iter().map(|e| e[chosen]).fold(f64::MAX, f64::min),
            max_veil: psfs.iter().map(|p| p.veil).fold(0.0, f64::max),
            window_capped: needed.is_none(),
            refinements: growth,
            psf_count: psfs.len(),
            compute_s: start.elapsed().as_secs_f64(),
            from_cache: false,
        };
        return Ok(PsfSet { psfs, report });
    }
    unreachable!("the growth loop returns or errs")
}

/// The quadrature of channel `ch` and the factor on its Ψ: the planner's
/// `grid`, or where a centred eye pupil smaller than the aperture is the
/// stop, a grid whose edge is the stop's (at no coarser a step); Ψ is
/// defined over the eyepiece's radius r, so over the stop's r_e it is
/// Ψ (r_e/r)² (docs/model.md §4a).
fn channel_grid(calib: &Calibration, ch: usize, grid: RadialGrid) -> (RadialGrid, f64) {
    match calib.eye_stop(ch) {
        Some(stop) => {
            let nodes = (stop.radius_m / grid.step_m - 1e-9).ceil().max(1.0) as usize;
            (
                RadialGrid::with_nodes(stop.radius_m, nodes),
                (stop.radius_m / grid.radius_m).powi(2),
            )
        }
        None => (grid, 1.0),
    }
}

/// The W×W cells of every spec of the request (in its order): per channel
/// one J0 kernel for all of that channel's pupils, the DOE's phase at the
/// nodes computed once per channel.
fn radial_cells(
    calib: &Calibration,
    request: &PsfRequest,
    channels: &[usize],
    grid: RadialGrid,
    window: &WindowCells,
    tick: &(dyn Fn() + Sync),
) -> Result<Vec<Vec<f64>>, OpticsError> {
    let angles = window.angles_rad();
    let mut out: Vec<Vec<f64>> = vec![Vec::new(); request.specs.len()];
    for &ch in channels {
        let (grid, scale) = channel_grid(calib, ch, grid);
        let radii = grid.sample_radii_m();
        let phase = match request.doe {
            Some(d) => Some(d.phase_at_radii(&radii, calib, ch).ok_or_else(|| {
                OpticsError::BadSpec("a 2-D DOE map has no radial profile".into())
            })?),
            None => None,
        };
        let members: Vec<usize> = (0..request.specs.len())
            .filter(|&i| request.specs[i].channel == ch)
            .collect();
        let pupils: Vec<_> = members
            .iter()
            .map(|&i| pupil_profile(grid, scale * request.specs[i].psi_rad, phase.as_deref()))
            .collect();
        let densities = angular_density(grid, calib.channels[ch].wavelength_m, &pupils, &angles);
        for (&i, d) in members.iter().zip(&densities) {
            out[i] = window.cells(d);
            tick();
        }
    }
    Ok(out)
}
