//! `nedrt psf`, `nedrt mtf`, `nedrt doe`, `nedrt calib`: the paper's Fig. 4
//! and Fig. 5 for the calibrated system (lens + DOE, and lens alone for
//! comparison), as PNG, SVG and CSV.

use std::fmt::Write as _;
use std::path::Path;

use plotters::style::RGBColor;

use super::{AppError, CommonOptions, create_dir, write_text};
use crate::charts::{
    BLUE_LINE, GREEN_LINE, HeatPanel, LinePanel, Panel, RED_LINE, Series, viridis, write_figure,
};
use nedrt_optics::mtf::{system_mtf, system_psf};
use nedrt_optics::sim::{Method, Prepared, Simulator};
use nedrt_optics::{HeightMap, Psf, doe_file};

/// Half-width of the PSF cross-section plots (paper Fig. 4b: ±20 arcmin).
const CROSS_SECTION_ARCMIN: f64 = 20.0;

fn sweep_depths(sim: &Simulator, step_d: f64) -> Result<Vec<f64>, AppError> {
    if !(step_d.is_finite() && step_d > 0.0 && step_d <= 1.0) {
        return Err(AppError::option(
            format!("--step {step_d}"),
            "must be in (0, 1] D",
        ));
    }
    Ok(sim.calib.depth_sweep_d(step_d))
}

fn prepare_sweep(
    common: &CommonOptions,
    step_d: f64,
) -> Result<(Simulator, Vec<f64>, Prepared), AppError> {
    let sim = Simulator::new(common.calibration()?, common.doe_path(), common.cache())?;
    let depths = sweep_depths(&sim, step_d)?;
    let prepared = sim.prepare(
        &[Method::DoeOnly, Method::Conventional],
        &depths,
        common.progress(),
    )?;
    Ok((sim, depths, prepared))
}

/// Symmetric cut through the system PSF (h ∗ pixel): the mean of its two
/// central rows; returns (angle in arcmin, value) pairs.
fn system_cut(psf: &Psf, cell_arcmin: f64) -> Vec<(f64, f64)> {
    let n = psf.window + 1;
    let sys = system_psf(psf);
    let (r0, r1) = (n / 2 - 1, n / 2);
    (0..n)
        .map(|x| {
            let angle = (x as f64 - (n as f64 - 1.0) / 2.0) * cell_arcmin;
            (angle, 0.5 * (sys[r0 * n + x] + sys[r1 * n + x]))
        })
        .collect()
}

fn header(sim: &Simulator, prepared: &Prepared) -> String {
    let mut t = format!(
        "calibration {}; DOE {} ({})\n",
        sim.calib.source, sim.doe_hash, sim.doe.description
    );
    for (name, r) in &prepared.reports {
        let _ = writeln!(t, "model {name}: {}", r.summary());
    }
    t
}

/// Layout of one written figure.
struct Figure {
    stem: &'static str,
    layout: (usize, usize),
    size: (u32, u32),
    svg: bool,
}

/// Writes the figure and its CSV (`stem`.csv) and reports what was written.
fn finish(
    sim: &Simulator,
    prepared: &Prepared,
    out_dir: &Path,
    figure: Figure,
    panels: &[Panel],
    csv: &str,
) -> Result<String, AppError> {
    let csv_path = out_dir.join(format!("{}.csv", figure.stem));
    write_text(&csv_path, csv)?;
    let written = write_figure(
        &out_dir.join(figure.stem),
        figure.layout,
        figure.size,
        panels,
        figure.svg,
    )?;
    Ok(format!(
        "{}wrote {} and {}\n",
        header(sim, prepared),
        written.join(", "),
        csv_path.display()
    ))
}

