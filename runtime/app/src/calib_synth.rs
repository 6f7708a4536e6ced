//! `nedrt calib synth`: what a camera at the eye would photograph of the
//! calibration patterns through optics perturbed from the design, written
//! in the capture format (docs/calibration.md §4). A camera nobody fooled:
//! the captures go through `calib psfs` like a lab's, and the true PSFs
//! they were made from (`truth/`, a PSF bundle) say how close it came.
//!
//! With field zones, each dot is seen through the true PSFs of its zone
//! (piecewise constant over the field); the flat fields and the
//! checkerboard, which only normalise and register, through the whole
//! field's.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calib_capture::{Camera, Capture, CapturesManifest, Frame, MANIFEST, Noise};
use crate::calib_patterns::{Pattern, PatternsManifest};
use crate::{AppError, CommonOptions};
use nedrt_core::image::Image;
use nedrt_optics::perturb::Perturbation;
use nedrt_optics::pixel::pixel_response;
use nedrt_optics::psf::Psf;
use nedrt_optics::sim::perceive;

/// The folder of the true PSFs, inside the output.
pub const TRUTH_DIR: &str = "truth";
/// What `calib synth` was asked: `synth.toml` beside the captures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SynthRecord {
    pub calibration: String,
    pub perturbation: Perturbation,
    pub camera: Camera,
    pub seed: u64,
    /// Field zones, columns × rows: each dot seen through its zone's PSFs.
    #[serde(default = "one_zone")]
    pub field_zones: [usize; 2],
}

fn one_zone() -> [usize; 2] {
    [1, 1]
}

/// What to photograph and how.
#[derive(Debug, Clone)]
pub struct SynthOptions {
    pub patterns_dir: PathBuf,
    pub out: PathBuf,
    pub accommodations_d: Vec<f64>,
    pub perturbation: Perturbation,
    pub camera: Camera,
    pub seed: u64,
    /// Field zones (columns, rows); (1, 1): one PSF for the whole field.
    pub field_zones: (usize, usize),
}

/// Each capture's share of the sensor's full well at its brightest pixel.
const DOTS_FILL: f64 = 0.8;
const FIELD_FILL: f64 = 0.5;
const DARK_EXPOSURE_MS: f64 = 10.0;

