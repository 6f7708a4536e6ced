//! `nedrt calib show`: a PSF bundle against the design's own PSFs (and,
//! given one, against another bundle: a synthetic capture's truth).

use std::fmt::Write as _;
use std::path::Path;

use nedrt_optics::bundle::PsfBundle;
use nedrt_optics::pixel::response_distance;
use nedrt_optics::psf::Psf;
use nedrt_optics::sim::Method;

use crate::{AppError, CommonOptions};

/// One accommodation and channel of a bundle, compared.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub accommodation_d: f64,
    pub channel: usize,
    /// The share of the light inside the window (1 − veil).
    pub window_share: f64,
    /// The light's centroid from the axis, retinal cells (x, y).
    pub centroid_cells: (f64, f64),
    pub to_design: f64,
    pub to_other: Option<f64>,
}

/// The centroid of a PSF's cells from its centre, cells.
pub fn centroid(p: &Psf) -> (f64, f64) {
    let n = p.window;
    let c = (n as f64 - 1.0) / 2.0;
    let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
    for (i, v) in p.cells.iter().enumerate() {
        sx += v * ((i % n) as f64 - c);
        sy += v * ((i / n) as f64 - c);
        s += v;
    }
    if s > 0.0 {
        (sx / s, sy / s)
    } else {
        (0.0, 0.0)
    }
}

/// Compares `bundle` with the design (the calibration's DOE) and, if
/// given, `other`, at every accommodation of `bundle` (`other` must hold
/// them all).
pub fn compare(
    common: &CommonOptions,
    bundle: &PsfBundle,
    other: Option<&PsfBundle>,
) -> Result<Vec<Row>, AppError> {
    let depths = bundle.accommodations_d().to_vec();
    let (design, _) = crate::frames::psfs_at(common, Method::DoeOnly, &depths, "the bundle's")?;
    let mut rows = Vec::new();
    for (a, d) in depths.iter().enumerate() {
        for (c, designed) in design[a].iter().enumerate().take(bundle.channels()) {
            let p = bundle.measured(a, c);
            let to_other = match other {
                Some(o) => Some(response_distance(
                    p,
                    &o.at(*d, c).map_err(nedrt_optics::sim::SimError::from)?,
                )),
                None => None,
            };
            rows.push(Row {
                accommodation_d: *d,
                channel: c,
                window_share: 1.0 - p.veil,
                centroid_cells: centroid(p),
                to_design: response_distance(p, designed),
                to_other,
            });
        }
    }
    Ok(rows)
}

/// `calib show`'s table.
pub fn show(
    common: &CommonOptions,
    path: &Path,
    against: Option<&Path>,
) -> Result<String, AppError> {
    let load = |p: &Path| PsfBundle::load(p).map_err(nedrt_optics::sim::SimError::from);
    let bundle = load(path)?;
    let other = against.map(load).transpose()?;
    let rows = compare(common, &bundle, other.as_ref())?;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "PSF bundle {} ({}): {}×{} cells\n\
         distances are relative L2 of the pixel responses (docs/calibration.md)",
        path.display(),
        bundle.card.made_by,
        bundle.card.window_cells,
        bundle.card.window_cells
    );
    let other_head = against.map_or(String::new(), |p| format!(" | to {}", p.display()));
    let _ = writeln!(
        out,
        "| D | channel | in window | centroid (cells) | to the design{other_head} |\n| ---: | ---: | ---: | --- | ---: |{}",
        if against.is_some() { " ---: |" } else { "" }
    );
    for r in &rows {
        let _ = writeln!(
            out,
            "| {} | {} | {:.4} | ({:+.2}, {:+.2}) | {:.4} |{}",
            r.accommodation_d,
            r.channel,
            r.window_share,
            r.centroid_cells.0,
            r.centroid_cells.1,
            r.to_design,
            r.to_other.map_or(String::new(), |v| format!(" {v:.4} |"))
        );
    }
    if let Some(m) = &bundle.card.measurement {
        let _ = writeln!(
            out,
            "registration: {} ({}), {} points, {:.3} px RMS, {:.3} px at most; dots a channel {:?}",
            m.registration_capture,
            m.registration_model,
            m.registration_points,
            m.registration_rms_px,
            m.registration_max_px,
            m.dots_per_channel
        );
    }
    Ok(out)
}