/// Fig. 4b: PSF cross-sections against accommodation.
pub fn psf(common: &CommonOptions, out_dir: &Path, step_d: f64) -> Result<String, AppError> {
    create_dir(out_dir)?;
    let (sim, depths, prepared) = prepare_sweep(common, step_d)?;
    let cell_arcmin = sim.calib.retinal_step_rad().to_degrees() * 60.0;
    let names: Vec<String> = sim.calib.channels.iter().map(|c| c.name.clone()).collect();
    let mut csv = String::from("optics,accommodation_d,channel,angle_arcmin,value\n");
    let mut panels = Vec::new();
    for (label, method) in [
        ("lens + DOE", Method::DoeOnly),
        ("lens only", Method::Conventional),
    ] {
        // cuts[depth][channel] = (angle, value) within ±20 arcmin.
        let mut cuts = Vec::new();
        for &d in &depths {
            let psfs = prepared.system_psfs(method, d)?;
            let per: Vec<Vec<(f64, f64)>> = psfs
                .iter()
                .map(|p| {
                    system_cut(p, cell_arcmin)
                        .into_iter()
                        .filter(|(a, _)| a.abs() <= CROSS_SECTION_ARCMIN)
                        .collect()
                })
                .collect();
            for (ch, cut) in per.iter().enumerate() {
                for (a, v) in cut {
                    let _ = writeln!(csv, "{label},{d:.3},{},{a:.4},{v:.6e}", names[ch]);
                }
            }
            cuts.push(per);
        }
        // RGB image, square-root scaled per channel to its largest value.
        let peak: Vec<f64> = (0..names.len())
            .map(|ch| {
                cuts.iter()
                    .flat_map(|c| c[ch].iter().map(|p| p.1))
                    .fold(1e-300, f64::max)
            })
            .collect();
        let rows = cuts.first().map_or(0, |c| c[0].len());
        let colors: Vec<Vec<RGBColor>> = (0..rows)
            .map(|r| {
                cuts.iter()
                    .map(|c| {
                        let v = |ch: usize| ((c[ch][r].1 / peak[ch]).max(0.0).sqrt() * 255.0) as u8;
                        RGBColor(v(0), v(1), v(2))
                    })
                    .collect()
            })
            .collect();
        let half_step = step_d / 2.0;
        panels.push(Panel::Heat(HeatPanel {
            title: format!("PSF cross-sections, {label} (√ scale)"),
            x_label: "accommodation (D)".into(),
            y_label: "arcmin".into(),
            x_range: (depths[0] - half_step, depths[depths.len() - 1] + half_step),
            y_range: (-CROSS_SECTION_ARCMIN, CROSS_SECTION_ARCMIN),
            colors,
        }));
    }
    let figure = Figure {
        stem: "psf_cross_sections",
        layout: (1, 2),
        size: (1200, 520),
        svg: false,
    };
    finish(&sim, &prepared, out_dir, figure, &panels, &csv)
}

