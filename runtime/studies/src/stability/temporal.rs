//! The temporal section of the stability study (issue 30): a photograph
//! panning by sub-pixel steps, and per method the frame-to-frame change of
//! the perceived image against that of the input. A linear, shift-invariant
//! preprocessing (the Wiener, `lsq`) moves the perceived image with the
//! input and only blurs or sharpens the change; what is not shift-invariant
//! (the panel's clamp, a network, an iterative solver stopped at a fixed
//! step count from a frame-dependent start) can add change of its own:
//! flicker. `refine:K` warm-started from the previous frame's display image
//! is measured beside the cold start at the same K, and so is the
//! runtime's warm start (`nedrt run`'s ladder, issue 54): refine:1 going on
//! from the last frame's solver state only where the frame is still, which
//! a pan never is, so it must flicker no more than refine:1 from the start.

use std::sync::Arc;

use serde::Serialize;

use crate::AppError;
use crate::preprocess::Prefilter;
use nedrt_core::Preprocess;
use nedrt_optics::sim::metrics::psnr;
use nedrt_optics::sim::{
    DisplayProblem, Image, Method, Objective, Prepared, SolveMode, SolveOptions, SolvedPrefilter,
};

/// Frames of the pan.
pub const FRAMES: usize = 8;
/// Pan per frame, input pixels (sub-pixel: the sampling phase changes every frame).
pub const STEP_PX: f32 = 0.37;
/// Side of the panned window, input pixels.
pub const SIDE: usize = 96;
/// Refinement steps of the cold and warm `refine:K` rows.
pub const REFINE_STEPS: usize = 10;
/// Refinement steps a frame of the runtime's warm-start row (the ladder's
/// cheapest refine level), and of its cold twin.
pub const RUNTIME_WARM_STEPS: usize = 1;

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

/// A method's display image of a frame of the pan, given its last one.
type DisplayOf<'a> = Box<dyn FnMut(&Image, Option<&Image>) -> Result<Image, AppError> + 'a>;

/// The section: every method on the pan, perceived at the headline depths.
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
    let mut methods: Vec<(String, Method, DisplayOf)> = Vec::new();
    for m in [
        Method::Conventional,
        Method::Ai,
        Method::DoeOnly,
        Method::DoeWiener,
    ] {
        let mut e =
            crate::preprocess::for_system(m, Prefilter::Native, prepared, &mut Default::default())?;
        methods.push((m.name().into(), m, Box::new(move |f, _| Ok(e.run(f)?))));
    }
    if let Some(mut p) = proposed {
        methods.push((
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
        methods.push((
            name.into(),
            Method::DoeWiener,
            Box::new(move |f, _| Ok(e.run(f)?)),
        ));
    }
    // Warm start: the previous frame's display image (the first frame
    // starts from lsq, as the cold start does).
    let warm = problem.clone();
    methods.push((
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
    // The runtime's warm start, beside refine:1 from the start.
    for (name, mode) in [
        ("doe+wiener refine:1", false),
        ("doe+wiener refine:1, the runtime's warm start", true),
    ] {
        let mut solver = runtime_refine(problem.clone(), mode);
        methods.push((
            name.into(),
            Method::DoeWiener,
            Box::new(move |f, _| Ok(solver.run(f)?)),
        ));
    }
    let mut rows = Vec::new();
    for (name, method, mut display_of) in methods {
        let displays = displays(&frames, &mut display_of)?;
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

/// refine:`RUNTIME_WARM_STEPS` from the linear prefilter each frame, or
/// warm-started as `nedrt run`'s ladder runs it.
fn runtime_refine(problem: Arc<DisplayProblem>, warm: bool) -> SolvedPrefilter {
    let solver = SolvedPrefilter::new(
        Method::DoeWiener.name(),
        problem,
        SolveMode::Refine(RUNTIME_WARM_STEPS),
    );
    if warm { solver.warm_started() } else { solver }
}

/// The display images of `frames`, each given the last.
fn displays(frames: &[Image], display_of: &mut DisplayOf) -> Result<Vec<Image>, AppError> {
    let mut displays: Vec<Image> = Vec::new();
    for f in frames {
        let d = display_of(f, displays.last())?;
        displays.push(d);
    }
    Ok(displays)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nedrt_optics::Psf;

    /// Three depths, the middle one's target blurred, Gaussian PSFs wider
    /// per channel and depth (the multifocal objective's shape).
    fn three_depths() -> Arc<DisplayProblem> {
        let gaussians = |s: f64| -> Vec<Psf> {
            [1.0, 1.3, 1.7]
                .iter()
                .map(|k| Psf::gaussian(s * k, 0.02))
                .collect()
        };
        let per_depth: Vec<Vec<Psf>> = [1.2, 3.0, 1.8].iter().map(|s| gaussians(*s)).collect();
        let psfs = (0..3)
            .map(|c| per_depth.iter().map(|d| d[c].clone()).collect())
            .collect();
        Arc::new(
            DisplayProblem::new(
                Objective::Target,
                vec![0.0, 1.0, 2.0],
                psfs,
                vec![false, true, false],
                Some(gaussians(2.0)),
                0.03,
            )
            .expect("problem"),
        )
    }

    /// The runtime's warm start on a pan (issue 54): every frame moved, so
    /// every frame starts afresh and the display is refine:1's, no more
    /// flicker; on a still frame it goes on and shows a display of its own.
    #[test]
    fn the_runtimes_warm_start_flickers_no_more_than_refine_from_the_start_on_a_pan() {
        let (w, h) = (140, 100);
        let plane = |c: usize| -> Vec<f32> {
            (0..w * h)
                .map(|i| {
                    let (x, y) = ((i % w) as f32, (i / w) as f32);
                    let bars = if (x / 9.0).floor() as i32 % 2 == 0 {
                        0.85
                    } else {
                        0.1
                    };
                    (bars * (0.4 + 0.6 * y / h as f32) + 0.05 * (x * 0.7 + c as f32).sin())
                        .clamp(0.0, 1.0)
                })
                .collect()
        };
        let image = Image::from_planes(w, h, (0..3).map(plane).collect());
        let frames = pan("bars.png", &image).expect("pan");
        let problem = three_depths();
        let run = |warm: bool, frames: &[Image]| {
            let mut solver = runtime_refine(problem.clone(), warm);
            let mut display_of: DisplayOf = Box::new(move |f, _| Ok(solver.run(f)?));
            displays(frames, &mut display_of).expect("displays")
        };
        let change = |d: &[Image]| -> f64 { d.windows(2).map(|p| rms_change(&p[1], &p[0])).sum() };
        let (cold, warm) = (run(false, &frames), run(true, &frames));
        assert!(change(&cold) > 0.0);
        // Every frame of the pan moved: each starts afresh, as the cold one.
        for (t, (c, w)) in cold.iter().zip(&warm).enumerate() {
            assert_eq!(c.data(), w.data(), "frame {t}: the pan went on warm");
        }
        assert!(
            change(&warm) <= change(&cold) * (1.0 + 1e-6),
            "warm {} vs cold {}",
            change(&warm),
            change(&cold)
        );
        // A still frame: the warm start goes on from its last state.
        let still = vec![frames[0].clone(); 3];
        let (cold, warm) = (run(false, &still), run(true, &still));
        assert_eq!(
            cold[2].data(),
            cold[0].data(),
            "cold: the same solve each frame"
        );
        assert_ne!(warm[2].data(), warm[0].data(), "warm: it went on");
    }

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
