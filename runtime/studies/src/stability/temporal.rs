//! The temporal section of the stability study (issue 30): a photograph
//! panning by sub-pixel steps, and per method the frame-to-frame change of
//! the perceived image against that of the input. A linear, shift-invariant
//! preprocessing (the Wiener, `lsq`) moves the perceived image with the
//! input and only blurs or sharpens the change; what is not shift-invariant
//! (the panel's clamp, a network, an iterative solver stopped at a fixed
//! step count from a frame-dependent start) can add change of its own:
//! flicker. `refine:K` warm-started from the previous frame's display image
//! is measured beside the cold start at the same K.

use std::sync::Arc;

use serde::Serialize;

use crate::AppError;
use crate::preprocess::Prefilter;
use nedrt_core::Preprocess;
use nedrt_optics::sim::metrics::psnr;
use nedrt_optics::sim::{Image, Method, Objective, Prepared, SolveOptions};

/// Frames of the pan.
pub const FRAMES: usize = 8;
/// Pan per frame, input pixels (sub-pixel: the sampling phase changes every frame).
pub const STEP_PX: f32 = 0.37;
/// Side of the panned window, input pixels.
pub const SIDE: usize = 96;
/// Refinement steps of the cold and warm `refine:K` rows.
pub const REFINE_STEPS: usize = 10;