/// Photographs the patterns; says what it wrote.
pub fn write(common: &CommonOptions, o: &SynthOptions) -> Result<String, AppError> {
    o.perturbation
        .check()
        .map_err(|e| AppError::option("the perturbation", e))?;
    check_camera(&o.camera)?;
    if o.accommodations_d.is_empty() {
        return Err(AppError::option("--accommodations", "give at least one"));
    }
    let patterns_path = o.patterns_dir.join("patterns.toml");
    let text = std::fs::read_to_string(&patterns_path)
        .map_err(|e| AppError::input(patterns_path.display(), e))?;
    let patterns: PatternsManifest =
        toml::from_str(&text).map_err(|e| AppError::input(patterns_path.display(), e.message()))?;
    let design = common.calibration()?;
    for &d in &o.accommodations_d {
        crate::check_accommodation_as(&design, d, "--accommodations")?;
    }
    let (w, h) = (design.panel.width_px, design.panel.height_px);
    if (patterns.panel.width_px, patterns.panel.height_px) != (w, h) {
        return Err(AppError::input(
            patterns_path.display(),
            format!(
                "patterns for a {}×{} panel; the calibration's is {w}×{h}",
                patterns.panel.width_px, patterns.panel.height_px
            ),
        ));
    }
    let mut truth = crate::calib_truth::true_psfs(
        common,
        &o.perturbation,
        &o.accommodations_d,
        "nedrt calib synth",
        o.field_zones,
    )?;
    let channels = truth.channels();
    let per_zone = truth.psfs.len();

    let staging = staging_dir(&o.out)?;
    let result = (|| -> Result<Vec<Capture>, AppError> {
        let mut streams = Noise::new(o.seed);
        let mut captures = Vec::new();
        let retina = (2 * w, 2 * h);
        let sensor = o.camera.sensor(retina.0, retina.1);
        common.progress().start(
            "captures",
            (o.accommodations_d.len() * patterns.pattern.len()) as u64,
        );
        for (a, &d) in o.accommodations_d.iter().enumerate() {
            let folder = format!("a{d:.2}");
            crate::create_dir(&staging.join(&folder))?;
            for p in &patterns.pattern {
                let seen = Truth {
                    whole: &truth.psfs[a * channels..(a + 1) * channels],
                    zones: (0..truth.zone_psfs.len() / per_zone.max(1))
                        .map(|z| {
                            let at = z * per_zone + a * channels;
                            &truth.zone_psfs[at..at + channels]
                        })
                        .collect(),
                    grid: o.field_zones,
                };
                let (plane, fill) = retinal_image(p, &patterns, &seen, &o.camera, w, h)?;
                let (frame, exposure_ms) =
                    photograph(plane, retina, sensor, &o.camera, fill, streams.next_u64());
                let file = format!("{folder}/{}", p.file);
                frame.write(&staging.join(&file))?;
                captures.push(Capture {
                    file,
                    pattern: p.file.clone(),
                    accommodation_d: d,
                    exposure_ms,
                    frames: o.camera.frames.max(1),
                });
                common.progress().advance(1);
            }
        }
        common.progress().finish();
        Ok(captures)
    })()
    .and_then(|captures| {
        let manifest = CapturesManifest {
            patterns: "patterns.toml".into(),
            bits: o.camera.bits,
            capture: captures,
        };
        let record = SynthRecord {
            calibration: design.source.clone(),
            perturbation: o.perturbation,
            camera: o.camera,
            seed: o.seed,
            field_zones: [o.field_zones.0, o.field_zones.1],
        };
        let ser = |e: toml::ser::Error| AppError::Internal(format!("the capture records: {e}"));
        crate::write_text(
            &staging.join(MANIFEST),
            &toml::to_string(&manifest).map_err(ser)?,
        )?;
        crate::write_text(
            &staging.join("synth.toml"),
            &toml::to_string(&record).map_err(ser)?,
        )?;
        crate::write_text(&staging.join("patterns.toml"), &text)?;
        truth
            .save(&staging.join(TRUTH_DIR))
            .map_err(|e| AppError::output(&staging, e))?;
        Ok(manifest.capture.len())
    })
    .and_then(|n| {
        if o.out.exists() {
            std::fs::remove_dir(&o.out).map_err(|e| {
                AppError::output(&o.out, format!("exists and is not an empty folder ({e})"))
            })?;
        }
        std::fs::rename(&staging, &o.out).map_err(|e| AppError::output(&o.out, e))?;
        Ok(n)
    });
    let n = match result {
        Ok(n) => n,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&staging);
            return Err(e);
        }
    };
    Ok(format!(
        "{n} captures of {} patterns at {} D through the display as built ({}) in {}; the true PSFs in {}\n",
        patterns.pattern.len(),
        o.accommodations_d
            .iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        o.perturbation.describe(),
        o.out.display(),
        o.out.join(TRUTH_DIR).display(),
    ))
}

/// A fresh sibling of `out` to write into; `out` itself must be new or an
/// empty folder, so that nothing of a user's is replaced.
fn staging_dir(out: &Path) -> Result<PathBuf, AppError> {
    if out.exists()
        && std::fs::read_dir(out)
            .map_err(|e| AppError::output(out, e))?
            .next()
            .is_some()
    {
        return Err(AppError::output(
            out,
            "exists and is not empty; give a new folder",
        ));
    }
    nedrt_core::util::staging_sibling(out).map_err(|e| AppError::output(out, e))
}

