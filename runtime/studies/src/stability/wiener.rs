//! The Wiener constant K over decades, for each Wiener method and design,
//! on clean and noisy frames: the numbers, as typed rows.

use serde::Serialize;

use super::{FRAME_NOISE_SIGMA, K_SWEEP, noisy};
use crate::AppError;
use crate::tradeoff::Scorer;
use nedrt_optics::sim::wiener::{CLIP_WARN_FRACTION, WienerFilter, clipped_fraction};
use nedrt_optics::sim::{Image, Method, Simulator};

/// The K sweep of every Wiener method.
#[derive(Debug, Clone, Serialize)]
pub struct WienerSection {
    pub frame_noise_sigma: f32,
    pub methods: Vec<WienerSweep>,
}

/// One method's (and design's) sweep.
#[derive(Debug, Clone, Serialize)]
pub struct WienerSweep {
    pub method: &'static str,
    pub design: Option<String>,
    /// The eye (`nedrt stability --eyes`), where not the calibration's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub eye: Option<String>,
    pub doe_hash: String,
    pub k_tuned: f64,
    /// Mean PSNR without a prefilter, clean then noisy frames.
    pub unprocessed_psnr_db: [f64; 2],
    pub sweep: Vec<KRow>,
    /// The row label: the method, and the design if any.
    #[serde(skip)]
    pub label: String,
    /// The first swept K from which the filter only blurs, and whether it
    /// is worse than no prefilter there.
    #[serde(skip)]
    pub blur_only_from: Option<(f64, bool)>,
}

/// One K: mean PSNR and the share of values the clamp cuts, clean and noisy.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct KRow {
    pub k: f64,
    pub clean_psnr_db: f64,
    pub clean_clipped: f64,
    pub noisy_psnr_db: f64,
    pub noisy_clipped: f64,
}

/// One sweep: a method on a simulator, its design ("" for the D-CNN's
/// DOE) and the eye it looks through (`None`: the calibration's).
#[derive(Debug)]
pub struct SweepCase<'a> {
    pub design: &'a str,
    pub eye: Option<&'a str>,
    pub sim: &'a Simulator,
    pub method: Method,
}

/// Sweeps K for each case.
pub fn sweep(sweeps: &[SweepCase], inputs: &[Image]) -> Result<WienerSection, AppError> {
    let noisy_inputs: Vec<Image> = inputs
        .iter()
        .enumerate()
        .map(|(i, im)| noisy(im, 100 + i as u64))
        .collect();
    let mut methods = Vec::new();
    for case in sweeps {
        let (design, sim, method) = (case.design, case.sim, case.method);
        let mut label = if design.is_empty() {
            method.name().to_string()
        } else {
            format!("{method} {design}")
        };
        if let Some(eye) = case.eye {
            label += &format!(", eye {eye}");
        }
        let scorer = Scorer::new(sim, &[method], inputs, &nedrt_core::progress::Silent)?;
        let filter = scorer
            .prepared
            .wiener(method)
            .ok_or_else(|| AppError::Unavailable(format!("{method} has no Wiener filter")))?;
        let unprocessed = [
            scorer.quality(method, inputs)?.mean_psnr_db,
            scorer.quality(method, &noisy_inputs)?.mean_psnr_db,
        ];
        let mut rows = Vec::new();
        for k in K_SWEEP {
            let f = filter.with_k(k);
            let mut cells = Vec::new();
            for frames in [inputs, &noisy_inputs[..]] {
                let raw: Vec<Image> = frames.iter().map(|i| f.apply_unclamped(i)).collect();
                let clipped = raw.iter().map(clipped_fraction).sum::<f64>() / raw.len() as f64;
                let shown: Vec<Image> = raw.into_iter().map(Image::clamped).collect();
                let q = scorer.quality(method, &shown)?;
                cells.push((q.mean_psnr_db, clipped));
            }
            rows.push(KRow {
                k,
                clean_psnr_db: cells[0].0,
                clean_clipped: cells[0].1,
                noisy_psnr_db: cells[1].0,
                noisy_clipped: cells[1].1,
            });
        }
        let blur_only_from = blur_only_from(filter, &rows, unprocessed[0]);
        methods.push(WienerSweep {
            method: method.name(),
            design: (!design.is_empty()).then(|| design.to_string()),
            eye: case.eye.map(str::to_string),
            doe_hash: sim.doe_hash.clone(),
            k_tuned: filter.k_reg,
            unprocessed_psnr_db: unprocessed,
            sweep: rows,
            label,
            blur_only_from,
        });
    }
    Ok(WienerSection {
        frame_noise_sigma: FRAME_NOISE_SIGMA,
        methods,
    })
}

fn blur_only_from(filter: &WienerFilter, rows: &[KRow], unprocessed: f64) -> Option<(f64, bool)> {
    rows.iter()
        .find(|r| filter.with_k(r.k).blur_only_warning().is_some())
        .map(|r| (r.k, r.clean_psnr_db < unprocessed))
}

impl WienerSweep {
    /// The findings of this sweep, from its numbers.
    pub fn finding(&self) -> String {
        let rows = &self.sweep;
        let unprocessed = self.unprocessed_psnr_db;
        let fmt_k = |k: Option<f64>| k.map_or("none of the swept K".into(), |k| format!("{k:e}"));
        let helps: Vec<f64> = rows
            .iter()
            .filter(|r| r.clean_psnr_db > unprocessed[0])
            .map(|r| r.k)
            .collect();
        let best = rows
            .iter()
            .max_by(|a, b| a.clean_psnr_db.total_cmp(&b.clean_psnr_db));
        let clamp_bound = rows
            .iter()
            .filter(|r| r.clean_clipped > CLIP_WARN_FRACTION)
            .map(|r| r.k)
            .reduce(f64::max);
        let mut f = format!(
            "{}: the prefilter beats no prefilter ({:.2} dB) only for K in [{}, {}]",
            self.label,
            unprocessed[0],
            fmt_k(helps.first().copied()),
            fmt_k(helps.last().copied())
        );
        if let Some(b) = best {
            f += &format!(
                "; best K {:e} ({:.2} dB) already clamps {:.0} % of the values, and frame noise costs {:.2} dB there",
                b.k,
                b.clean_psnr_db,
                100.0 * b.clean_clipped,
                b.clean_psnr_db - b.noisy_psnr_db
            );
        }
        if let (Some(k), Some(s)) = (clamp_bound, rows.first()) {
            f += &format!(
                "; at K ≤ {k:e} the clamp cuts over {:.0} % and the ringing it cuts is lost: {:.2} dB at K = {:e}, where noise costs a further {:.2} dB (the filter amplifies it)",
                100.0 * CLIP_WARN_FRACTION,
                s.clean_psnr_db,
                s.k,
                s.clean_psnr_db - s.noisy_psnr_db
            );
        }
        if let Some((k, worse)) = self.blur_only_from {
            f += &format!(
                "; from K = {k:e} the filter amplifies no frequency and only blurs ({} than none)",
                if worse { "worse" } else { "not yet worse" }
            );
        }
        f + "."
    }
}