/// One method's row.
#[derive(Debug, Clone, Serialize)]
pub struct TemporalRow {
    pub method: String,
    /// Mean over the frames and the headline depths of the perceived
    /// image's PSNR vs the target.
    pub psnr_vs_target_db: f64,
    /// Mean over consecutive frames and the headline depths of the RMS
    /// change of the perceived image, over the same for the target (the
    /// input as the eye should see it): 1 moves as the content moves;
    /// above 1 adds change of its own.
    pub change_ratio: f64,
    /// The RMS change of the display image over the input's.
    pub display_change_ratio: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct TemporalSection {
    pub image: String,
    pub frames: usize,
    pub step_px: f32,
    pub side: usize,
    pub depths_d: Vec<f64>,
    pub rows: Vec<TemporalRow>,
}

/// The pan: `FRAMES` windows of `SIDE`×`SIDE` (smaller where the image
/// is) from the image's centre, each `STEP_PX` further right, by bilinear
/// interpolation.
pub fn pan(image_name: &str, image: &Image) -> Result<Vec<Image>, AppError> {
    let travel = (STEP_PX * FRAMES as f32).ceil() as usize + 2;
    let side = SIDE
        .min(image.height)
        .min(image.width.saturating_sub(travel));
    if side < 16 {
        return Err(AppError::input(
            image_name,
            format!(
                "the temporal study pans a window of at least 16×16 by {travel} pixels: the image must be at \
                 least {}×16, this one is {}×{}",
                16 + travel,
                image.width,
                image.height
            ),
        ));
    }
    let (x0, y0) = ((image.width - side - travel) / 2, (image.height - side) / 2);
    Ok((0..FRAMES)
        .map(|t| {
            let shift = STEP_PX * t as f32;
            let (whole, frac) = (shift.floor() as usize, shift.fract());
            let planes = image
                .planes()
                .map(|p| {
                    (0..side * side)
                        .map(|i| {
                            let (x, y) = (x0 + whole + i % side, y0 + i / side);
                            let a = p[y * image.width + x];
                            let b = p[y * image.width + x + 1];
                            a + frac * (b - a)
                        })
                        .collect()
                })
                .collect();
            Image::from_planes(side, side, planes)
        })
        .collect())
}

fn rms_change(a: &Image, b: &Image) -> f64 {
    let n = a.data().len().max(1) as f64;
    (a.data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        / n)
        .sqrt()
}

/// A method's display images of the pan.
type Engine<'a> = Box<dyn FnMut(&Image, Option<&Image>) -> Result<Image, AppError> + 'a>;

/// The section: every engine on the pan, perceived at the headline depths.
/// `prepared` must hold conventional, ai, doe-only, doe+wiener (and
/// proposed, when given) at the headline `depths`.
pub fn section(
    prepared: &Prepared,
    depths: Vec<f64>,
    image_name: &str,
    image: &Image,
    proposed: Option<Box<dyn Preprocess>>,
) -> Result<TemporalSection, AppError> {
    let frames = pan(image_name, image)?;
    let problem = Arc::new(prepared.display_problem(Method::DoeWiener, Objective::Target)?);
    let mut engines: Vec<(String, Method, Engine)> = Vec::new();
    for m in [
        Method::Conventional,
        Method::Ai,
        Method::DoeOnly,
        Method::DoeWiener,
    ] {
        let mut e =
            crate::preprocess::for_system(m, Prefilter::Native, prepared, &mut Default::default())?;
        engines.push((m.name().into(), m, Box::new(move |f, _| Ok(e.run(f)?))));
    }
    if let Some(mut p) = proposed {
        engines.push((
            "proposed".into(),
            Method::Proposed,
            Box::new(move |f, _| Ok(p.run(f)?)),
        ));
    }
    for (name, prefilter) in [
        ("doe+wiener lsq", Prefilter::Lsq(Objective::Target)),
        (
            "doe+wiener refine:10",
            Prefilter::Refine(REFINE_STEPS, Objective::Target),
        ),
        ("doe+wiener optimal", Prefilter::Optimal(Objective::Target)),
    ] {
        let mut e = crate::preprocess::for_system(
            Method::DoeWiener,
            prefilter,
            prepared,
            &mut Default::default(),
        )?;
        engines.push((
            name.into(),
            Method::DoeWiener,
            Box::new(move |f, _| Ok(e.run(f)?)),
        ));
    }
    // Warm start: the previous frame's display image (the first frame
    // starts from lsq, as the cold start does).
    let warm = problem.clone();
    engines.push((
        "doe+wiener refine:10, warm start".into(),
        Method::DoeWiener,
        Box::new(move |f, previous| {
            let start = match previous {
                Some(p) => p.clone(),
                None => warm.linear_unclamped(f).clamped(),
            };
            Ok(warm.solve(f, &start, &SolveOptions::steps(REFINE_STEPS)).0)
        }),
    ));
    let mut rows = Vec::new();
    for (name, method, mut engine) in engines {
        let mut displays: Vec<Image> = Vec::new();
        for f in &frames {
            let d = engine(f, displays.last())?;
            displays.push(d);
        }
        let (mut quality, mut change, mut target_change, mut n) = (0.0, 0.0, 0.0, 0usize);
        for &depth in &depths {
            let mut previous: Option<(Image, Image)> = None;
            for (f, d) in frames.iter().zip(&displays) {
                let seen = prepared.perceived(method, d, depth)?;
                let target = prepared.target(f, depth)?;
                quality += psnr(&seen, &target);
                n += 1;
                if let Some((ps, pt)) = &previous {
                    change += rms_change(&seen, ps);
                    target_change += rms_change(&target, pt);
                }
                previous = Some((seen, target));
            }
        }
        let display_change: f64 = displays.windows(2).map(|w| rms_change(&w[1], &w[0])).sum();
        let input_change: f64 = frames.windows(2).map(|w| rms_change(&w[1], &w[0])).sum();
        rows.push(TemporalRow {
            method: name,
            psnr_vs_target_db: quality / n.max(1) as f64,
            change_ratio: change / target_change.max(f64::MIN_POSITIVE),
            display_change_ratio: display_change / input_change.max(f64::MIN_POSITIVE),
        });
    }
    Ok(TemporalSection {
        image: image_name.into(),
        frames: FRAMES,
        step_px: STEP_PX,
        side: frames[0].width,
        depths_d: depths,
        rows,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pan_moves_a_ramp_by_its_step_every_frame() {
        let (w, h) = (140, 100);
        let ramp: Vec<f32> = (0..w * h).map(|i| (i % w) as f32 / w as f32).collect();
        let image = Image::from_planes(w, h, vec![ramp.clone(), ramp.clone(), ramp]);
        let frames = pan("pan.png", &image).expect("pan");
        assert_eq!(frames.len(), FRAMES);
        assert_eq!((frames[0].width, frames[0].height), (SIDE, SIDE));
        for pair in frames.windows(2) {
            for (a, b) in pair[0].data().iter().zip(pair[1].data()) {
                // Bilinear resampling of a ramp is exact: every value moves by the step.
                assert!((b - a - STEP_PX / w as f32).abs() < 1e-5, "{a} → {b}");
            }
        }
        assert!((rms_change(&frames[1], &frames[0]) - (STEP_PX / w as f32) as f64).abs() < 1e-6);
        // A small image gets a smaller window; too small, a clear error.
        let small = Image::from_planes(40, 30, vec![vec![0.5; 1200]; 3]);
        assert_eq!(pan("small.png", &small).expect("pan")[0].width, 30);
        let tiny = Image::from_planes(12, 12, vec![vec![0.5; 144]; 3]);
        let e = pan("tiny.png", &tiny)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.starts_with("tiny.png: ") && e.contains("12×12"), "{e}");
    }
}
