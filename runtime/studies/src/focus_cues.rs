//! Focus cues in `nedrt eval` (docs/evaluation.md): the accommodation sweep
//! gathers S_f(D) per method from the perceived images ([`FocusSweep`]), the
//! typed rows summarise each curve at the main depths ([`FocusCues`]), and
//! the report renders them as a Markdown section and a chart (the paper's
//! Fig. 5b–d, from perceived images instead of PSFs). eval.json carries the
//! rows as they are.

use std::fmt::Write as _;
use std::path::Path;

use plotters::prelude::SeriesLabelPosition;
use serde::Serialize;

use super::AppError;
use crate::charts::{LinePanel, MARKER_LINE, Panel, Series, series_color, write_figure};
use nedrt_core::Image;
use nedrt_core::calib::Calibration;
use nedrt_optics::sim::focus::{
    BAND_HALF_WIDTH_OCTAVES, BandPowers, CUE_OFFSET_D, Curve, FOCUS_FREQUENCIES_CPD, Peak,
    SWEEP_STEP_D, SharpnessMeter, mean_defined, sharpness,
};

/// File stem of the chart, written beside eval.md.
pub const CHART_STEM: &str = "focus_cues";

/// Depths closer than this are the same depth, diopters.
const SAME_DEPTH_D: f64 = 1e-9;

/// How the numbers were measured, stated in eval.json so a reader of the
/// file alone can interpret them.
#[derive(Debug, Clone, Serialize)]
pub struct FocusCueDefinition {
    pub frequencies_cpd: Vec<f64>,
    /// The band around f is f·[2^(−w), 2^(w)] with w this many octaves.
    pub band_half_width_octaves: f64,
    pub sweep_step_d: f64,
    pub cue_offset_d: f64,
    pub window: String,
    pub sharpness: String,
    pub score: String,
}

impl FocusCueDefinition {
    pub fn current() -> Self {
        Self {
            frequencies_cpd: FOCUS_FREQUENCIES_CPD.to_vec(),
            band_half_width_octaves: BAND_HALF_WIDTH_OCTAVES,
            sweep_step_d: SWEEP_STEP_D,
            cue_offset_d: CUE_OFFSET_D,
            window: "separable Hann, sin²(π(i+½)/n) per axis, applied to (image − its mean)".into(),
            sharpness: "S_f = sqrt(band power of the perceived image / band power of up2(sharp)) \
                        on the retinal grid, per channel, averaged over channels, then images"
                .into(),
            score: "FC_f(D) = S_f(D) − ½(S_f(D − offset) + S_f(D + offset)); one side where \
                    the other is outside the range"
                .into(),
        }
    }
}

/// S_f(D) over the sweep for one frequency (`None`: no image had anything
/// in that band).
#[derive(Debug, Clone, Serialize)]
pub struct SharpnessCurve {
    pub frequency_cpd: f64,
    pub sharpness: Vec<Option<f64>>,
}

/// S and FC at one main depth for one frequency.
#[derive(Debug, Clone, Serialize)]
pub struct CueScore {
    pub frequency_cpd: f64,
    pub sharpness: Option<f64>,
    pub score: Option<f64>,
}

/// The local maximum of S_5 nearest to a main depth.
#[derive(Debug, Clone, Serialize)]
pub struct NearestPeak {
    pub accommodation_d: f64,
    /// Peak location minus the main depth.
    pub offset_d: f64,
    pub sharpness: f64,
    pub at_range_end: bool,
}

/// The focus cues of one method at one main depth.
#[derive(Debug, Clone, Serialize)]
pub struct MainDepthCue {
    pub depth_d: f64,
    pub scores: Vec<CueScore>,
    /// Nearest local maximum of S at the first frequency (5 CPD).
    pub nearest_peak: Option<NearestPeak>,
}

/// The focus-cue row of one method.
#[derive(Debug, Clone, Serialize)]
pub struct FocusCues {
    /// The sweep's accommodations, diopters.
    pub accommodation_d: Vec<f64>,
    pub curves: Vec<SharpnessCurve>,
    pub main_depths: Vec<MainDepthCue>,
    /// Every local maximum of S at the first frequency (5 CPD).
    pub peaks: Vec<Peak>,
}

impl FocusCues {
    /// Summarises the curves at the main depths.
    pub fn from_curves(
        accommodation_d: Vec<f64>,
        curves: Vec<SharpnessCurve>,
        main_d: &[f64],
    ) -> Self {
        let sampled: Vec<Curve> = curves
            .iter()
            .map(|c| Curve::new(&accommodation_d, &c.sharpness))
            .collect();
        let peaks = sampled.first().map(Curve::local_maxima).unwrap_or_default();
        let main_depths = main_d
            .iter()
            .map(|&d| MainDepthCue {
                depth_d: d,
                scores: curves
                    .iter()
                    .zip(&sampled)
                    .map(|(c, s)| CueScore {
                        frequency_cpd: c.frequency_cpd,
                        sharpness: s.at(d),
                        score: s.focus_cue_score(d, CUE_OFFSET_D),
                    })
                    .collect(),
                nearest_peak: sampled.first().and_then(|s| s.nearest_peak(d)).map(|p| {
                    NearestPeak {
                        accommodation_d: p.accommodation_d,
                        offset_d: p.accommodation_d - d,
                        sharpness: p.value,
                        at_range_end: p.at_range_end,
                    }
                }),
            })
            .collect();
        Self {
            accommodation_d,
            curves,
            main_depths,
            peaks,
        }
    }
}

