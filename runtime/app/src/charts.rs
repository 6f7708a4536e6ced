//! Chart drawing with plotters: line panels and heat maps, written as PNG and
//! SVG with an embedded font (DejaVu Sans), so they render on machines
//! without system fonts.

use std::path::Path;
use std::sync::Once;

use crate::AppError;

use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::FontStyle;

static FONT: Once = Once::new();

pub fn register_font() {
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
    /// Where the legend goes; `None`: plotters' default (middle right).
    pub legend: Option<SeriesLabelPosition>,
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
                // A series without a name (a repeated marker) has no legend entry.
                if s.dashed {
                    let drawn = chart
                        .draw_series(DashedLineSeries::new(s.points.iter().copied(), 6, 4, style))
                        .map_err(e)?;
                    if !s.name.is_empty() {
                        drawn.label(&s.name).legend(move |(x, y)| {
                            plotters::element::DashedPathElement::new(
                                vec![(x, y), (x + 18, y)],
                                4,
                                3,
                                color,
                            )
                        });
                    }
                } else {
                    let drawn = chart
                        .draw_series(LineSeries::new(s.points.iter().copied(), style))
                        .map_err(e)?;
                    if !s.name.is_empty() {
                        drawn.label(&s.name).legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 18, y)], color)
                        });
                    }
                }
            }
            if p.series.iter().filter(|s| !s.name.is_empty()).count() > 1 {
                let mut labels = chart.configure_series_labels();
                if let Some(at) = &p.legend {
                    labels.position(at.clone());
                }
                labels
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

/// A bitmap chart drawn in memory by `draw` and written to `path` as a PNG
/// at the encoder's best compression (atomically): plotters' own encoder
/// wrote charts three to four times larger, and docs/ travels to the
/// device with every check.
fn compact_png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), String>,
) -> Result<(), AppError> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut rgb = vec![0u8; size.0 as usize * size.1 as usize * 3];
    draw(BitMapBackend::with_buffer(&mut rgb, size).into_drawing_area())
        .map_err(|e| AppError::output(path, e))?;
    atomically(path, |tmp| {
        let file = std::io::BufWriter::new(std::fs::File::create(tmp).map_err(|e| e.to_string())?);
        PngEncoder::new_with_quality(file, CompressionType::Best, FilterType::Adaptive)
            .write_image(&rgb, size.0, size.1, image::ExtendedColorType::Rgb8)
            .map_err(|e| e.to_string())
    })
}

/// A chart file drawn in full beside `path` and renamed into place, so a
/// stopped or failed run never leaves half a chart.
fn atomically(path: &Path, draw: impl FnOnce(&Path) -> Result<(), String>) -> Result<(), AppError> {
    struct Failed(String);
    impl From<std::io::Error> for Failed {
        fn from(e: std::io::Error) -> Self {
            Failed(e.to_string())
        }
    }
    nedrt_core::util::write_atomic_with(path, |tmp| draw(tmp).map_err(Failed))
        .map_err(|Failed(e)| AppError::output(path, e))
}

