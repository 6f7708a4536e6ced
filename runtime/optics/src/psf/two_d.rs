//! The 2-D path: each PSF over a whole period with every cell integrated
//! exactly, the window chosen from all of them.

use std::time::Instant;

use rayon::prelude::*;

use super::{
    ChannelReport, MAX_REFINEMENTS, Propagator, Psf, PsfRequest, PsfSet, SamplingReport,
    predicted_min_period, request_channels, step_cap,
};
use crate::OpticsError;
use crate::propagate::{centred_window_energies, crop_centred, exact_period_cells};
use crate::pupil::{PupilGrid, pupil_field, pupil_field_through, stop_square};
use crate::sampling::{ChannelSampling, StepRule, channel_sampling};
use nedrt_core::calib::Calibration;

/// Full-period PSF.
struct PeriodPsf {
    cells: Vec<f64>,
    period: usize,
}

/// Most bytes of whole-period PSFs held at once. A request whose periods
/// need more (a free-form map at a 10 mm aperture, a Wiener's depth
/// sweep: a hundred PSFs of a few thousand cells square) is computed
/// twice: first for each PSF's energies alone, then, the window chosen,
/// each PSF cropped as it comes. The same PSFs (to the rounding of
/// parallel sums) in twice the time and the memory of the windows.
const PERIODS_BUDGET_BYTES: usize = 2 << 30;

/// The 2-D path: exact cells over one period per PSF, the pupil step
/// refined (lens alone) until the window fits in the period.
pub(super) fn compute(
    calib: &Calibration,
    request: &PsfRequest,
    tick: &(dyn Fn() + Sync),
    start: Instant,
) -> Result<PsfSet, OpticsError> {
    compute_within(calib, request, tick, start, PERIODS_BUDGET_BYTES)
}

/// [`compute`] holding at most `budget_bytes` of whole periods.
pub(super) fn compute_within(
    calib: &Calibration,
    request: &PsfRequest,
    tick: &(dyn Fn() + Sync),
    start: Instant,
    budget_bytes: usize,
) -> Result<PsfSet, OpticsError> {
    let (mut step_cap, step_rule) = step_cap(calib, request)?;
    let mut min_period = predicted_min_period(calib, request);
    let channels = request_channels(request);
    let target = calib.simulation.window_energy;

    for refinement in 0..=MAX_REFINEMENTS {
        let sampling: Vec<ChannelSampling> = channels
            .iter()
            .map(|&ch| channel_sampling(calib, ch, step_cap, min_period))
            .collect::<Result<_, _>>()?;
        let dtheta = calib.retinal_step_rad();
        let window_limited = refinement > 0
            || channels.iter().any(|&ch| {
                calib.channels[ch].wavelength_m / (step_cap * dtheta) < min_period as f64
            });
        let rule = if window_limited {
            StepRule::Window
        } else {
            step_rule
        };
        let period_of = |channel: usize| {
            sampling
                .iter()
                .find(|s| s.channel == channel)
                .map_or(0, |s| s.period_cells)
        };
        let period_bytes: usize = request
            .specs
            .iter()
            .map(|s| period_of(s.channel).pow(2) * std::mem::size_of::<f64>())
            .sum();
        let two_passes = period_bytes > budget_bytes;
        if two_passes {
            tracing::info!(
                "PSFs: the periods of {} PSFs need {:.1} GB, over the {:.1} GB held at once: \
                 energies first, then each PSF cropped to the window",
                request.specs.len(),
                period_bytes as f64 / 1e9,
                budget_bytes as f64 / 1e9
            );
        }
        // Each PSF's energies and period; its cells too in one pass.
        let silent = || {};
        let firsts = compute_periods(
            calib,
            request,
            &sampling,
            if two_passes { &silent } else { tick },
            &|p: PeriodPsf| {
                let e = centred_window_energies(&p.cells, p.period);
                (e, p.period, (!two_passes).then_some(p.cells))
            },
        )?;

        // Smallest odd window holding the target energy for every PSF.
        let mut half_needed = 0usize;
        let mut fits = true;
        for (e, _, _) in &firsts {
            match e.iter().position(|&v| v >= target) {
                Some(k) => half_needed = half_needed.max(k),
                None => fits = false,
            }
        }
        let half_cap = firsts.iter().map(|f| (f.1 - 1) / 2).min().unwrap_or(0);
        // The period caps the window below the energy target.
        let capped = !fits || half_needed > half_cap;
        if capped {
            let can_refine = request.doe.is_none() && calib.simulation.pupil_step_m.is_none();
            if can_refine && refinement < MAX_REFINEMENTS {
                // Lens only: the blur outgrew the period; halve the step.
                step_cap = sampling
                    .iter()
                    .map(|s| s.grid.step_m)
                    .fold(f64::MAX, f64::min)
                    / 2.0;
                min_period *= 2;
                tracing::debug!(
                    "window outgrew the period; refining the pupil step to {:.3} µm",
                    step_cap * 1e6
                );
                continue;
            }
            if request.doe.is_none() {
                return Err(OpticsError::RuleViolated(format!(
                    "no window within one period holds {:.3}% of the light (rules 3 and 5); \
                     allow a finer pupil step or a lower simulation.window_energy",
                    100.0 * target
                )));
            }
        }
        let half = if capped { half_cap } else { half_needed };
        let window = 2 * half + 1;
        let (energies, cells): (Vec<Vec<f64>>, Vec<Vec<f64>>) = if two_passes {
            let cells = compute_periods(calib, request, &sampling, tick, &|p: PeriodPsf| {
                crop_centred(&p.cells, p.period, window)
            })?;
            (firsts.into_iter().map(|f| f.0).collect(), cells)
        } else {
            firsts
                .into_iter()
                .map(|(e, period, cells)| {
                    let cells = crop_centred(&cells.unwrap_or_default(), period, window);
                    (e, cells)
                })
                .unzip()
        };
        let psfs: Vec<Psf> = cells
            .into_iter()
            .zip(&energies)
            .map(|(cells, e)| Psf {
                window,
                veil: (1.0 - e[half]).max(0.0),
                cells,
            })
            .collect();
        let report = SamplingReport {
            propagator: Propagator::TwoD,
            annuli_per_cell: 0,
            channels: sampling
                .iter()
                .map(|s| ChannelReport {
                    name: calib.channels[s.channel].name.clone(),
                    pupil_step_um: s.grid.step_m * 1e6,
                    // Through an eye stop only its square is computed.
                    pupil_samples: calib.eye_stop(s.channel).map_or(s.grid.samples, |stop| {
                        stop_square(s.grid.step_m, stop).samples
                    }),
                    period_cells: s.period_cells,
                })
                .collect(),
            step_rule: rule,
            window_cells: window,
            min_window_energy: energies.iter().map(|e| e[half]).fold(f64::MAX, f64::min),
            max_veil: psfs.iter().map(|p| p.veil).fold(0.0, f64::max),
            window_capped: capped,
            refinements: refinement,
            psf_count: psfs.len(),
            compute_s: start.elapsed().as_secs_f64(),
            from_cache: false,
        };
        return Ok(PsfSet { psfs, report });
    }
    unreachable!("the refinement loop returns or errs on its last pass")
}