/// Fig. 5: MTF at 0.5 D against CPD, and against accommodation at 1, 5, 10 CPD.
pub fn mtf(common: &CommonOptions, out_dir: &Path, step_d: f64) -> Result<String, AppError> {
    create_dir(out_dir)?;
    let (sim, depths, prepared) = prepare_sweep(common, step_d)?;
    let c = &sim.calib;
    let dtheta = c.retinal_step_rad();
    let colors = [RED_LINE, GREEN_LINE, BLUE_LINE];
    let g = c.design_channel;
    let freqs: Vec<f64> = (0..=60).map(|i| i as f64 * 0.5).collect();
    let mut csv = String::from("figure,optics,channel,accommodation_d,cpd,mtf\n");

    // The curves of Fig. 5: every channel through lens + DOE, and the design
    // channel through the lens alone (dashed).
    let curves: Vec<(Method, usize)> = (0..c.channels.len())
        .map(|ch| (Method::DoeOnly, ch))
        .chain([(Method::Conventional, g)])
        .collect();
    let label = |m: Method| {
        if m == Method::DoeOnly {
            "lens+DOE"
        } else {
            "lens"
        }
    };
    let series_of = |m: Method, ch: usize, points: Vec<(f64, f64)>| {
        let lens_only = m == Method::Conventional;
        Series {
            name: if lens_only {
                format!("lens-only {}", c.channels[ch].name)
            } else {
                c.channels[ch].name.clone()
            },
            color: if lens_only {
                GREEN_LINE
            } else {
                colors[ch % 3]
            },
            dashed: lens_only,
            points,
        }
    };
    let mut row = |fig: &str, m: Method, ch: usize, d: f64, f: f64, v: f64| {
        let _ = writeln!(
            csv,
            "{fig},{},{},{d:.3},{f},{v:.6}",
            label(m),
            c.channels[ch].name
        );
    };

    let at_half = 0.5;
    let mut series = Vec::new();
    for &(m, ch) in &curves {
        let psf = &prepared.system_psfs(m, at_half)?[ch];
        let pts: Vec<(f64, f64)> = freqs
            .iter()
            .copied()
            .zip(system_mtf(psf, dtheta, &freqs))
            .collect();
        pts.iter()
            .for_each(|(f, v)| row("a", m, ch, at_half, *f, *v));
        series.push(series_of(m, ch, pts));
    }
    let mut panels = vec![Panel::Lines(LinePanel {
        title: format!("MTF at {at_half} D"),
        x_label: "CPD".into(),
        y_label: "MTF".into(),
        x_range: (0.0, 30.0),
        y_range: (0.0, 1.02),
        series,
        legend: None,
    })];

    let psfs_at: Vec<[Vec<Psf>; 2]> = depths
        .iter()
        .map(|d| {
            Ok([
                prepared.system_psfs(Method::DoeOnly, *d)?,
                prepared.system_psfs(Method::Conventional, *d)?,
            ])
        })
        .collect::<Result<_, AppError>>()?;
    for (fig, cpd) in ["b", "c", "d"].iter().zip([1.0, 5.0, 10.0]) {
        let mut series = Vec::new();
        for &(m, ch) in &curves {
            let which = usize::from(m == Method::Conventional);
            let pts: Vec<(f64, f64)> = depths
                .iter()
                .zip(&psfs_at)
                .map(|(d, psfs)| (*d, system_mtf(&psfs[which][ch], dtheta, &[cpd])[0]))
                .collect();
            pts.iter().for_each(|(d, v)| row(fig, m, ch, *d, cpd, *v));
            series.push(series_of(m, ch, pts));
        }
        panels.push(Panel::Lines(LinePanel {
            title: format!("MTF at {cpd} CPD"),
            x_label: "accommodation (D)".into(),
            y_label: "MTF".into(),
            x_range: (depths[0], depths[depths.len() - 1]),
            y_range: (0.0, 1.02),
            series,
            legend: None,
        }));
    }
    let figure = Figure {
        stem: "mtf",
        layout: (2, 2),
        size: (1100, 800),
        svg: true,
    };
    finish(&sim, &prepared, out_dir, figure, &panels, &csv)
}