/// The sweep's measurements while eval renders: per image the sharp
/// reference's band powers, then S of every perceived image.
#[derive(Debug)]
pub struct FocusSweep {
    pub depths_d: Vec<f64>,
    cell_rad: f64,
    meter: Option<SharpnessMeter>,
    sharp: Option<BandPowers>,
    /// s[row][depth][frequency]: S of each image, in image order.
    s: Vec<Vec<Vec<Vec<Option<f64>>>>>,
}

impl FocusSweep {
    /// A sweep over the calibrated range in [`SWEEP_STEP_D`] steps for `rows` methods.
    pub fn new(calib: &Calibration, rows: usize) -> Self {
        let depths_d = calib.depth_sweep_d(SWEEP_STEP_D);
        let per_depth = vec![vec![Vec::new(); FOCUS_FREQUENCIES_CPD.len()]; depths_d.len()];
        Self {
            depths_d,
            cell_rad: calib.retinal_step_rad(),
            meter: None,
            sharp: None,
            s: vec![per_depth; rows],
        }
    }

    /// The sweep index of `d`, if it is one of the sweep's depths.
    pub fn index_of(&self, d: f64) -> Option<usize> {
        self.depths_d
            .iter()
            .position(|x| (x - d).abs() < SAME_DEPTH_D)
    }

    /// Starts an image: measures its sharp retinal image up2(I) (the meter
    /// is planned again only when the size changes).
    pub fn start_image(&mut self, sharp: &Image) {
        if self
            .meter
            .as_ref()
            .is_none_or(|m| !m.has_size(sharp.width, sharp.height))
        {
            self.meter = Some(SharpnessMeter::new(
                sharp.width,
                sharp.height,
                self.cell_rad,
                &FOCUS_FREQUENCIES_CPD,
            ));
        }
        self.sharp = self.meter.as_ref().map(|m| m.band_powers(sharp));
    }

    /// Records S of a perceived image of the current image.
    pub fn record(&mut self, row: usize, depth_index: usize, perceived: &Image) {
        let (Some(meter), Some(sharp)) = (&self.meter, &self.sharp) else {
            return;
        };
        let s = sharpness(&meter.band_powers(perceived), sharp);
        for (acc, v) in self.s[row][depth_index].iter_mut().zip(s) {
            acc.push(v);
        }
    }

    /// One row per method: the curves averaged over the images, summarised
    /// at `main_d`.
    pub fn finish(self, main_d: &[f64]) -> Vec<FocusCues> {
        let depths = self.depths_d;
        self.s
            .into_iter()
            .map(|per_depth| {
                let curves = FOCUS_FREQUENCIES_CPD
                    .iter()
                    .enumerate()
                    .map(|(fi, &f)| SharpnessCurve {
                        frequency_cpd: f,
                        sharpness: per_depth
                            .iter()
                            .map(|per_freq| mean_defined(per_freq[fi].iter().copied()))
                            .collect(),
                    })
                    .collect();
                FocusCues::from_curves(depths.clone(), curves, main_d)
            })
            .collect()
    }
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or_else(|| "–".into(), |v| format!("{v:.digits$}"))
}

/// The Markdown section: S and FC at each main depth per method, the
/// nearest S_5 maximum, and the chart.
pub fn markdown(rows: &[(&str, &FocusCues)]) -> String {
    let f = FOCUS_FREQUENCIES_CPD;
    let mut t = format!(
        "\n## Focus cues (perceived sharpness across accommodation)\n\n\
         S_f(D): contrast of the perceived image at f CPD relative to the sharp image \
         (half-octave band, Hann window; 1 = as sharp as the input), every {SWEEP_STEP_D} D. \
         FC_f = S_f(D) − ½(S_f(D − {CUE_OFFSET_D}) + S_f(D + {CUE_OFFSET_D})): how far \
         sharpness falls {CUE_OFFSET_D} D away (> 0: a cue to focus at D). \
         Peak: the local maximum of S_{} nearest to D (offset in brackets; \
         † at the end of the range).\n\n\
         ![S_{} and S_{} against accommodation]({CHART_STEM}.png)\n\n\
         | method | D | S_{} | S_{} | FC_{} | FC_{} | S_{} peak (D) |\n\
         | --- | --- | --- | --- | --- | --- | --- |\n",
        f[0], f[0], f[1], f[0], f[1], f[0], f[1], f[0]
    );
    for (name, cues) in rows {
        for m in &cues.main_depths {
            let _ = write!(t, "| {name} | {:.1} |", m.depth_d);
            for s in &m.scores {
                let _ = write!(t, " {} |", opt(s.sharpness, 3));
            }
            for s in &m.scores {
                let _ = write!(t, " {} |", opt(s.score, 3));
            }
            match &m.nearest_peak {
                Some(p) => {
                    let _ = writeln!(
                        t,
                        " {:.2} ({:+.2}){} |",
                        p.accommodation_d,
                        p.offset_d,
                        if p.at_range_end { " †" } else { "" }
                    );
                }
                None => t.push_str(" – |\n"),
            }
        }
    }
    for (name, cues) in rows {
        let peaks: Vec<String> = cues
            .peaks
            .iter()
            .map(|p| format!("{:.2} D ({:.3})", p.accommodation_d, p.value))
            .collect();
        let _ = writeln!(
            t,
            "\nS_{} maxima, {name}: {}.",
            f[0],
            if peaks.is_empty() {
                "none".into()
            } else {
                peaks.join(", ")
            }
        );
    }
    t
}

