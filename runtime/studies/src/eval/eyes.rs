//! `nedrt eval --eyes`: the evaluation repeated for several eyes
//! (docs/model.md §4a) — pupil diameters, field angles, eye LCA — with one
//! table per headline and a chart of each method's headline against the
//! pupil diameter (docs/evaluation.md, "Where the designs break").
//!
//! Each eye's full evaluation goes to `OUT/<eye>/` (eval.md, eval.json);
//! an eye whose eval.json is there for the same eye, images and rows is
//! read back instead of recomputed, so a long study resumes where it stopped.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{EvalExtras, EvalResult, evaluate};
use crate::charts::{LinePanel, Panel, Series, series_color, write_figure};
use crate::{AppError, CommonOptions, create_dir, write_text};
use nedrt_core::calib::{EyeLca, EyeOverrides};
use nedrt_optics::sim::Method;

/// The chart's file stem under the output folder.
const CHART_STEM: &str = "eyes";

/// One eye of the study: a label and its overrides of the calibration's `[eye]`.
#[derive(Debug, Clone, PartialEq)]
pub struct EyeCase {
    pub label: String,
    pub overrides: EyeOverrides,
}

impl std::str::FromStr for EyeCase {
    type Err = String;

    /// `paper` (the eyepiece's aperture is the stop) or `<D>mm` (a pupil of
    /// D mm), then optionally `@<θ>` (field angle, degrees) and `+lca`
    /// (Thibos 1992 eye LCA): `3mm`, `4mm@20`, `4mm+lca`, `paper+lca`.
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = |why: &str| format!("{s:?}: {why} (paper, 3mm, 4mm@20, 4mm+lca)");
        let (rest, lca) = match s.strip_suffix("+lca") {
            Some(r) => (r, true),
            None => (s, false),
        };
        let (pupil, field) = match rest.split_once('@') {
            Some((p, f)) => (
                p,
                Some(
                    f.trim_end_matches("deg")
                        .parse::<f64>()
                        .map_err(|_| bad("the field angle is not a number"))?,
                ),
            ),
            None => (rest, None),
        };
        let pupil_mm = match pupil {
            "paper" => None,
            p => Some(
                p.strip_suffix("mm")
                    .ok_or_else(|| bad("a pupil is written in mm"))?
                    .parse::<f64>()
                    .map_err(|_| bad("the pupil is not a number"))?,
            ),
        };
        if pupil_mm.is_none() && field.is_some() {
            return Err(bad("the paper's eye has no field dependence: give a pupil"));
        }
        // `paper` is the paper's eye: no pupil and no eye LCA, whatever the
        // calibration or the command line say; a pupil case keeps their
        // LCA unless it adds `+lca`.
        let paper = pupil_mm.is_none();
        Ok(EyeCase {
            label: s.to_string(),
            overrides: EyeOverrides {
                pupil_diameter_mm: Some(pupil_mm),
                relief_mm: None,
                field_deg: if paper { Some(0.0) } else { field },
                lca: match (lca, paper) {
                    (true, _) => Some(EyeLca::Thibos1992),
                    (false, true) => Some(EyeLca::Off),
                    (false, false) => None,
                },
            },
        })
    }
}

/// One eye's headlines, per evaluated row (method or design).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EyeRow {
    pub eye: String,
    /// What the calibration made of it (`Calibration::eye_summary`).
    pub summary: String,
    /// Pupil diameter, mm (`None`: the paper's eye).
    pub pupil_mm: Option<f64>,
    pub field_deg: f64,
    pub lca: bool,
    pub rows: Vec<MethodHeadline>,
    pub seconds: f64,
    /// What was evaluated (images, rows, DOE, D-CNN): a row is read back
    /// only into a study of the same.
    #[serde(default)]
    pub study: String,
}

/// One evaluated row's headlines under one eye (PSNR over 0–2.5 D).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MethodHeadline {
    pub method: String,
    pub mean_vs_sharp_db: f64,
    pub worst_vs_sharp_db: f64,
    pub mean_vs_target_db: f64,
    /// The focus-cue score at 5 CPD averaged over the main depths, when measured.
    pub focus_cue_5cpd: Option<f64>,
}

