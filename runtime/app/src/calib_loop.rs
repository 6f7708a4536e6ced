//! The closed loop (docs/calibration.md §5): a display built unlike its
//! design, preprocessed from three sets of PSFs (the design's, a measured
//! bundle's, the built optics' own: the oracle) and scored through the
//! built optics. What calibration earns is how much of the oracle's gain
//! over the design it recovers.

use std::collections::HashMap;
use std::sync::Arc;

use nedrt_core::image::Image;
use nedrt_optics::bundle::PsfBundle;
use nedrt_optics::sim::metrics::psnr;
use nedrt_optics::sim::{Method, Simulator};
use nedrt_stages::preprocess::{Prefilter, for_system};

use crate::{AppError, CommonOptions};

/// Mean PSNR vs the sharp image over the depths and images, dB.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopScores {
    pub design: f64,
    pub measured: Option<f64>,
    pub oracle: f64,
}

impl LoopScores {
    /// The share of the oracle's gain over the design that the measured
    /// PSFs recover (1: all of it); None without a measurement or gain.
    pub fn recovered_share(&self) -> Option<f64> {
        let gain = self.oracle - self.design;
        self.measured
            .filter(|_| gain.abs() > 1e-9)
            .map(|m| (m - self.design) / gain)
    }
}

/// Scores `method` with `prefilter` (a method through the DOE whose
/// preprocessing needs no network) on the `built` display: preprocessed
/// from the design's PSFs (`design`), from `measured` (if given) and from
/// the built optics' own, every display image seen through the built
/// optics at `depths_d`.
#[allow(clippy::too_many_arguments)]
pub fn scores(
    common: &CommonOptions,
    design: &Simulator,
    built: &Simulator,
    measured: Option<Arc<PsfBundle>>,
    method: Method,
    prefilter: Prefilter,
    images: &[Image],
    depths_d: &[f64],
) -> Result<LoopScores, AppError> {
    if method.uses_dcnn() || method.optics() != nedrt_optics::sim::Optics::Doe {
        return Err(AppError::option(
            format!("method {method}"),
            "the closed loop scores methods through the DOE without a network",
        ));
    }
    let seen = built.prepare(&[Method::DoeOnly], depths_d, common.progress())?;
    let score = |sim: &Simulator| -> Result<f64, AppError> {
        let mut depths = prefilter.depths_d(&sim.calib);
        depths.extend_from_slice(depths_d);
        let prepared = sim.prepare(&[method], &depths, common.progress())?;
        let mut total = 0.0;
        let mut n = 0.0;
        for img in images {
            let mut pre = for_system(method, prefilter, &prepared, &mut HashMap::new())?;
            let display = pre.run(img)?;
            let sharp = img.up2();
            for &d in depths_d {
                let perceived = seen.perceived(Method::DoeOnly, &display, d)?;
                total += psnr(&perceived, &sharp);
                n += 1.0;
            }
        }
        Ok(total / n)
    };
    let measured = match measured {
        Some(b) => {
            let sim = Simulator::with_doe(
                design.calib.clone(),
                design.doe.clone(),
                design.cache.clone(),
            )
            .with_measured(b)?;
            Some(score(&sim)?)
        }
        None => None,
    };
    Ok(LoopScores {
        design: score(design)?,
        measured,
        oracle: score(built)?,
    })
}
