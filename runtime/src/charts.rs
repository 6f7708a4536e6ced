//! Chart drawing with plotters: line panels and heat maps, written as PNG and
//! SVG with an embedded font (DejaVu Sans), so they render on machines
//! without system fonts.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::FontStyle;

static FONT: Once = Once::new();

fn register_font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../assets/DejaVuSans.ttf");
        if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_err() {
            tracing::warn!("embedded font failed to load; chart text may be missing");
        }
    });
}

/// One line of a panel.
#[derive(Debug, Clone)]
pub struct Series {
    pub name: String,
    pub color: RGBColor,
    pub dashed: bool,
    pub points: Vec<(f64, f64)>,
}

/// A panel of lines with fixed axes.
#[derive(Debug, Clone)]
pub struct LinePanel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub x_range: (f64, f64),
    pub y_range: (f64, f64),
    pub series: Vec<Series>,
}

/// A heat map: `values[row][col]` as RGB colours on a grid of cells.
#[derive(Debug, Clone)]
pub struct HeatPanel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub x_range: (f64, f64),
    pub y_range: (f64, f64),
    pub colors: Vec<Vec<RGBColor>>,
}

#[derive(Debug, Clone)]
pub enum Panel {
    Lines(LinePanel),
    Heat(HeatPanel),
}

type Chart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// A titled panel with labelled axes over fixed ranges (grid lines optional).
fn axes<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    title: &str,
    x_label: &str,
    y_label: &str,
    x: (f64, f64),
    y: (f64, f64),
    grid: bool,
) -> Result<Chart<'a, DB>, String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(32)
        .y_label_area_size(44)
        .build_cartesian_2d(x.0..x.1, y.0..y.1)
        .map_err(e)?;
    let mut mesh = chart.configure_mesh();
    if !grid {
        mesh.disable_mesh();
    }
    mesh.x_desc(x_label)
        .y_desc(y_label)
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(e)?;
    Ok(chart)
}

fn draw<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, panel: &Panel) -> Result<(), String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    match panel {
        Panel::Lines(p) => {
            let mut chart = axes(
                area, &p.title, &p.x_label, &p.y_label, p.x_range, p.y_range, true,
            )?;
            for s in &p.series {
                let style = ShapeStyle::from(s.color).stroke_width(2);
                let color = s.color;
                if s.dashed {
                    chart
                        .draw_series(DashedLineSeries::new(s.points.iter().copied(), 6, 4, style))
                        .map_err(e)?
                        .label(&s.name)
                        .legend(move |(x, y)| {
                            plotters::element::DashedPathElement::new(
                                vec![(x, y), (x + 18, y)],
                                4,
                                3,
                                color,
                            )
                        });
                } else {
                    chart
                        .draw_series(LineSeries::new(s.points.iter().copied(), style))
                        .map_err(e)?
                        .label(&s.name)
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color));
                }
            }
            if p.series.len() > 1 {
                chart
                    .configure_series_labels()
                    .label_font(("sans-serif", 11))
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK)
                    .draw()
                    .map_err(e)?;
            }
        }
        Panel::Heat(p) => {
            let mut chart = axes(
                area, &p.title, &p.x_label, &p.y_label, p.x_range, p.y_range, false,
            )?;
            let rows = p.colors.len();
            let cols = p.colors.first().map_or(0, |r| r.len());
            let dx = (p.x_range.1 - p.x_range.0) / cols.max(1) as f64;
            let dy = (p.y_range.1 - p.y_range.0) / rows.max(1) as f64;
            chart
                .draw_series(p.colors.iter().enumerate().flat_map(|(r, row)| {
                    row.iter().enumerate().map(move |(c, color)| {
                        let x0 = p.x_range.0 + c as f64 * dx;
                        let y0 = p.y_range.0 + r as f64 * dy;
                        Rectangle::new([(x0, y0), (x0 + dx, y0 + dy)], color.filled())
                    })
                }))
                .map_err(e)?;
        }
    }
    Ok(())
}

fn draw_all<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    layout: (usize, usize),
    panels: &[Panel],
) -> Result<(), String> {
    root.fill(&WHITE).map_err(|x| x.to_string())?;
    for (area, panel) in root.split_evenly(layout).iter().zip(panels) {
        draw(area, panel)?;
    }
    root.present().map_err(|x| x.to_string())
}

/// Writes `panels` in a rows×cols grid to `stem`.png and `stem`.svg.
/// Heat maps with many cells are written as PNG only (`svg` = false).
pub fn write_figure(
    stem: &Path,
    layout: (usize, usize),
    size: (u32, u32),
    panels: &[Panel],
    svg: bool,
) -> Result<Vec<String>, String> {
    register_font();
    let png = stem.with_extension("png");
    draw_all(
        BitMapBackend::new(&png, size).into_drawing_area(),
        layout,
        panels,
    )
    .map_err(|e| format!("{}: {e}", png.display()))?;
    let mut written = vec![png.display().to_string()];
    if svg {
        let svg_path = stem.with_extension("svg");
        draw_all(
            SVGBackend::new(&svg_path, size).into_drawing_area(),
            layout,
            panels,
        )
        .map_err(|e| format!("{}: {e}", svg_path.display()))?;
        written.push(svg_path.display().to_string());
    }
    Ok(written)
}

/// Viridis colour of `t` in [0, 1].
pub fn viridis(t: f64) -> RGBColor {
    plotters::style::colors::colormaps::ViridisRGB::get_color(t.clamp(0.0, 1.0))
}

pub const RED_LINE: RGBColor = RGBColor(214, 39, 40);
pub const GREEN_LINE: RGBColor = RGBColor(44, 160, 44);
pub const BLUE_LINE: RGBColor = RGBColor(31, 119, 180);
