//! `nedrt tolerance` (docs/tolerance.md): each fabrication and assembly
//! error alone, and a realistic combination, for every method at its
//! shipped preprocessing. Per error and method: PSNR vs sharp and vs
//! target, mean over the headline depths, of the nominal display, of the
//! display as built preprocessed for its design (no calibration), and as
//! built preprocessed from its own PSFs (a perfect calibration); and the
//! error at which the uncalibrated display loses 0.5 dB.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::charts::{LinePanel, Panel, Series, series_color, write_figure};
use crate::{AppError, CommonOptions};
use nedrt_core::image::Image;
use nedrt_optics::perturb::Perturbation;
use nedrt_optics::sim::metrics::psnr;
use nedrt_optics::sim::{HEADLINE_MAX_D, Method, Prepared, Simulator};

/// The loss (dB, vs sharp) whose error is each method's tolerance.
pub const LOSS_DB: f64 = 0.5;

/// One error swept alone.
#[derive(Debug, Clone)]
pub struct Axis {
    pub name: &'static str,
    pub unit: &'static str,
    pub values: Vec<f64>,
    pub make: fn(f64) -> Perturbation,
    /// The design lies at infinity (levels: the continuous profile), so
    /// the loss is walked outwards in 1/value (the quantisation step): 16,
    /// then 8, 4, 2 levels.
    pub reciprocal: bool,
}

/// The errors of issue 57, each over its range.
pub fn axes() -> Vec<Axis> {
    vec![
        Axis {
            name: "etch depth",
            unit: "%",
            values: vec![-10.0, -5.0, 5.0, 10.0],
            make: |v| Perturbation {
                etch_scale: 1.0 + v / 100.0,
                ..Default::default()
            },
            reciprocal: false,
        },
        Axis {
            name: "levels",
            unit: "levels",
            values: vec![2.0, 4.0, 8.0, 16.0],
            make: |v| Perturbation {
                levels: v as u32,
                ..Default::default()
            },
            reciprocal: true,
        },
        Axis {
            name: "decentre",
            unit: "mm",
            values: vec![0.1, 0.2, 0.3],
            make: |v| Perturbation {
                decentre_mm: [v, 0.0],
                ..Default::default()
            },
            reciprocal: false,
        },
        Axis {
            name: "eye relief",
            unit: "mm",
            values: vec![-3.0, 3.0],
            make: |v| Perturbation {
                eye_relief_mm: v,
                ..Default::default()
            },
            reciprocal: false,
        },
        Axis {
            name: "panel distance",
            unit: "mm",
            values: vec![-0.2, 0.2],
            make: |v| Perturbation {
                panel_distance_mm: v,
                ..Default::default()
            },
            reciprocal: false,
        },
        Axis {
            name: "primaries",
            unit: "nm",
            values: vec![-5.0, 5.0],
            make: |v| Perturbation {
                primaries_nm: [v; 3],
                ..Default::default()
            },
            reciprocal: false,
        },
    ]
}

/// A realistic build: every error at a fraction of its range.
pub fn combination() -> Perturbation {
    Perturbation {
        etch_scale: 1.04,
        levels: 16,
        decentre_mm: [0.05, 0.03],
        eye_relief_mm: 1.0,
        panel_distance_mm: 0.05,
        primaries_nm: [2.0, -2.0, 3.0],
        bandwidths_nm: [0.0; 3],
    }
}