/// Writes the chart (one panel per frequency, a line per method, the main
/// depths marked) to `out_dir`/focus_cues.png and .svg.
pub fn write_chart(
    out_dir: &Path,
    rows: &[(&str, &FocusCues)],
    main_d: &[f64],
    range_d: [f64; 2],
) -> Result<Vec<String>, AppError> {
    let y_max = rows
        .iter()
        .flat_map(|(_, c)| c.curves.iter().flat_map(|k| k.sharpness.iter().flatten()))
        .fold(1.0f64, |a, v| a.max(*v))
        * 1.05;
    let panels: Vec<Panel> = FOCUS_FREQUENCIES_CPD
        .iter()
        .enumerate()
        .map(|(fi, f)| {
            let marks = main_d.iter().enumerate().map(|(i, &d)| Series {
                name: if i == 0 {
                    "main depths".into()
                } else {
                    String::new()
                },
                color: MARKER_LINE,
                dashed: true,
                points: vec![(d, 0.0), (d, y_max)],
            });
            let lines = rows.iter().enumerate().map(|(ri, (name, c))| Series {
                name: (*name).to_string(),
                color: series_color(ri),
                dashed: false,
                points: c
                    .accommodation_d
                    .iter()
                    .zip(&c.curves[fi].sharpness)
                    .filter_map(|(d, s)| s.map(|s| (*d, s)))
                    .collect(),
            });
            Panel::Lines(LinePanel {
                title: format!("Perceived sharpness at {f} CPD (vs sharp input)"),
                x_label: "accommodation (D)".into(),
                y_label: format!("S_{f}"),
                x_range: (range_d[0], range_d[1]),
                y_range: (0.0, y_max),
                series: marks.chain(lines).collect(),
                // The axis reaches S = 1.05 and perceived frames are rarely that
                // sharp, so the upper right stays clear of the curves.
                legend: Some(SeriesLabelPosition::UpperRight),
            })
        })
        .collect();
    write_figure(
        &out_dir.join(CHART_STEM),
        (1, panels.len()),
        (1200, 480),
        &panels,
        true,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_summarise_the_curves_at_the_main_depths() {
        let depths: Vec<f64> = (0..=30).map(|i| i as f64 / 10.0).collect();
        // S_5 peaks at 1.5 D, S_10 is flat.
        let tent: Vec<Option<f64>> = depths
            .iter()
            .map(|d| Some(1.0 - (d - 1.5).abs() / 3.0))
            .collect();
        let flat = vec![Some(0.4); depths.len()];
        let cues = FocusCues::from_curves(
            depths,
            vec![
                SharpnessCurve {
                    frequency_cpd: 5.0,
                    sharpness: tent,
                },
                SharpnessCurve {
                    frequency_cpd: 10.0,
                    sharpness: flat,
                },
            ],
            &[0.5, 1.5, 2.5],
        );
        let mid = &cues.main_depths[1];
        assert!((mid.scores[0].score.expect("fc") - 0.5 / 3.0).abs() < 1e-12);
        assert_eq!(mid.scores[1].score, Some(0.0));
        let p = mid.nearest_peak.as_ref().expect("peak");
        assert!(p.offset_d.abs() < 1e-9 && !p.at_range_end);
        // 0.5 D: the nearest maximum is 1.5 D's, a full diopter away.
        let low = cues.main_depths[0].nearest_peak.as_ref().expect("peak");
        assert!((low.offset_d - 1.0).abs() < 1e-9);
        let md = markdown(&[("tent", &cues)]);
        assert!(
            md.contains("| tent | 1.5 | 1.000 | 0.400 | 0.167 | 0.000 | 1.50 (+0.00) |"),
            "{md}"
        );
        assert!(md.contains("focus_cues.png"), "{md}");
    }
}
