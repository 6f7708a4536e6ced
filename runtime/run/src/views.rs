//! The views of `nedrt run` (a headset's eyes, issue 33): each its region
//! of the panel and its design (`[[view]]` in the calibration; without
//! tables, the panel's halves and the run's own system; without either,
//! one view covering the panel). The builder (`builder`) runs every view
//! alike.

use super::plan::ViewFacts;
use super::{AppError, RunOptions};
use nedrt_core::calib::Calibration;
use nedrt_service::compose::ViewRegion;
use nedrt_service::pipeline::service::PanelConfig;

/// The views of the run: the calibration's or `--stereo`'s, else one
/// covering the panel; their designs checked against the run's `network`
/// ([`check_designs`]).
pub(super) fn view_facts(
    opts: &RunOptions,
    calib: &Calibration,
    panel: &PanelConfig,
    network: bool,
) -> Result<Vec<ViewFacts>, AppError> {
    if opts.stereo || !calib.views.is_empty() {
        let views = layout(calib, (panel.width, panel.height))?;
        check_designs(opts, &views, network)?;
        return Ok(views);
    }
    Ok(vec![ViewFacts {
        name: "panel".into(),
        region: ViewRegion {
            x: 0,
            y: 0,
            width: panel.width,
            height: panel.height,
        },
        design: None,
    }])
}

/// A view's own design with a network is refused rather than ignored: the
/// network runs on the DOE it was trained with. The frame budget's ladder
/// leaves its network level out instead (`plan`).
fn check_designs(opts: &RunOptions, views: &[ViewFacts], network: bool) -> Result<(), AppError> {
    match views.iter().find(|v| v.design.is_some()) {
        Some(v) if network && opts.ladder.is_none() => Err(AppError::Conflict(format!(
            "view {:?}: design {:?} with --preprocess {}: a D-CNN runs on the DOE it was \
             trained with; a view's design needs a method without a network (doe+wiener, \
             doe-only)",
            v.name,
            v.design.as_deref().unwrap_or_default(),
            opts.preprocess
        ))),
        _ => Ok(()),
    }
}

/// The views of `calib`, or the halves of a `width`×`height` panel when it
/// has none (`--stereo`), each checked to fit the panel this run drives.
pub(super) fn layout(
    calib: &Calibration,
    (width, height): (usize, usize),
) -> Result<Vec<ViewFacts>, AppError> {
    let min = nedrt_core::calib::views::MIN_VIEW_SIDE_PX;
    let layout: Vec<ViewFacts> = if calib.views.is_empty() {
        if width / 2 < min || height < min {
            return Err(AppError::Conflict(format!(
                "--stereo on a {width}×{height} panel: each eye would be {}×{height}; a view is \
                 at least {min} pixels a side",
                width / 2
            )));
        }
        let [left, right] = ViewRegion::side_by_side(width, height);
        vec![
            ViewFacts {
                name: "left".into(),
                region: left,
                design: None,
            },
            ViewFacts {
                name: "right".into(),
                region: right,
                design: None,
            },
        ]
    } else {
        // The calibration checked its views against its own panel; the run
        // may drive another size (--panel in the benchmarks).
        for v in &calib.views {
            let [x, y, w, h] = v.region_px;
            let region = ViewRegion {
                x,
                y,
                width: w,
                height: h,
            };
            if !region.fits((width, height)) {
                return Err(AppError::Conflict(format!(
                    "{}: view {:?} ({w}×{h} at ({x}, {y})) is not inside the {width}×{height} \
                     panel this run drives",
                    calib.source, v.name
                )));
            }
        }
        calib
            .views
            .iter()
            .map(|v| {
                let [x, y, w, h] = v.region_px;
                let region = ViewRegion {
                    x,
                    y,
                    width: w,
                    height: h,
                };
                ViewFacts {
                    name: v.name.clone(),
                    region,
                    design: v.design.clone(),
                }
            })
            .collect()
    };
    Ok(layout)
}