/// The study: an evaluation per eye, then the tables and the chart.
pub fn run(
    common: &CommonOptions,
    images_dir: &Path,
    out_dir: &Path,
    methods: &[Method],
    extras: &EvalExtras,
    cases: &[EyeCase],
) -> Result<String, AppError> {
    create_dir(out_dir)?;
    let study = signature(common, images_dir, methods, extras);
    let mut rows = Vec::with_capacity(cases.len());
    for case in cases {
        let mut eye_common = common.clone();
        eye_common.eye = merged(&common.eye, &case.overrides);
        let calib = eye_common.calibration()?;
        let dir = out_dir.join(dir_name(&case.label));
        let summary = calib.eye_summary();
        let row = match resume(&dir, &case.label, &summary, &study) {
            Some(r) => {
                tracing::info!("{}: read back from {}", case.label, dir.display());
                r
            }
            None => {
                tracing::info!("{}: {summary}", case.label);
                let (result, _) = evaluate(&eye_common, images_dir, &dir, methods, extras)?;
                let row = eye_row(case, &summary, &study, &calib.eye, &result);
                let path = dir.join("eye.json");
                let json =
                    serde_json::to_string_pretty(&row).map_err(|e| AppError::output(&path, e))?;
                write_text(&path, &json)?;
                row
            }
        };
        rows.push(row);
    }
    let aperture_mm = 2e3 * common.calibration()?.aperture_radius_m;
    let md = markdown(&rows, aperture_mm);
    let md_path = out_dir.join("eyes.md");
    write_text(&md_path, &md)?;
    let json_path = out_dir.join("eyes.json");
    let json = serde_json::to_string_pretty(&rows).map_err(|e| AppError::output(&json_path, e))?;
    write_text(&json_path, &json)?;
    let charts = chart(out_dir, &rows, aperture_mm)?;
    Ok(format!(
        "{md}\nwrote {}, {}{}\n",
        md_path.display(),
        json_path.display(),
        charts.iter().map(|c| format!(", {c}")).collect::<String>()
    ))
}

/// The case's overrides over the command line's own (`--eye-relief-mm`
/// for all, `--eye-lca` for the pupil cases without `+lca`).
fn merged(base: &EyeOverrides, case: &EyeOverrides) -> EyeOverrides {
    EyeOverrides {
        pupil_diameter_mm: case.pupil_diameter_mm.or(base.pupil_diameter_mm),
        relief_mm: case.relief_mm.or(base.relief_mm),
        field_deg: case.field_deg.or(base.field_deg),
        lca: case.lca.or(base.lca),
    }
}

/// A folder name for a label: `4mm@20+lca` → `4mm-at20-lca`.
fn dir_name(label: &str) -> PathBuf {
    PathBuf::from(label.replace('@', "-at").replace('+', "-"))
}

/// The eye's row from an earlier run, when it was made for the same eye
/// and the same study.
fn resume(dir: &Path, label: &str, summary: &str, study: &str) -> Option<EyeRow> {
    let text = std::fs::read_to_string(dir.join("eye.json")).ok()?;
    let row: EyeRow = serde_json::from_str(&text).ok()?;
    (row.eye == label && row.summary == summary && row.study == study).then_some(row)
}

/// What a study evaluates, as one line: the images, the rows (methods,
/// designs, prefilters, an external folder), the calibration, the DOE and
/// the D-CNN, and whether focus cues are measured.
fn signature(
    common: &CommonOptions,
    images_dir: &Path,
    methods: &[Method],
    extras: &EvalExtras,
) -> String {
    let names = |v: Vec<String>| v.join(",");
    format!(
        "images {}; methods {}; designs {}; prefilters {}; external {}; calib {}; doe {}; dcnn {}; focus cues {}",
        images_dir.display(),
        names(methods.iter().map(|m| m.name().to_string()).collect()),
        names(
            extras
                .designs
                .iter()
                .map(|d| d.source.display().to_string())
                .collect()
        ),
        names(extras.prefilters.iter().map(|p| p.to_string()).collect()),
        extras
            .external
            .as_ref()
            .map_or("none".into(), |e| e.dir.display().to_string()),
        common
            .calib
            .as_ref()
            .map_or("embedded".into(), |p| p.display().to_string()),
        common
            .doe
            .as_ref()
            .map_or("calibration's".into(), |p| p.display().to_string()),
        common.dcnn.path.display(),
        extras.focus_cues
    )
}