fn check_camera(c: &Camera) -> Result<(), AppError> {
    let bad = |f: &str, why: &str| Err(AppError::option(format!("camera {f}"), why));
    if !(c.pitch_cells.is_finite() && (0.2..=4.0).contains(&c.pitch_cells)) {
        return bad("pitch_cells", "must lie in [0.2, 4] retinal cells");
    }
    if !(1..=16).contains(&c.bits) {
        return bad("bits", "must lie in [1, 16]");
    }
    if c.frames == 0 || c.frames as u64 * ((1u64 << c.bits) - 1) > u16::MAX as u64 {
        return bad(
            "frames",
            "at least 1, and the sum of the frames must fit 16 bits",
        );
    }
    let max = ((1u32 << c.bits) - 1) as f64;
    if !(c.dark_dn >= 0.0 && c.dark_dn < max / 2.0) {
        return bad("dark_dn", "must lie in [0, half the largest value)");
    }
    if !(c.full_well_e > 0.0 && c.flux_e_per_ms > 0.0 && c.read_noise_e >= 0.0) {
        return bad(
            "full_well_e",
            "full well and flux must be positive, read noise not negative",
        );
    }
    if c.qe.iter().any(|q| !(*q > 0.0 && *q <= 1.0)) {
        return bad("qe", "each must lie in (0, 1]");
    }
    if !(c.rotation_deg.abs() <= 10.0
        && c.distortion_k1.abs() <= 0.05
        && (0.0..=0.5).contains(&c.field_margin))
    {
        return bad(
            "rotation_deg",
            "rotation within ±10°, |k1| ≤ 0.05, margin in [0, 0.5]",
        );
    }
    Ok(())
}

/// The true PSFs at one accommodation, per channel: the whole field's,
/// and each field zone's (row by row; none without zones).
struct Truth<'a> {
    whole: &'a [Psf],
    zones: Vec<&'a [Psf]>,
    grid: (usize, usize),
}

impl Truth<'_> {
    /// The zone of panel pixel (`x`, `y`) of a `w`×`h` panel (0 without zones).
    fn zone(&self, x: usize, y: usize, w: usize, h: usize) -> usize {
        if self.zones.is_empty() {
            return 0;
        }
        nedrt_optics::bundle::zone_at(self.grid, (w, h), x as f64, y as f64)
    }
}

/// The retinal irradiance of a pattern (a full-white pixel of one primary
/// is 1 on each of its cells), weighted by the camera's QE for each
/// primary, and how full the brightest pixel is to be.
fn retinal_image(
    p: &Pattern,
    patterns: &PatternsManifest,
    truth: &Truth,
    camera: &Camera,
    w: usize,
    h: usize,
) -> Result<(Vec<f32>, f64), AppError> {
    let psfs = truth.whole;
    let (rw, rh) = (2 * w, 2 * h);
    let channel = |c: Option<usize>| {
        c.filter(|c| *c < psfs.len().min(3))
            .ok_or_else(|| AppError::input(&p.file, "a pattern without a valid channel"))
    };
    match p.kind.as_str() {
        "dots" => {
            let c = channel(p.channel)?;
            let (origin, cols, rows) = match (p.origin_px, p.columns, p.rows) {
                (Some(o), Some(c), Some(r)) => (o, c, r),
                _ => return Err(AppError::input(&p.file, "a dot pattern without its grid")),
            };
            let spacing = patterns.dots.spacing_px;
            // Each zone's pixel response, once (the whole field's without zones).
            let responses: Vec<(usize, Vec<f64>)> = if truth.zones.is_empty() {
                vec![pixel_response(&psfs[c])]
            } else {
                truth.zones.iter().map(|z| pixel_response(&z[c])).collect()
            };
            let r = (psfs[c].window / 2) as isize;
            let veil = psfs[c].veil * (cols * rows) as f64 / (w * h) as f64;
            let mut plane = vec![(veil * camera.qe[c]) as f32; rw * rh];
            for j in 0..rows {
                for i in 0..cols {
                    let (px, py) = (origin[0] + i * spacing, origin[1] + j * spacing);
                    let (m, g) = &responses[truth.zone(px, py, w, h)];
                    let m = *m;
                    for ky in 0..m {
                        let y = 2 * py as isize + ky as isize - r;
                        if y < 0 || y >= rh as isize {
                            continue;
                        }
                        for kx in 0..m {
                            let x = 2 * px as isize + kx as isize - r;
                            if x >= 0 && x < rw as isize {
                                plane[y as usize * rw + x as usize] +=
                                    (g[ky * m + kx] * camera.qe[c]) as f32;
                            }
                        }
                    }
                }
            }
            Ok((plane, DOTS_FILL))
        }
        "flat" => {
            let c = channel(p.channel)?;
            let ones = Image::from_planes(w, h, vec![vec![1.0f32; w * h]]);
            let seen = perceive(&ones, std::slice::from_ref(&psfs[c]));
            let qe = camera.qe[c] as f32;
            Ok((
                seen.planes()
                    .next()
                    .unwrap_or(&[])
                    .iter()
                    .map(|v| v * qe)
                    .collect(),
                FIELD_FILL,
            ))
        }
        "checkerboard" => {
            let q = p.square_px.unwrap_or(1).max(1);
            let board: Vec<f32> = (0..w * h)
                .map(|i| (i % w / q + i / w / q).is_multiple_of(2) as u8 as f32)
                .collect();
            let img = Image::from_planes(w, h, vec![board; 3]);
            let seen = perceive(&img, &psfs[..3]);
            let mut plane = vec![0.0f32; rw * rh];
            for (c, pl) in seen.planes().enumerate() {
                let qe = camera.qe[c] as f32;
                plane.iter_mut().zip(pl).for_each(|(o, v)| *o += qe * v);
            }
            Ok((plane, FIELD_FILL))
        }
        "dark" => Ok((vec![0.0; rw * rh], 0.0)),
        other => Err(AppError::input(
            &p.file,
            format!("unknown pattern kind {other:?}"),
        )),
    }
}

