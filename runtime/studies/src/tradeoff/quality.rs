//! Headline quality of display images: mean and worst PSNR (and mean
//! SSIM) against the sharp image over the evaluation depths 0–2.5 D,
//! averaged over an image set, as `nedrt eval` reports it.

use super::Record;
use super::pareto::Point;
use crate::AppError;
use crate::sim::Score;
use nedrt_optics::sim::simulator::Prepared;
use nedrt_optics::sim::{Image, Method, Simulator};

/// PSFs prepared for some methods at the headline depths, and the sharp
/// references of an image set.
#[derive(Debug)]
pub struct Scorer {
    pub prepared: Prepared,
    pub depths_d: Vec<f64>,
    sharps: Vec<Image>,
}

/// Quality of one configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Quality {
    pub mean_psnr_db: f64,
    pub worst_psnr_db: f64,
    pub mean_ssim: f64,
    /// Image-averaged PSNR per depth, (D, dB).
    pub per_depth_psnr_db: Vec<(f64, f64)>,
}

/// The evaluation depths within the headline range 0–2.5 D (those the
/// least-squares prefilters are solved over, so one request serves both).
pub fn headline_depths(calib: &nedrt_core::calib::Calibration) -> Vec<f64> {
    nedrt_optics::sim::objective_depths_d(calib)
}

impl Scorer {
    pub fn new(
        sim: &Simulator,
        methods: &[Method],
        inputs: &[Image],
        progress: &dyn nedrt_core::Progress,
    ) -> Result<Self, AppError> {
        let depths_d = headline_depths(&sim.calib);
        let prepared = sim.prepare(methods, &depths_d, progress)?;
        Ok(Self {
            prepared,
            depths_d,
            sharps: inputs.iter().map(Image::up2).collect(),
        })
    }

    /// Scores one display image per input, seen through `method`'s optics.
    pub fn quality(&self, method: Method, displays: &[Image]) -> Result<Quality, AppError> {
        score_depths(&self.depths_d, &self.sharps, |d, i| {
            Ok(self.prepared.perceived(method, &displays[i], d)?)
        })
    }
}

/// Mean over images per depth, then mean and worst over depths, of the
/// perceived images `perceive(depth, image index)` against `sharps`.
pub fn score_depths(
    depths_d: &[f64],
    sharps: &[Image],
    mut perceive: impl FnMut(f64, usize) -> Result<Image, AppError>,
) -> Result<Quality, AppError> {
    if depths_d.is_empty() || sharps.is_empty() {
        return Err(AppError::Unavailable(
            "no depths or no images to score".into(),
        ));
    }
    let mut per_depth = Vec::new();
    let mut ssim_sum = 0.0;
    for &d in depths_d {
        let mut psnr_sum = 0.0;
        for (i, sharp) in sharps.iter().enumerate() {
            let s = Score::of(&perceive(d, i)?, sharp);
            psnr_sum += s.psnr_db;
            ssim_sum += s.ssim;
        }
        per_depth.push((d, psnr_sum / sharps.len() as f64));
    }
    let n = per_depth.len() as f64;
    Ok(Quality {
        mean_psnr_db: per_depth.iter().map(|p| p.1).sum::<f64>() / n,
        worst_psnr_db: per_depth.iter().map(|p| p.1).fold(f64::INFINITY, f64::min),
        mean_ssim: ssim_sum / (n * sharps.len() as f64),
        per_depth_psnr_db: per_depth,
    })
}

impl Quality {
    /// A table row for this quality and the given cost.
    pub fn record(
        &self,
        name: &str,
        method: Method,
        latency_ms: Option<f64>,
        estimated_ms: Option<f64>,
        doe_hash: Option<String>,
        (backend, precision, device): (&str, &str, String),
    ) -> Record {
        Record {
            point: Point {
                name: name.to_string(),
                latency_ms,
                mean_psnr_db: self.mean_psnr_db,
                worst_psnr_db: self.worst_psnr_db,
                mean_ssim: self.mean_ssim,
            },
            method: method.name().to_string(),
            model: None,
            model_hash: None,
            doe_hash,
            backend: backend.to_string(),
            precision: precision.to_string(),
            device,
            estimated_ms,
            per_depth_psnr_db: self.per_depth_psnr_db.clone(),
            on_front: false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_and_worst_are_over_depths_of_image_means() {
        let sharp = Image::from_planes(8, 8, vec![vec![0.5; 64]; 3]);
        let sharps = vec![sharp.clone(), sharp];
        // Off by 0.01 (40 dB) everywhere, except image 0 at 1 D: 0.1 (20 dB).
        let q = score_depths(&[0.0, 1.0], &sharps, |d, i| {
            let off = if d == 1.0 && i == 0 { 0.1 } else { 0.01 };
            Ok(Image::from_planes(8, 8, vec![vec![0.5 + off; 64]; 3]))
        })
        .expect("scored");
        assert!((q.per_depth_psnr_db[0].1 - 40.0).abs() < 1e-4, "{q:?}");
        assert!((q.per_depth_psnr_db[1].1 - 30.0).abs() < 1e-4, "{q:?}");
        assert!((q.mean_psnr_db - 35.0).abs() < 1e-4);
        assert!((q.worst_psnr_db - 30.0).abs() < 1e-4);
        assert!(score_depths(&[], &sharps, |_, _| unreachable!()).is_err());
    }
}
