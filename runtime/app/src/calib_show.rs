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

/// `calib show`'s table, and with `chart` (a file stem) its chart: each
/// channel's PSF through its centre row at the bundle's middle
/// accommodation (log scale), the bundle's against the design's (and the
/// other bundle's), and the distance to the design against accommodation.
pub fn show(
    common: &CommonOptions,
    path: &Path,
    against: Option<&Path>,
    chart: Option<&Path>,
) -> Result<String, AppError> {
    let load = |p: &Path| PsfBundle::load(p).map_err(nedrt_optics::sim::SimError::from);
    let bundle = load(path)?;
    let other = against.map(load).transpose()?;
    let rows = compare(common, &bundle, other.as_ref())?;
    let mut out = String::new();
    if let Some(stem) = chart {
        let written = draw(common, &bundle, other.as_ref(), &rows, stem)?;
        let _ = writeln!(out, "chart: {}", written.join(", "));
    }
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
    zones_table(&mut out, &bundle, other.as_ref(), against);
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

/// A zoned bundle's zones: each one's largest distance (over the
/// accommodations and channels) from the whole field's PSFs, and from the
/// same zone of `other` where it has the same zones.
fn zones_table(
    out: &mut String,
    bundle: &PsfBundle,
    other: Option<&PsfBundle>,
    against: Option<&Path>,
) {
    let (nx, ny) = bundle.zones();
    if bundle.card.zones.is_none() {
        return;
    }
    let other = other.filter(|o| o.zones() == (nx, ny) && o.card.zones.is_some());
    let other_head = match (other, against) {
        (Some(_), Some(p)) => format!(" | to {}'s zone |", p.display()),
        _ => " |".into(),
    };
    let _ = writeln!(
        out,
        "\n{nx}×{ny} field zones (largest distance over accommodations and channels)\n\
         | zone | from the whole field{other_head}\n| --- | ---: |{}",
        if other.is_some() { " ---: |" } else { "" }
    );
    let worst = |a: &PsfBundle, b: &PsfBundle| {
        (0..a.accommodations_d().len())
            .flat_map(|i| (0..a.channels()).map(move |c| (i, c)))
            .map(|(i, c)| response_distance(a.measured(i, c), b.measured(i, c)))
            .fold(0.0, f64::max)
    };
    for j in 0..ny {
        for i in 0..nx {
            let Some(zone) = bundle.zone(i, j) else {
                continue;
            };
            let to_other = other
                .and_then(|o| o.zone(i, j))
                .filter(|o| o.accommodations_d() == zone.accommodations_d())
                .map_or(String::new(), |o| format!(" {:.4} |", worst(&zone, &o)));
            let _ = writeln!(
                out,
                "| ({i}, {j}) | {:.4} |{to_other}",
                worst(&zone, bundle)
            );
        }
    }
}

/// The centre row of a PSF's pixel response (what a display shows of it,
/// and what a capture measures: the PSF's Nyquist content, which the 2×2
/// pixel erases, is left out), log10 of each cell's share of the pixel's
/// light (floored at 1e-7), against its offset in cells from the pixel's
/// centre.
fn centre_row(p: &Psf) -> Vec<(f64, f64)> {
    let (m, g) = nedrt_optics::pixel::pixel_response(p);
    let c = m / 2;
    (0..m)
        .map(|x| {
            (
                x as f64 - c as f64 + 0.5,
                (g[c * m + x] / 4.0).max(1e-7).log10(),
            )
        })
        .collect()
}

fn draw(
    common: &CommonOptions,
    bundle: &PsfBundle,
    other: Option<&PsfBundle>,
    rows: &[Row],
    stem: &Path,
) -> Result<Vec<String>, AppError> {
    use crate::charts::{LinePanel, Panel, Series, series_color, write_figure};
    let depths = bundle.accommodations_d();
    let mid = depths.len() / 2;
    let d = depths[mid];
    let (design, _) = crate::frames::psfs_at(common, Method::DoeOnly, &[d], "the bundle's")?;
    let half = (bundle.card.window_cells / 2) as f64;
    let mut panels = Vec::new();
    for (c, designed) in design[0].iter().enumerate().take(bundle.channels()) {
        let mut series = vec![
            Series {
                name: "bundle".into(),
                color: series_color(0),
                dashed: false,
                points: centre_row(bundle.measured(mid, c)),
            },
            Series {
                name: "design".into(),
                color: series_color(1),
                dashed: true,
                points: centre_row(designed),
            },
        ];
        if let Some(o) = other {
            let p = o.at(d, c).map_err(nedrt_optics::sim::SimError::from)?;
            series.push(Series {
                name: "other".into(),
                color: series_color(2),
                dashed: true,
                points: centre_row(&p),
            });
        }
        panels.push(Panel::Lines(LinePanel {
            title: format!("channel {c} at {d} D, pixel response's centre row"),
            x_label: "retinal cells".into(),
            y_label: "log10 share of the light".into(),
            x_range: (-half.min(60.0), half.min(60.0)),
            y_range: (-7.0, 0.0),
            series,
            legend: None,
        }));
    }
    let top = rows.iter().map(|r| r.to_design).fold(0.05, f64::max);
    let series = (0..bundle.channels())
        .map(|c| Series {
            name: format!("channel {c}"),
            color: series_color(c),
            dashed: false,
            points: rows
                .iter()
                .filter(|r| r.channel == c)
                .map(|r| (r.accommodation_d, r.to_design))
                .collect(),
        })
        .collect();
    panels.push(Panel::Lines(LinePanel {
        title: "distance to the design".into(),
        x_label: "accommodation (D)".into(),
        y_label: "relative L2 of the pixel responses".into(),
        x_range: (depths[0], depths[depths.len() - 1].max(depths[0] + 0.1)),
        y_range: (0.0, 1.1 * top),
        series,
        legend: None,
    }));
    write_figure(stem, (2, 2), (1200, 900), &panels, true)
}