/// The camera's frame of a retinal image, exposed so that its brightest
/// pixel fills `fill` of the full well (a dark frame: a fixed exposure),
/// and that exposure (ms, to the microsecond).
fn photograph(
    plane: Vec<f32>,
    retina: (usize, usize),
    sensor: (usize, usize),
    cam: &Camera,
    fill: f64,
    seed: u64,
) -> (Frame, f64) {
    // The retinal image sampled as a camera frame is (bilinear, 0 outside).
    let retinal = Frame {
        width: retina.0,
        height: retina.1,
        values: plane,
    };
    let sample = |u: usize, v: usize| {
        let (x, y) = cam.to_retina(u as f64, v as f64, sensor, retina);
        retinal.sample(x, y)
    };
    let irradiance: Vec<f64> = (0..sensor.0 * sensor.1)
        .into_par_iter()
        .map(|i| sample(i % sensor.0, i / sensor.0))
        .collect();
    let peak = irradiance.iter().cloned().fold(0.0, f64::max);
    let exposure_ms = if fill > 0.0 && peak > 0.0 {
        ((fill * cam.full_well_e / (peak * cam.flux_e_per_ms)) * 1000.0)
            .round()
            .max(1.0)
            / 1000.0
    } else {
        DARK_EXPOSURE_MS
    };
    let max = ((1u32 << cam.bits) - 1) as f64;
    let gain = cam.full_well_e / max;
    let n = cam.frames.max(1) as f64;
    let mut frame = Frame::new(sensor.0, sensor.1);
    // The sum of n frames: shot noise of the summed electrons, read noise
    // and each frame's rounding (1/12 DN² a frame) added n times. Each row
    // draws from its own stream, so that rows run in parallel and the
    // frame is the same whatever the threads.
    frame
        .values
        .par_chunks_mut(sensor.0)
        .zip(irradiance.par_chunks(sensor.0))
        .enumerate()
        .for_each(|(row, (out, e))| {
            let mut noise = Noise::new(seed ^ (row as u64 + 1).wrapping_mul(0xA076_1D64_78BD_642F));
            for (o, e) in out.iter_mut().zip(e) {
                let electrons = noise.poisson(n * e * cam.flux_e_per_ms * exposure_ms)
                    + cam.read_noise_e * n.sqrt() * noise.normal();
                let dn = n * cam.dark_dn + electrons / gain + (n / 12.0).sqrt() * noise.normal();
                *o = dn.round().clamp(0.0, n * max) as f32;
            }
        });
    (frame, exposure_ms)
}