fn eye_row(
    case: &EyeCase,
    summary: &str,
    study: &str,
    eye: &nedrt_core::calib::EyeSettings,
    r: &EvalResult,
) -> EyeRow {
    EyeRow {
        eye: case.label.clone(),
        summary: summary.to_string(),
        pupil_mm: eye.pupil_diameter_m.map(|d| d * 1e3),
        field_deg: eye.field_rad.to_degrees(),
        lca: eye.lca != EyeLca::Off,
        rows: r
            .methods
            .iter()
            .map(|m| {
                let cue = m.focus_cues.as_ref().and_then(|c| {
                    let s: Vec<f64> = c
                        .main_depths
                        .iter()
                        .filter_map(|d| d.scores.first().and_then(|s| s.score))
                        .collect();
                    (!s.is_empty()).then(|| s.iter().sum::<f64>() / s.len() as f64)
                });
                MethodHeadline {
                    method: m.method.clone(),
                    mean_vs_sharp_db: m.headline_vs_sharp.mean.psnr_db,
                    worst_vs_sharp_db: m.headline_vs_sharp.worst.psnr_db,
                    mean_vs_target_db: m.headline_vs_target.mean.psnr_db,
                    focus_cue_5cpd: cue,
                }
            })
            .collect(),
        seconds: r.seconds,
        study: study.to_string(),
    }
}

/// The three tables: mean / worst vs sharp, mean vs target, and the focus
/// cues where measured; a row per eye, a column per method.
pub fn markdown(rows: &[EyeRow], aperture_mm: f64) -> String {
    let mut t = String::new();
    let Some(first) = rows.first() else {
        return "no eyes evaluated\n".into();
    };
    let names: Vec<&str> = first.rows.iter().map(|r| r.method.as_str()).collect();
    let header = |t: &mut String, title: &str| {
        let _ = writeln!(t, "### {title}\n");
        let _ = writeln!(t, "| eye | {} |", names.join(" | "));
        let _ = writeln!(t, "| --- |{}", " --- |".repeat(names.len()));
    };
    let label = |r: &EyeRow| match r.pupil_mm {
        None => format!("{} (the {aperture_mm:.0} mm aperture)", r.eye),
        Some(_) => r.eye.clone(),
    };
    type Pick = fn(&MethodHeadline) -> f64;
    let tables: [(&str, Pick); 3] = [
        ("Mean PSNR vs sharp over 0–2.5 D (dB)", |c| {
            c.mean_vs_sharp_db
        }),
        ("Worst PSNR vs sharp over 0–2.5 D (dB)", |c| {
            c.worst_vs_sharp_db
        }),
        ("Mean PSNR vs target over 0–2.5 D (dB)", |c| {
            c.mean_vs_target_db
        }),
    ];
    for (title, pick) in tables {
        header(&mut t, title);
        for r in rows {
            let best = r.rows.iter().map(pick).fold(f64::NEG_INFINITY, f64::max);
            let cells: Vec<String> = r
                .rows
                .iter()
                .map(|c| match pick(c) {
                    v if v == best => format!("**{v:.2}**"),
                    v => format!("{v:.2}"),
                })
                .collect();
            let _ = writeln!(t, "| {} | {} |", label(r), cells.join(" | "));
        }
        t.push('\n');
    }
    if rows
        .iter()
        .any(|r| r.rows.iter().any(|c| c.focus_cue_5cpd.is_some()))
    {
        header(
            &mut t,
            "Focus cues: FC at 5 CPD, mean over the main depths (higher: a sharper peak where it belongs)",
        );
        for r in rows {
            let cells: Vec<String> = r
                .rows
                .iter()
                .map(|c| c.focus_cue_5cpd.map_or("–".into(), |v| format!("{v:.3}")))
                .collect();
            let _ = writeln!(t, "| {} | {} |", label(r), cells.join(" | "));
        }
        t.push('\n');
    }
    for r in rows {
        let _ = writeln!(t, "- {}: {} ({:.0} s)", r.eye, r.summary, r.seconds);
    }
    t
}

