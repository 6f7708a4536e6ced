//! The optics beyond their sampling, as typed rows: Ψ past what a pupil
//! grid can sample, PSF windows too small for the energy rule, DOE heights
//! outside the fabrication range. Each case is run and its outcome
//! (refinement, veil or error) recorded.

use serde::Serialize;

use crate::AppError;
use nedrt_optics::sampling::{channel_sampling, max_pupil_step};
use nedrt_optics::sim::Simulator;
use nedrt_optics::{HeightMap, PsfRequest, PsfSpec, SamplingReport, compute_psfs, doe_file};

/// Accommodations of the pupil-sampling sweep (lens alone, G), D.
const SWEEP_D: [f64; 7] = [0.0, 3.0, 10.0, 20.0, 30.0, 40.0, 100.0];

/// One accommodation of the pupil-sampling sweep.
#[derive(Debug, Clone, Serialize)]
pub struct PupilRow {
    pub accommodation_d: f64,
    pub psi_rad: f64,
    pub step_m: f64,
    /// "sampled", or the sampling error.
    pub outcome: String,
    /// The table's step (µm), samples and outcome cells.
    #[serde(skip)]
    pub shown: (f64, f64, String),
}

/// One PSF request with the DOE, at the planner's or a forced pupil step.
#[derive(Debug, Clone, Serialize)]
pub struct WindowRow {
    pub forced_step_m: Option<f64>,
    pub report: SamplingReport,
    #[serde(skip)]
    pub label: &'static str,
}

/// A DOE profile edited out of range, and what loading it did.
#[derive(Debug, Clone, Serialize)]
pub struct DoeHeightRow {
    pub profile: &'static str,
    pub outcome: String,
}

/// The optics beyond their sampling.
#[derive(Debug, Clone, Serialize)]
pub struct OpticsSection {
    pub pupil_sweep: Vec<PupilRow>,
    pub windows: Vec<WindowRow>,
    pub lens_forced_step_error: String,
    pub doe_heights: Vec<DoeHeightRow>,
    #[serde(skip)]
    pub channel: String,
    #[serde(skip)]
    pub max_pupil_samples: usize,
    #[serde(skip)]
    pub window_energy: f64,
}

impl OpticsSection {
    /// The first swept accommodation the sampling refuses.
    pub fn first_error_d(&self) -> Option<f64> {
        self.pupil_sweep
            .iter()
            .find(|r| r.outcome != "sampled")
            .map(|r| r.accommodation_d)
    }
}

pub fn section(sim: &Simulator) -> Result<OpticsSection, AppError> {
    let c = &sim.calib;
    let g = c.design_channel;
    let mut pupil_sweep = Vec::new();
    for d in SWEEP_D {
        let spec = PsfSpec {
            channel: g,
            psi_rad: c.psi_rad(g, d),
        };
        let (step, rule) = max_pupil_step(c, &[spec], None);
        let (outcome, shown) = match channel_sampling(c, g, step, 1) {
            Ok(s) => (
                "sampled".to_string(),
                (
                    s.grid.step_m * 1e6,
                    s.grid.samples as f64,
                    format!("sampled ({rule})"),
                ),
            ),
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
                (
                    e.to_string(),
                    (step * 1e6, 2.0 * c.aperture_radius_m / step, planner),
                )
            }
        };
        pupil_sweep.push(PupilRow {
            accommodation_d: d,
            psi_rad: spec.psi_rad,
            step_m: step,
            outcome,
            shown,
        });
    }

    // Windows too small for the energy rule. Every channel: the shortest
    // wavelength has the shortest period.
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
        windows.push(WindowRow {
            forced_step_m: forced,
            report: set.report,
            label,
        });
    }
    let mut lens = c.clone();
    lens.simulation.pupil_step_m = Some(30e-6);
    let lens_forced_step_error = compute_psfs(
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

    // DOE heights outside the fabrication range.
    let mut doe_heights = Vec::new();
    let peak = sim.doe.height_m.iter().copied().fold(0.0, f64::max);
    let max = sim.doe.max_height_m;
    let peak_at = sim
        .doe
        .height_m
        .iter()
        .position(|h| *h == peak)
        .unwrap_or(0);
    for profile in [
        "heights × 1.5 (beyond max_height_um)",
        "heights − 0.5 µm (negative)",
        "one sample at max + 10 %",
    ] {
        let mut map = sim.doe.clone();
        match profile.chars().next() {
            Some('o') => map.height_m[peak_at] = 1.1 * max,
            _ if profile.contains('×') => map.height_m.iter_mut().for_each(|h| *h *= 1.5),
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
        doe_heights.push(DoeHeightRow { profile, outcome });
    }
    Ok(OpticsSection {
        pupil_sweep,
        windows,
        lens_forced_step_error,
        doe_heights,
        channel: c.channels[g].name.clone(),
        max_pupil_samples: c.simulation.max_pupil_samples,
        window_energy: c.simulation.window_energy,
    })
}