/// Mean PSNR (dB) vs sharp and vs target.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Score {
    pub sharp: f64,
    pub target: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Row {
    pub error: String,
    pub value: f64,
    pub method: String,
    pub nominal: Score,
    pub uncalibrated: Score,
    pub calibrated: Score,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Report {
    pub calibration: String,
    /// Each image's centre crop, pixels a side (absent in reports from
    /// before it was recorded).
    #[serde(default)]
    pub crop_px: Option<usize>,
    pub methods: Vec<String>,
    pub images: Vec<String>,
    pub depths_d: Vec<f64>,
    pub rows: Vec<Row>,
    /// Per error and method: the error (its unit) at which the
    /// uncalibrated display first loses [`LOSS_DB`] vs sharp, if it does
    /// within the range.
    pub tolerances: Vec<(String, String, Option<f64>)>,
}

/// `method`'s shipped preprocessing on `prepared`'s optics: its Wiener
/// (or none), or its network (behind the Wiener of those optics where the
/// network was trained on one; the network itself stays the design's).
fn preprocessor(
    common: &CommonOptions,
    prepared: &Prepared,
    method: Method,
) -> Result<Box<dyn nedrt_core::Preprocess>, AppError> {
    if !method.uses_dcnn() {
        return Ok(prepared.preprocessor(method)?);
    }
    let network = common
        .dcnn
        .load_for(&[method])?
        .remove(&method)
        .ok_or_else(|| AppError::Internal(format!("no network for {method}")))?;
    Ok(network.into_preprocess(method, prepared)?)
}

fn score(
    seen: &Prepared,
    displays: &[Image],
    sharps: &[Image],
    targets: &[Vec<Image>],
    method: Method,
    depths: &[f64],
) -> Result<Score, AppError> {
    let (mut s, mut t, mut n) = (0.0, 0.0, 0.0);
    for ((display, sharp), targets) in displays.iter().zip(sharps).zip(targets) {
        for (d, target) in depths.iter().zip(targets) {
            let p = seen.perceived(method, display, *d)?;
            s += psnr(&p, sharp);
            t += psnr(&p, target);
            n += 1.0;
        }
    }
    Ok(Score {
        sharp: s / n,
        target: t / n,
    })
}

/// Runs the sweep over `images` (each centre-cropped to `crop`²) and writes
/// `out` (Markdown), its JSON and its chart beside it.
pub fn run(
    common: &CommonOptions,
    methods: &[Method],
    images: &[PathBuf],
    crop: usize,
    out: &Path,
) -> Result<String, AppError> {
    crate::check_output_folder(out)?;
    let calib = common.calibration()?;
    let inputs: Vec<Image> = images
        .iter()
        .map(|p| {
            let img = nedrt_core::image_io::load(p)?.image;
            let side = crop.min(img.width).min(img.height);
            Ok(img.crop((img.width - side) / 2, (img.height - side) / 2, side, side))
        })
        .collect::<Result<_, AppError>>()?;
    if inputs.is_empty() {
        return Err(AppError::Unavailable("no images to sweep over".into()));
    }
    let depths: Vec<f64> = calib
        .evaluation_depths_d()
        .into_iter()
        .filter(|d| *d <= HEADLINE_MAX_D + 1e-9)
        .collect();
    let methods = if methods.is_empty() {
        common.default_methods()
    } else {
        methods.to_vec()
    };
    let stages = nedrt_stages::network::wiener_stages(&common.dcnn.load_for(&methods)?)?;
    let design = Simulator::new(
        calib.clone(),
        common.doe_path_for(&methods).as_deref(),
        common.cache(),
    )?
    .with_wiener_stages(stages.clone());
    let nominal = design.prepare(&methods, &depths, common.progress())?;
    let targets: Vec<Vec<Image>> = inputs
        .iter()
        .map(|img| {
            depths
                .iter()
                .map(|d| nominal.target(img, *d))
                .collect::<Result<_, _>>()
        })
        .collect::<Result<_, _>>()?;
    // The design's display images, the same for every build.
    let sharps: Vec<Image> = inputs.iter().map(|img| img.up2()).collect();
    let mut designed: HashMap<Method, Vec<Image>> = HashMap::new();
    for &m in &methods {
        let mut pre = preprocessor(common, &nominal, m)?;
        let shown = inputs
            .iter()
            .map(|img| pre.run(img))
            .collect::<Result<Vec<_>, _>>()?;
        designed.insert(m, shown);
    }
    let mut builds: Vec<(String, f64, Perturbation)> = Vec::new();
    for axis in axes() {
        for &v in &axis.values {
            builds.push((axis.name.to_string(), v, (axis.make)(v)));
        }
    }
    builds.push(("combination".into(), 1.0, combination()));
    let mut nominal_scores = HashMap::new();
    for &m in &methods {
        nominal_scores.insert(
            m,
            score(&nominal, &designed[&m], &sharps, &targets, m, &depths)?,
        );
    }
    let mut rows = Vec::new();
    for (name, value, p) in &builds {
        let built = Simulator::with_doe(
            p.calibration(&calib),
            p.doe(&design.doe, design.calib.doe_wave_height_m()),
            common.cache(),
        )
        .with_wiener_stages(stages.clone());
        let seen = built.prepare(&methods, &depths, common.progress())?;
        for &m in &methods {
            let shown = &designed[&m];
            let mut own = preprocessor(common, &seen, m)?;
            let calibrated = inputs
                .iter()
                .map(|img| own.run(img))
                .collect::<Result<Vec<_>, _>>()?;
            let at = |prepared: &Prepared, shown: &[Image]| {
                score(prepared, shown, &sharps, &targets, m, &depths)
            };
            rows.push(Row {
                error: name.clone(),
                value: *value,
                method: m.name().into(),
                nominal: nominal_scores[&m],
                uncalibrated: at(&seen, shown)?,
                calibrated: at(&seen, &calibrated)?,
            });
        }
        tracing::info!("tolerance: {name} {value} done");
    }
    let method_names: Vec<String> = methods.iter().map(|m| m.name().to_string()).collect();
    let tolerances = tolerances(&rows, &method_names);
    let report = Report {
        calibration: calib.source.clone(),
        crop_px: Some(crop),
        methods: method_names,
        images: images.iter().map(|p| p.display().to_string()).collect(),
        depths_d: depths.clone(),
        rows,
        tolerances,
    };
    write_report(&report, crop, out)
}

/// The report's Markdown, JSON and chart, written beside `out`.
fn write_report(report: &Report, crop: usize, out: &Path) -> Result<String, AppError> {
    let text = markdown(report, crop);
    crate::write_text(out, &text)?;
    let json = serde_json::to_string_pretty(report).map_err(|e| AppError::output(out, e))?;
    crate::write_text(&out.with_extension("json"), &json)?;
    let charts = chart(report, &out.with_extension(""))?;
    Ok(format!(
        "{text}\nwrote {}, {} and {}\n",
        out.display(),
        out.with_extension("json").display(),
        charts.join(", ")
    ))
}

/// `--replot`: the report, its tolerances and its chart made again from
/// `out`'s JSON, without sweeping (after a change to how they are summed
/// or drawn); `crop` where the JSON does not record its own.
pub fn replot(out: &Path, crop: usize) -> Result<String, AppError> {
    let path = out.with_extension("json");
    let bytes = nedrt_core::util::read_capped(&path, 64 << 20).map_err(|e| {
        AppError::input(
            path.display(),
            format!("{e} (--replot reads the JSON a sweep wrote beside --out)"),
        )
    })?;
    let mut report: Report = serde_json::from_slice(&bytes)
        .map_err(|e| AppError::input(path.display(), format!("not a tolerance report: {e}")))?;
    report.tolerances = tolerances(&report.rows, &report.methods);
    let crop = report.crop_px.unwrap_or(crop);
    report.crop_px = Some(crop);
    write_report(&report, crop, out)
}

/// Per error and method, where the uncalibrated display first loses
/// [`LOSS_DB`] vs sharp ([`first_crossing`]; a reciprocal axis walked in
/// 1/value).
pub fn tolerances(rows: &[Row], methods: &[String]) -> Vec<(String, String, Option<f64>)> {
    let mut out = Vec::new();
    for axis in axes() {
        let x = |v: f64| if axis.reciprocal { 1.0 / v } else { v };
        for m in methods {
            let mut pts: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| r.error == axis.name && &r.method == m)
                .map(|r| (x(r.value), r.nominal.sharp - r.uncalibrated.sharp))
                .collect();
            let found = first_crossing(&mut pts, LOSS_DB).map(x);
            out.push((axis.name.to_string(), m.clone(), found));
        }
    }
    out
}