/// Each method's mean PSNR vs sharp against the pupil diameter, on axis
/// without eye LCA (the paper's eye at the aperture's diameter): eyes.png/.svg.
fn chart(out_dir: &Path, rows: &[EyeRow], aperture_mm: f64) -> Result<Vec<String>, AppError> {
    let on_axis: Vec<(f64, &EyeRow)> = rows
        .iter()
        .filter(|r| r.field_deg == 0.0 && !r.lca)
        .map(|r| (r.pupil_mm.unwrap_or(aperture_mm), r))
        .collect();
    if on_axis.len() < 2 {
        return Ok(Vec::new());
    }
    let names: Vec<String> = on_axis[0].1.rows.iter().map(|c| c.method.clone()).collect();
    let mut series = Vec::new();
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (i, name) in names.iter().enumerate() {
        let mut points: Vec<(f64, f64)> = on_axis
            .iter()
            .filter_map(|(d, r)| {
                r.rows
                    .iter()
                    .find(|c| &c.method == name)
                    .map(|c| (*d, c.mean_vs_sharp_db))
            })
            .collect();
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        for p in &points {
            lo = lo.min(p.1);
            hi = hi.max(p.1);
        }
        series.push(Series {
            name: name.clone(),
            color: series_color(i),
            dashed: false,
            points,
        });
    }
    let x_max = on_axis.iter().map(|p| p.0).fold(0.0, f64::max) + 0.5;
    let panel = Panel::Lines(LinePanel {
        title: "Mean PSNR vs sharp over 0–2.5 D against the eye's pupil (on axis, no eye LCA)"
            .into(),
        x_label: format!("pupil diameter (mm; {aperture_mm:.0}: the paper's eye)"),
        y_label: "PSNR (dB)".into(),
        x_range: (0.0, x_max),
        y_range: ((lo - 1.0).floor(), (hi + 1.0).ceil()),
        series,
        legend: Some(plotters::prelude::SeriesLabelPosition::LowerRight),
    });
    write_figure(
        &out_dir.join(CHART_STEM),
        (1, 1),
        (900, 560),
        &[panel],
        true,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eye_cases_parse_and_bad_ones_say_why() {
        let c: EyeCase = "4mm@20+lca".parse().expect("case");
        assert_eq!(c.overrides.pupil_diameter_mm, Some(Some(4.0)));
        assert_eq!(c.overrides.field_deg, Some(20.0));
        assert_eq!(c.overrides.lca, Some(EyeLca::Thibos1992));
        let p: EyeCase = "paper".parse().expect("paper");
        assert_eq!(p.overrides.pupil_diameter_mm, Some(None));
        assert_eq!(p.overrides.lca, Some(EyeLca::Off));
        // A pupil without +lca keeps the command line's or calibration's LCA.
        let plain: EyeCase = "3mm".parse().expect("3mm");
        assert_eq!(plain.overrides.lca, None);
        let base = EyeOverrides {
            pupil_diameter_mm: Some(Some(6.0)),
            lca: Some(EyeLca::Thibos1992),
            ..Default::default()
        };
        assert_eq!(merged(&base, &p.overrides).pupil_diameter_mm, Some(None));
        assert_eq!(
            merged(&base, &plain.overrides).lca,
            Some(EyeLca::Thibos1992)
        );
        for (bad, why) in [
            ("4", "in mm"),
            ("xmm", "not a number"),
            ("4mm@x", "field angle"),
            ("paper@10", "give a pupil"),
        ] {
            let e = bad.parse::<EyeCase>().unwrap_err();
            assert!(e.contains(why), "{bad}: {e}");
        }
        assert_eq!(dir_name("4mm@20+lca"), PathBuf::from("4mm-at20-lca"));
    }

    #[test]
    fn tables_mark_the_best_and_name_the_papers_aperture() {
        let row = |eye: &str, pupil: Option<f64>, a: f64, b: f64| EyeRow {
            eye: eye.into(),
            summary: "s".into(),
            pupil_mm: pupil,
            field_deg: 0.0,
            lca: false,
            rows: vec![
                MethodHeadline {
                    method: "conventional".into(),
                    mean_vs_sharp_db: a,
                    worst_vs_sharp_db: a - 2.0,
                    mean_vs_target_db: a,
                    focus_cue_5cpd: None,
                },
                MethodHeadline {
                    method: "ai".into(),
                    mean_vs_sharp_db: b,
                    worst_vs_sharp_db: b - 1.0,
                    mean_vs_target_db: b,
                    focus_cue_5cpd: Some(0.1),
                },
            ],
            seconds: 1.0,
            study: String::new(),
        };
        let md = markdown(
            &[
                row("paper", None, 23.0, 24.0),
                row("3mm", Some(3.0), 26.0, 25.5),
            ],
            10.0,
        );
        assert!(
            md.contains("| paper (the 10 mm aperture) | 23.00 | **24.00** |"),
            "{md}"
        );
        assert!(md.contains("| 3mm | **26.00** | 25.50 |"), "{md}");
        assert!(md.contains("| 3mm | – | 0.100 |"), "{md}");
    }
}