/// Fig. 4a: the height map; optionally writes the DOE files.
pub fn doe(
    common: &CommonOptions,
    out_dir: &Path,
    write_init: Option<&Path>,
    write_fabrication: Option<&Path>,
) -> Result<String, AppError> {
    let calib = common.calibration()?;
    let mut t = String::new();
    let mut save = |map: &HeightMap, p: &Path, what: &str| -> Result<(), AppError> {
        doe_file::save(map, p)?;
        let _ = writeln!(
            t,
            "wrote {} ({what}, {} µm pitch, {n}×{n})",
            p.display(),
            map.pitch_m * 1e6,
            n = map.samples
        );
        Ok(())
    };
    if let Some(p) = write_init {
        save(
            &HeightMap::three_lens_init(&calib, calib.doe_design_pitch_m),
            p,
            "three-lens DOE",
        )?;
    }
    let sim = Simulator::new(
        calib,
        common.doe_path(),
        nedrt_optics::cache::PsfCache::disabled(),
    )?;
    let map = &sim.doe;
    if let Some(p) = write_fabrication {
        save(
            &map.resampled(sim.calib.doe_fabrication_pitch_m),
            p,
            "bicubic to the fabrication pitch",
        )?;
    }
    // A radial profile is drawn as the 2-D map it describes.
    let as_map;
    let map = if map.profile == nedrt_optics::Profile::Radial {
        as_map = map.to_map(map.pitch_m, sim.calib.aperture_radius_m);
        &as_map
    } else {
        map
    };
    create_dir(out_dir)?;
    let n = map.samples;
    let (lo, hi) = map
        .height_m
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
    // Area-average to at most 500×500 cells for the picture.
    let cells = n.min(500);
    let colors: Vec<Vec<RGBColor>> = (0..cells)
        .map(|r| {
            (0..cells)
                .map(|c| {
                    let (y0, y1) = (r * n / cells, ((r + 1) * n / cells).max(r * n / cells + 1));
                    let (x0, x1) = (c * n / cells, ((c + 1) * n / cells).max(c * n / cells + 1));
                    let mut acc = 0.0;
                    for y in y0..y1 {
                        for x in x0..x1 {
                            acc += map.height_m[y * n + x];
                        }
                    }
                    viridis(acc / ((y1 - y0) * (x1 - x0)) as f64 / map.max_height_m)
                })
                .collect()
        })
        .collect();
    let half_mm = map.coord_m(n - 1) * 1e3;
    let panel = Panel::Heat(HeatPanel {
        title: format!("height map (0 … {:.2} µm, viridis)", map.max_height_m * 1e6),
        x_label: "s (mm)".into(),
        y_label: "t (mm)".into(),
        x_range: (-half_mm, half_mm),
        y_range: (-half_mm, half_mm),
        colors: colors.into_iter().rev().collect(),
    });
    let written = write_figure(
        &out_dir.join("doe_height_map"),
        (1, 1),
        (640, 640),
        &[panel],
        false,
    )?;
    let mut csv = String::from("s_mm,height_um_row,height_um_column\n");
    let mid = n / 2;
    for i in 0..n {
        let _ = writeln!(
            csv,
            "{:.4},{:.5},{:.5}",
            map.coord_m(i) * 1e3,
            map.height_m[mid * n + i] * 1e6,
            map.height_m[i * n + mid] * 1e6
        );
    }
    let csv_path = out_dir.join("doe_cross_sections.csv");
    write_text(&csv_path, &csv)?;
    let _ = writeln!(
        t,
        "DOE {} ({}): {n}×{n} at {:.3} µm, heights {:.3}–{:.3} µm of max {:.3} µm, levels {}, material {}",
        sim.doe_hash,
        map.description,
        map.pitch_m * 1e6,
        lo * 1e6,
        hi * 1e6,
        map.max_height_m * 1e6,
        if map.levels == 0 {
            "continuous".to_string()
        } else {
            map.levels.to_string()
        },
        map.material
    );
    let _ = writeln!(t, "wrote {} and {}", written.join(", "), csv_path.display());
    Ok(t)
}

/// `nedrt calib`: the resolved calibration and derived quantities.
pub fn calib_summary(common: &CommonOptions) -> Result<String, AppError> {
    let c = common.calibration()?;
    let mut t = format!("calibration {}\n", c.source);
    let _ = writeln!(
        t,
        "retinal step Δθ = {:.4} arcmin ({:.4e} rad); one DOE wave at λ0 = {:.4} µm",
        c.retinal_step_rad().to_degrees() * 60.0,
        c.retinal_step_rad(),
        c.doe_wave_height_m() * 1e6
    );
    for (i, ch) in c.channels.iter().enumerate() {
        let _ = writeln!(
            t,
            "{}: λ = {:.1} nm, n = {}, f = {:.4} mm, V = {:.4} D, Ψ(0 D) = {:.1}, Ψ(3 D) = {:.1} rad",
            ch.name,
            ch.wavelength_m * 1e9,
            ch.index,
            c.focal_length_m(i) * 1e3,
            c.vergence_d(i),
            c.psi_rad(i, 0.0),
            c.psi_rad(i, 3.0)
        );
    }
    let p = &c.panel;
    let _ = writeln!(
        t,
        "panel {}×{} px at {} Hz ({:.2} ms per refresh), {:.2} × {:.2} mm at {} µm pitch, transfer γ = {:?}",
        p.width_px,
        p.height_px,
        p.refresh_hz,
        1e3 / p.refresh_hz,
        p.width_px as f64 * c.pixel_pitch_m * 1e3,
        p.height_px as f64 * c.pixel_pitch_m * 1e3,
        c.pixel_pitch_m * 1e6,
        p.transfer_gamma
    );
    let _ = writeln!(t, "eye: {}", c.eye_summary());
    let _ = writeln!(t, "optics fingerprint {}", c.optics_fingerprint());
    Ok(t)
}