/// Writes `panels` in a rows×cols grid to `stem`.png and `stem`.svg.
/// Heat maps with many cells are written as PNG only (`svg` = false).
pub fn write_figure(
    stem: &Path,
    layout: (usize, usize),
    size: (u32, u32),
    panels: &[Panel],
    svg: bool,
) -> Result<Vec<String>, AppError> {
    register_font();
    let png = stem.with_extension("png");
    compact_png(&png, size, |area| draw_all(area, layout, panels))?;
    let mut written = vec![png.display().to_string()];
    if svg {
        let svg_path = stem.with_extension("svg");
        atomically(&svg_path, |tmp| {
            draw_all(
                SVGBackend::new(tmp, size).into_drawing_area(),
                layout,
                panels,
            )
        })?;
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
/// Thin reference lines (marked depths) that should not compete with data.
pub const MARKER_LINE: RGBColor = RGBColor(150, 150, 150);

/// Colour of the `i`-th of several compared series (matplotlib's tab10, so
/// neighbouring series stay distinguishable; repeats after ten).
pub fn series_color(i: usize) -> RGBColor {
    const TAB10: [RGBColor; 10] = [
        BLUE_LINE,
        RGBColor(255, 127, 14),
        GREEN_LINE,
        RED_LINE,
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
        RGBColor(188, 189, 34),
        RGBColor(23, 190, 207),
    ];
    TAB10[i % TAB10.len()]
}

/// One point of a scatter figure.
#[derive(Debug, Clone)]
pub struct ScatterPoint {
    pub label: String,
    pub x: f64,
    pub y: f64,
    /// Drawn filled and joined by the front line.
    pub on_front: bool,
    /// Drawn hollow: a value that was estimated, not measured.
    pub estimated: bool,
}

/// A scatter plot with a logarithmic x axis, labelled points and the
/// Pareto front drawn as a staircase through the points marked on it.
#[derive(Debug, Clone)]
pub struct ScatterFigure {
    pub title: String,
    /// Lines printed under the plot (device, hashes).
    pub footer: Vec<String>,
    pub x_label: String,
    pub y_label: String,
    pub points: Vec<ScatterPoint>,
}

fn draw_scatter<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    f: &ScatterFigure,
) -> Result<(), String> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let footer_px = 16 * f.footer.len() as i32 + 8;
    let (h, _) = (root.dim_in_pixel().1 as i32, ());
    let (plot, foot) = root.split_vertically(h - footer_px);
    let xs = f.points.iter().map(|p| p.x.max(1e-3));
    let (x0, x1) = xs.fold((f64::MAX, f64::MIN), |(a, b), x| (a.min(x), b.max(x)));
    let (y0, y1) = f
        .points
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.y), b.max(p.y)));
    let (x0, x1) = if x0 > x1 {
        (0.1, 10.0)
    } else {
        (x0 / 3.0, x1 * 30.0)
    };
    let (y0, y1) = if y0 > y1 {
        (0.0, 1.0)
    } else {
        (y0 - 0.4 - 0.05 * (y1 - y0), y1 + 0.4 + 0.05 * (y1 - y0))
    };
    let mut chart = ChartBuilder::on(&plot)
        .caption(&f.title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(52)
        .build_cartesian_2d((x0..x1).log_scale(), y0..y1)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc(&f.x_label)
        .y_desc(&f.y_label)
        .label_style(("sans-serif", 12))
        .draw()
        .map_err(e)?;
    let mut front: Vec<(f64, f64)> = f
        .points
        .iter()
        .filter(|p| p.on_front)
        .map(|p| (p.x.max(1e-3), p.y))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut stairs = Vec::new();
    for (i, &(x, y)) in front.iter().enumerate() {
        if i > 0 {
            stairs.push((x, front[i - 1].1));
        }
        stairs.push((x, y));
    }
    if let Some(&(_, y)) = front.last() {
        stairs.push((x1, y));
    }
    chart
        .draw_series(LineSeries::new(
            stairs,
            ShapeStyle::from(RED_LINE).stroke_width(2),
        ))
        .map_err(e)?
        .label("Pareto front")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], RED_LINE));
    // Labels alternate below and above their points, in order of x, so
    // neighbours (f32 and f16 of one backend) do not overprint.
    let mut order: Vec<usize> = (0..f.points.len()).collect();
    order.sort_by(|&a, &b| f.points[a].x.total_cmp(&f.points[b].x));
    for (rank, &i) in order.iter().enumerate() {
        let p = &f.points[i];
        let at = (p.x.max(1e-3), p.y);
        let color = if p.on_front { RED_LINE } else { BLUE_LINE };
        let style = if p.estimated {
            ShapeStyle::from(color).stroke_width(2)
        } else {
            color.filled()
        };
        chart
            .draw_series(std::iter::once(Circle::new(at, 5, style)))
            .map_err(e)?;
        // Points that (nearly) coincide with earlier ones get their label
        // moved right, one slot per earlier neighbour.
        let near = order[..rank]
            .iter()
            .filter(|&&j| {
                let q = &f.points[j];
                (q.x.max(1e-3) / at.0).ln().abs() < 0.05 && (q.y - p.y).abs() < 0.02 * (y1 - y0)
            })
            .count() as i32;
        let dy = if rank % 2 == 0 { 6 } else { -18 };
        let dx = 8 + 16 * near;
        chart
            .draw_series(std::iter::once(
                EmptyElement::at(at)
                    + Text::new(
                        p.label.clone(),
                        (dx, dy),
                        ("sans-serif", 11).into_font().color(&BLACK),
                    ),
            ))
            .map_err(e)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .label_font(("sans-serif", 11))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(e)?;
    for (i, line) in f.footer.iter().enumerate() {
        foot.draw(&Text::new(
            line.clone(),
            (12, 4 + 16 * i as i32),
            ("sans-serif", 12).into_font().color(&BLACK),
        ))
        .map_err(e)?;
    }
    root.present().map_err(e)
}

/// Writes a scatter figure to `stem`.png and `stem`.svg.
pub fn write_scatter(
    stem: &Path,
    size: (u32, u32),
    figure: &ScatterFigure,
) -> Result<Vec<String>, AppError> {
    register_font();
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    compact_png(&png, size, |area| draw_scatter(area, figure))?;
    atomically(&svg, |tmp| {
        draw_scatter(SVGBackend::new(tmp, size).into_drawing_area(), figure)
    })?;
    Ok(vec![png.display().to_string(), svg.display().to_string()])
}