/// Full-period PSFs of every spec, each cell integrated exactly, each
/// handed to `keep` as it is made (what is kept of it is returned).
fn compute_periods<T: Send>(
    calib: &Calibration,
    request: &PsfRequest,
    sampling: &[ChannelSampling],
    tick: &(dyn Fn() + Sync),
    keep: &(dyn Fn(PeriodPsf) -> T + Sync),
) -> Result<Vec<T>, OpticsError> {
    // The DOE's phase depends only on the channel's grid: once per channel.
    let phases: Vec<Option<Vec<f64>>> = sampling
        .iter()
        .map(|s| {
            request
                .doe
                .map(|d| d.phase_on(s.grid.into(), calib, s.channel))
        })
        .collect();
    let one = |spec: &crate::sampling::PsfSpec| -> Result<T, OpticsError> {
        let i = sampling
            .iter()
            .position(|s| s.channel == spec.channel)
            .ok_or_else(|| OpticsError::BadSpec(format!("{spec:?}")))?;
        let s = &sampling[i];
        let full: PupilGrid = s.grid.into();
        let (q, grid) = match calib.eye_stop(s.channel) {
            Some(stop) => pupil_field_through(
                full,
                calib.aperture_radius_m,
                spec.psi_rad,
                phases[i].as_deref(),
                stop,
            ),
            None => (
                pupil_field(
                    full,
                    calib.aperture_radius_m,
                    spec.psi_rad,
                    phases[i].as_deref(),
                ),
                full,
            ),
        };
        let lambda = calib.channels[s.channel].wavelength_m;
        let cells = exact_period_cells(&q, grid, lambda, calib.retinal_step_rad())
            .ok_or_else(|| OpticsError::BadSpec("period is not a whole number of cells".into()))?;
        tick();
        Ok(keep(PeriodPsf {
            cells,
            period: s.period_cells,
        }))
    };
    // As many PSFs in flight as threads: a thread waiting inside one PSF's
    // parallel transforms would otherwise steal and start another, each
    // holding its (2N)² transform (docs/model.md §6, the 2-D path).
    let mut out = Vec::with_capacity(request.specs.len());
    for chunk in request.specs.chunks(rayon::current_num_threads().max(1)) {
        out.extend(chunk.par_iter().map(one).collect::<Result<Vec<T>, _>>()?);
    }
    Ok(out)
}