/// Walking outwards from the design (no loss at 0) through `(error, loss)`
/// points, each side of 0 on its own, where the loss first reaches
/// `limit` (linear between the points); the nearer of the two sides'
/// crossings, None if the loss never reaches it.
pub fn first_crossing(points: &mut [(f64, f64)], limit: f64) -> Option<f64> {
    points.sort_by(|a, b| a.0.abs().total_cmp(&b.0.abs()));
    let side = |positive: bool| {
        let mut prev = (0.0, 0.0);
        for &(x, loss) in points
            .iter()
            .filter(|p| (p.0 > 0.0) == positive && p.0 != 0.0)
        {
            if loss >= limit {
                let t = (limit - prev.1) / (loss - prev.1).max(1e-12);
                return Some(prev.0 + t * (x - prev.0));
            }
            prev = (x, loss);
        }
        None
    };
    match (side(true), side(false)) {
        (Some(a), Some(b)) => Some(if a.abs() <= b.abs() { a } else { b }),
        (a, b) => a.or(b),
    }
}

fn markdown(r: &Report, crop: usize) -> String {
    let mut s = format!(
        "Calibration {}; {} image(s) cropped to {crop}²; PSNR mean over {} D.\n\n\
         | error | value | method | nominal vs sharp | as built, design's preprocessing | as built, calibrated | vs target: nominal / as built / calibrated |\n\
         | --- | ---: | --- | ---: | ---: | ---: | --- |\n",
        r.calibration,
        r.images.len(),
        r.depths_d
            .iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    for row in &r.rows {
        s += &format!(
            "| {} | {} | {} | {:.2} | {:.2} ({:+.2}) | {:.2} ({:+.2}) | {:.2} / {:.2} / {:.2} |\n",
            row.error,
            row.value,
            row.method,
            row.nominal.sharp,
            row.uncalibrated.sharp,
            row.uncalibrated.sharp - row.nominal.sharp,
            row.calibrated.sharp,
            row.calibrated.sharp - row.nominal.sharp,
            row.nominal.target,
            row.uncalibrated.target,
            row.calibrated.target
        );
    }
    s += &format!(
        "\nThe error at which each method, preprocessed for its design, loses {LOSS_DB} dB vs sharp:\n\n| error | method | tolerance |\n| --- | --- | ---: |\n"
    );
    for (e, m, t) in &r.tolerances {
        let axis = axes().into_iter().find(|a| a.name == e);
        let unit = axis.as_ref().map_or("", |a| a.unit);
        let reciprocal = axis.is_some_and(|a| a.reciprocal);
        s += &format!(
            "| {e} | {m} | {} |\n",
            t.map_or("beyond the range".to_string(), |v| if reciprocal {
                format!("{v:.1} {unit} (fewer lose more)")
            } else {
                format!("{v:.3} {unit}")
            })
        );
    }
    s
}

fn chart(r: &Report, stem: &Path) -> Result<Vec<String>, AppError> {
    let methods = &r.methods;
    let panels: Vec<Panel> = axes()
        .iter()
        .map(|a| {
            let mut series = Vec::new();
            let (mut lo, mut hi) = (0.0f64, 0.1f64);
            for (i, m) in methods.iter().enumerate() {
                for (dashed, pick) in [(false, 0usize), (true, 1)] {
                    let mut points: Vec<(f64, f64)> = r
                        .rows
                        .iter()
                        .filter(|row| row.error == a.name && &row.method == m)
                        .map(|row| {
                            let after = if pick == 0 {
                                row.uncalibrated.sharp
                            } else {
                                row.calibrated.sharp
                            };
                            (row.value, row.nominal.sharp - after)
                        })
                        .collect();
                    if a.name != "levels" {
                        points.push((0.0, 0.0));
                    }
                    points.sort_by(|x, y| x.0.total_cmp(&y.0));
                    for p in &points {
                        (lo, hi) = (lo.min(p.1), hi.max(p.1));
                    }
                    series.push(Series {
                        name: if dashed {
                            format!("{m}, calibrated")
                        } else {
                            m.clone()
                        },
                        color: series_color(i),
                        dashed,
                        points,
                    });
                }
            }
            let xs: Vec<f64> = a.values.iter().copied().chain([0.0]).collect();
            let (x0, x1) = (
                xs.iter().cloned().fold(f64::MAX, f64::min),
                xs.iter().cloned().fold(f64::MIN, f64::max),
            );
            Panel::Lines(LinePanel {
                title: a.name.to_string(),
                x_label: a.unit.to_string(),
                y_label: "loss vs sharp (dB)".into(),
                x_range: (x0, x1),
                y_range: (lo - 0.05, hi + 0.05),
                series,
                legend: None,
            })
        })
        .collect();
    write_figure(stem, (2, 3), (1500, 900), &panels, true)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tolerance_is_where_the_loss_first_reaches_the_limit() {
        // decentre on the 3 mm calibration (docs/tolerance.md): 0.14, 0.40, 0.64 dB.
        let mut pts = vec![(0.3, 0.64), (0.1, 0.14), (0.2, 0.40)];
        let t = first_crossing(&mut pts, 0.5).expect("a crossing");
        assert!((t - (0.2 + 0.1 * 0.1 / 0.24)).abs() < 1e-12, "{t}");
        // From the design to the first point when that one is already past it.
        assert!((first_crossing(&mut [(2.0, 1.0)], 0.5).expect("crossing") - 1.0).abs() < 1e-12);
        // Each side from the design on its own; the nearer crossing wins
        // (+2.5 between 0 and +10, before −5).
        assert_eq!(
            first_crossing(&mut [(10.0, 2.0), (-5.0, 0.5)], 0.5),
            Some(2.5)
        );
        assert_eq!(
            first_crossing(&mut [(10.0, 0.2), (-5.0, 0.5)], 0.5),
            Some(-5.0)
        );
        assert_eq!(first_crossing(&mut [(0.1, 0.1), (0.2, -0.3)], 0.5), None);
    }

    #[test]
    fn levels_are_walked_from_the_continuous_profile_towards_fewer() {
        // The shipped calibration's doe+wiener (docs/tolerance.md): 0.25 dB
        // at 16 levels, 0.65 at 8, 0.45 at 4, 0.78 at 2. The loss first
        // reaches 0.5 dB between 16 and 8 levels, linear in 1/levels.
        let row = |value: f64, loss: f64| Row {
            error: "levels".into(),
            value,
            method: "doe+wiener".into(),
            nominal: Score {
                sharp: 20.0,
                target: 20.0,
            },
            uncalibrated: Score {
                sharp: 20.0 - loss,
                target: 20.0,
            },
            calibrated: Score {
                sharp: 20.0,
                target: 20.0,
            },
        };
        let rows = [
            row(2.0, 0.78),
            row(4.0, 0.45),
            row(8.0, 0.65),
            row(16.0, 0.25),
        ];
        let t = tolerances(&rows, &["doe+wiener".to_string()]);
        let (_, _, found) = t.iter().find(|(e, ..)| e == "levels").expect("levels");
        let x = 1.0 / 16.0 + (0.5 - 0.25) / (0.65 - 0.25) * (1.0 / 8.0 - 1.0 / 16.0);
        let levels = found.expect("a crossing");
        assert!((levels - 1.0 / x).abs() < 1e-9, "{levels}");
        assert!(levels > 8.0 && levels < 16.0, "{levels}");
        // Already past the limit at 16 levels: from the continuous profile.
        let t = tolerances(&[row(16.0, 1.0)], &["doe+wiener".to_string()]);
        let found = t.iter().find(|(e, ..)| e == "levels").and_then(|r| r.2);
        assert!((found.expect("crossing") - 32.0).abs() < 1e-9);
    }

    #[test]
    fn every_axis_is_a_valid_perturbation_and_zero_is_the_design() {
        for a in axes() {
            for v in &a.values {
                assert!((a.make)(*v).check().is_ok(), "{} {v}", a.name);
            }
            if a.name != "levels" {
                assert!((a.make)(0.0).is_nominal(), "{}", a.name);
            }
        }
        assert!(combination().check().is_ok() && !combination().is_nominal());
    }
}
