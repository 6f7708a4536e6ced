//! `nedrt calib psfs`: from the captures of a built display to its PSF
//! bundle (docs/calibration.md §3). Per accommodation and channel: the dark
//! frame subtracted, each dot divided by its channel's flat field there
//! (which makes a full-white pixel 1 on every retinal cell, so the dot's
//! light is measured against the whole pixel's), every dot cut out at the
//! place the camera-to-panel registration gives it (not its own centroid:
//! the DOE's orders keep their offsets), its background removed, the dots
//! averaged, a noise floor, and the 2×2 pixel divided out. With field
//! zones, the dots of each zone (by their place on the panel) make that
//! zone's PSFs as well, and all of them the whole field's.

use std::collections::BTreeMap;
use std::path::Path;

use crate::calib_capture::{Capture, Captures, Frame};
use crate::calib_fit::{Samples, fit_response, gather, response_to_psf};
use crate::calib_patterns::Pattern;
use crate::calib_register::{Homography, from_flat, saddle};
use crate::{AppError, CommonOptions};
use nedrt_optics::bundle::{Measurement, PsfBundle};

/// The largest registration residual accepted (RMS over the corners,
/// panel pixels): beyond it the map is wrong, not just imprecise.
pub const MAX_REGISTRATION_RMS_PX: f64 = 0.25;
/// A pixel whose mean over the summed frames reaches this share of the
/// full scale is taken as saturated.
pub const SATURATED_SHARE: f32 = 0.98;

/// `--field-zones` checked: a grid a bundle can hold.
pub(crate) fn check_zones((nx, ny): (usize, usize)) -> Result<(), AppError> {
    if nedrt_optics::bundle::zones_valid(nx, ny) {
        return Ok(());
    }
    Err(AppError::option(
        "--field-zones",
        format!(
            "{nx}×{ny}: give 1 to {} zones in all",
            nedrt_optics::bundle::MAX_ZONES
        ),
    ))
}

/// A frame minus the dark frame, per ms of exposure.
fn rate(frame: &Frame, dark: &Frame, exposure_ms: f64) -> Frame {
    let mut f = frame.clone();
    f.values
        .iter_mut()
        .zip(&dark.values)
        .for_each(|(v, d)| *v = (*v - d) / exposure_ms as f32);
    f
}

/// Reads captures lazily, checking that every frame has one size.
struct Reader<'a> {
    caps: &'a Captures,
    size: Option<(usize, usize, String)>,
}

impl Reader<'_> {
    fn read(&mut self, capture: &Capture) -> Result<Frame, AppError> {
        let file = &capture.file;
        let path = self.caps.dir.join(file);
        let f = Frame::read(&path, self.caps.manifest.bits, capture.frames)?;
        match &self.size {
            Some((w, h, first)) if (*w, *h) != (f.width, f.height) => Err(AppError::input(
                path.display(),
                format!(
                    "a {}×{} capture; {first} is {w}×{h} (every capture comes from one camera)",
                    f.width, f.height
                ),
            )),
            Some(_) => Ok(f),
            None => {
                self.size = Some((f.width, f.height, file.to_string()));
                Ok(f)
            }
        }
    }
}

/// Turns the captures in `dir` into a PSF bundle at `out`, with
/// `zones` (columns, rows) of the field besides the whole field's PSFs
/// where that is not (1, 1); says what it did.
pub fn write(
    common: &CommonOptions,
    dir: &Path,
    out: &Path,
    zones: (usize, usize),
) -> Result<String, AppError> {
    check_zones(zones)?;
    let (nx, ny) = zones;
    let zoned = (nx, ny) != (1, 1);
    let caps = Captures::load(dir)?;
    let calib = common.calibration()?;
    let manifest_path = dir.join(crate::calib_capture::MANIFEST);
    let pats = &caps.patterns;
    let (w, h) = (pats.panel.width_px, pats.panel.height_px);
    if (calib.panel.width_px, calib.panel.height_px) != (w, h) {
        return Err(AppError::input(
            &caps.manifest.patterns,
            format!(
                "patterns for a {w}×{h} panel; the calibration's is {}×{}",
                calib.panel.width_px, calib.panel.height_px
            ),
        ));
    }
    // Accommodation (µD) → pattern file → capture index.
    let mut by_depth: BTreeMap<i64, BTreeMap<String, usize>> = BTreeMap::new();
    for (i, c) in caps.manifest.capture.iter().enumerate() {
        let key = (c.accommodation_d * 1e6).round() as i64;
        if by_depth
            .entry(key)
            .or_default()
            .insert(c.pattern.clone(), i)
            .is_some()
        {
            return Err(AppError::input(
                manifest_path.display(),
                format!("two captures of {} at {} D", c.pattern, c.accommodation_d),
            ));
        }
    }
    let channels = 3usize.min(calib.channels.len());
    let needed: Vec<&Pattern> = pats
        .pattern
        .iter()
        .filter(|p| p.kind != "checkerboard")
        .collect();
    for (key, set) in &by_depth {
        for p in &needed {
            if !set.contains_key(&p.file) {
                return Err(AppError::input(
                    manifest_path.display(),
                    format!(
                        "no capture of {} at {} D (each accommodation needs the dark field, every flat \
                         field and every dot pattern)",
                        p.file,
                        *key as f64 / 1e6
                    ),
                ));
            }
        }
    }
    let mut reader = Reader {
        caps: &caps,
        size: None,
    };
    let (reg, model_note) = register(
        &caps,
        &by_depth,
        &mut reader,
        calib.design_channel.min(channels - 1),
    )?;
    let inverse = reg
        .inverse()
        .ok_or_else(|| AppError::Internal("a registration without an inverse".into()))?;
    let spacing = pats.dots.spacing_px;
    let half = spacing.saturating_sub(1).max(2);
    let m = 2 * half + 2;
    // Summed frames hide a frame's clipping; a mean this near full scale
    // has clipped in some.
    let saturated = SATURATED_SHARE * ((1u32 << caps.manifest.bits) - 1) as f32;
    let mut psfs = Vec::new();
    // [zone][accommodation × channel], as the bundle's zone_psfs.
    let mut zone_psfs: Vec<Vec<nedrt_optics::psf::Psf>> = vec![Vec::new(); nx * ny];
    let mut floors = Vec::new();
    let mut dots_per_channel = vec![0usize; channels];
    common
        .progress()
        .start("PSFs", (by_depth.len() * channels) as u64);
    for set in by_depth.values() {
        let cap = |file: &str| &caps.manifest.capture[set[file]];
        let dark_file = &needed
            .iter()
            .find(|p| p.kind == "dark")
            .ok_or_else(|| {
                AppError::input(&caps.manifest.patterns, "no dark field among the patterns")
            })?
            .file;
        let dark = reader.read(cap(dark_file))?;
        let mut floor_row = Vec::new();
        #[allow(clippy::needless_range_loop)] // c names the channel in patterns and errors
        for c in 0..channels {
            let flat_pattern = needed
                .iter()
                .find(|p| p.kind == "flat" && p.channel == Some(c))
                .ok_or_else(|| {
                    AppError::input(
                        &caps.manifest.patterns,
                        format!("no flat field of channel {c}"),
                    )
                })?;
            let fc = cap(&flat_pattern.file);
            let flat = rate(&reader.read(fc)?, &dark, fc.exposure_ms);
            let mut samples: Vec<Samples> = (0..nx * ny).map(|_| Samples::new(half)).collect();
            let mut count = 0usize;
            for p in needed
                .iter()
                .filter(|p| p.kind == "dots" && p.channel == Some(c))
            {
                let dc = cap(&p.file);
                let raw = reader.read(dc)?;
                let frame = rate(&raw, &dark, dc.exposure_ms);
                let (origin, cols, rows) = match (p.origin_px, p.columns, p.rows) {
                    (Some(o), Some(c), Some(r)) => (o, c, r),
                    _ => return Err(AppError::input(&p.file, "a dot pattern without its grid")),
                };
                for j in 0..rows {
                    for i in 0..cols {
                        let (px, py) = (
                            (origin[0] + i * spacing) as f64,
                            (origin[1] + j * spacing) as f64,
                        );
                        let (u, v) = reg.apply(px, py);
                        let path = || caps.dir.join(&dc.file).display().to_string();
                        if u < 0.0 || v < 0.0 || u >= raw.width as f64 || v >= raw.height as f64 {
                            return Err(AppError::input(
                                path(),
                                format!("the dot at panel ({px}, {py}) lies outside the frame"),
                            ));
                        }
                        let peak_r = 4.0f64;
                        let saturated_here = (-peak_r as isize..=peak_r as isize).any(|dy| {
                            (-peak_r as isize..=peak_r as isize).any(|dx| {
                                let (x, y) = (u.round() as isize + dx, v.round() as isize + dy);
                                x >= 0
                                    && y >= 0
                                    && (x as usize) < raw.width
                                    && (y as usize) < raw.height
                                    && raw.values[y as usize * raw.width + x as usize] >= saturated
                            })
                        });
                        if saturated_here {
                            return Err(AppError::input(
                                path(),
                                format!(
                                    "the dot at panel ({px}, {py}) is saturated; shorten the exposure"
                                ),
                            ));
                        }
                        let level = flat.local_mean(u, v, 3);
                        if level.is_nan() || level <= 0.0 {
                            return Err(AppError::input(
                                caps.dir.join(&fc.file).display().to_string(),
                                format!(
                                    "no light at the dot at panel ({px}, {py}); is this the flat field of channel {c}?"
                                ),
                            ));
                        }
                        gather(
                            &frame,
                            &reg,
                            &inverse,
                            (px, py),
                            level,
                            &mut samples[nedrt_optics::bundle::zone_at(zones, (w, h), px, py)],
                        );
                        count += 1;
                    }
                }
            }
            dots_per_channel[c] = count;
            if zoned {
                for (z, s) in samples.iter().enumerate() {
                    if s.dots() == 0 {
                        return Err(AppError::option(
                            "--field-zones",
                            format!(
                                "{nx}×{ny}: zone ({}, {}) holds no dot of channel {c}; give fewer \
                                 zones, or patterns with more dots (calib patterns --margin)",
                                z % nx,
                                z / nx
                            ),
                        ));
                    }
                    zone_psfs[z].push(response_to_psf(m, fit_response(s)).0);
                }
            }
            let mut whole = samples.swap_remove(0);
            samples.iter().for_each(|s| whole.absorb(s));
            let (cells, floor) = response_to_psf(m, fit_response(&whole));
            floor_row.push(floor);
            psfs.push(cells);
            common.progress().advance(1);
        }
        floors.push(floor_row);
    }
    common.progress().finish();
    let accommodations: Vec<f64> = by_depth.keys().map(|k| *k as f64 / 1e6).collect();
    let wavelengths: Vec<f64> = (0..channels)
        .map(|c| {
            pats.pattern
                .iter()
                .find(|p| p.channel == Some(c))
                .and_then(|p| p.wavelength_nm)
                .unwrap_or(calib.channels[c].wavelength_m * 1e9)
        })
        .collect();
    let capture_hashes = caps
        .manifest
        .capture
        .iter()
        .map(|c| {
            let bytes = std::fs::read(caps.dir.join(&c.file))
                .map_err(|e| AppError::input(caps.dir.join(&c.file).display(), e))?;
            Ok([c.file.clone(), blake3::hash(&bytes).to_hex().to_string()])
        })
        .collect::<Result<Vec<_>, AppError>>()?;
    let measurement = Measurement {
        captures: dir.display().to_string(),
        manifest_blake3: caps.manifest_blake3.clone(),
        registration_capture: model_note.capture.clone(),
        registration_model: "homography (panel edges, then checkerboard corners)".into(),
        registration_points: model_note.points,
        registration_rms_px: model_note.rms_px,
        registration_max_px: model_note.max_px,
        dots_per_channel: dots_per_channel.clone(),
        noise_floor: floors.clone(),
        capture_hashes,
    };
    let mut bundle = PsfBundle::new(
        "nedrt calib psfs",
        accommodations.clone(),
        wavelengths,
        psfs,
        Some(measurement),
    )
    .and_then(|b| match zoned {
        true => b.with_zones(nx, ny, zone_psfs.concat()),
        false => Ok(b),
    })
    .map_err(|e| AppError::Internal(e.to_string()))?;
    bundle.save(out).map_err(|e| AppError::output(out, e))?;
    Ok(format!(
        "PSF bundle {}: {} accommodations ({} D) × {channels} channels, {}×{} cells{}; {} dots a channel; \
         registration from {}: {} corners, residual {:.3} px RMS, {:.3} px at most\n",
        out.display(),
        accommodations.len(),
        accommodations
            .iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        2 * half + 1,
        2 * half + 1,
        if zoned {
            format!(", and in {nx}×{ny} field zones")
        } else {
            String::new()
        },
        dots_per_channel
            .iter()
            .map(|n| n.to_string())
            .collect::<Vec<_>>()
            .join("/"),
        model_note.capture,
        model_note.points,
        model_note.rms_px,
        model_note.max_px,
    ))
}

/// What the registration used and how well it fits.
struct RegistrationNote {
    capture: String,
    points: usize,
    rms_px: f64,
    max_px: f64,
}

/// The homography from panel pixels to camera pixels: from the sharpest
/// checkerboard capture, seeded by the panel's edges in the flat field of
/// `channel` at the same accommodation.
fn register(
    caps: &Captures,
    by_depth: &BTreeMap<i64, BTreeMap<String, usize>>,
    reader: &mut Reader,
    channel: usize,
) -> Result<(Homography, RegistrationNote), AppError> {
    let pats = &caps.patterns;
    let board = pats
        .pattern
        .iter()
        .find(|p| p.kind == "checkerboard")
        .ok_or_else(|| {
            AppError::input(
                &caps.manifest.patterns,
                "no checkerboard among the patterns",
            )
        })?;
    let flat = pats
        .pattern
        .iter()
        .find(|p| p.kind == "flat" && p.channel == Some(channel))
        .ok_or_else(|| {
            AppError::input(
                &caps.manifest.patterns,
                "no flat field for the registration",
            )
        })?;
    let dark = pats
        .pattern
        .iter()
        .find(|p| p.kind == "dark")
        .map(|p| p.file.clone())
        .unwrap_or_default();
    let mut best: Option<(f64, Frame, i64)> = None;
    for (key, set) in by_depth {
        let Some(&i) = set.get(&board.file) else {
            continue;
        };
        let c = &caps.manifest.capture[i];
        let d = reader.read(&caps.manifest.capture[set[&dark]])?;
        let f = rate(&reader.read(c)?, &d, c.exposure_ms);
        let s = sharpness(&f);
        if best.as_ref().is_none_or(|b| s > b.0) {
            best = Some((s, f, *key));
        }
    }
    let manifest_path = caps.dir.join(crate::calib_capture::MANIFEST);
    let (_, frame, key) = best.ok_or_else(|| {
        AppError::input(
            manifest_path.display(),
            format!("no capture of the checkerboard {}", board.file),
        )
    })?;
    let set = &by_depth[&key];
    let board_file = caps.manifest.capture[set[&board.file]].file.clone();
    let fail = |why: String| {
        AppError::input(
            caps.dir.join(&board_file).display(),
            format!("registration failed: {why}"),
        )
    };
    let fc = &caps.manifest.capture[set[&flat.file]];
    let d = reader.read(&caps.manifest.capture[set[&dark]])?;
    let flat_frame = rate(&reader.read(fc)?, &d, fc.exposure_ms);
    let (w, h) = (pats.panel.width_px, pats.panel.height_px);
    let coarse = from_flat(&flat_frame, w, h)
        .ok_or_else(|| fail(format!("the panel's edges are not all inside {}", fc.file)))?;
    let q = board.square_px.unwrap_or(0);
    if q < 2 {
        return Err(fail("the checkerboard has no square_px".into()));
    }
    let (a, b) = (coarse.apply(0.0, 0.0), coarse.apply(q as f64, 0.0));
    let scale = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt() / q as f64;
    let r = ((0.3 * q as f64 * scale).round() as usize).max(3);
    let mut panel = Vec::new();
    let mut camera = Vec::new();
    let mut wanted = 0;
    for j in 1.. {
        if j * q >= h {
            break;
        }
        for i in 1.. {
            if i * q >= w {
                break;
            }
            wanted += 1;
            let (x, y) = ((i * q) as f64 - 0.5, (j * q) as f64 - 0.5);
            let (u, v) = coarse.apply(x, y);
            if let Some(found) = saddle(&frame, u, v, r) {
                panel.push((x, y));
                camera.push(found);
            }
        }
    }
    if panel.len() < 8 || panel.len() * 2 < wanted {
        return Err(fail(format!(
            "{} of {wanted} checkerboard corners found",
            panel.len()
        )));
    }
    let mut fit =
        Homography::fit(&panel, &camera).ok_or_else(|| fail("the corners lie on a line".into()))?;
    // One pass without the outliers (a corner caught by dust or a dead pixel).
    let residuals =
        |fit: &Homography, panel: &[(f64, f64)], camera: &[(f64, f64)]| -> Option<Vec<f64>> {
            let inv = fit.inverse()?;
            Some(
                panel
                    .iter()
                    .zip(camera)
                    .map(|(p, c)| {
                        let (x, y) = inv.apply(c.0, c.1);
                        ((x - p.0).powi(2) + (y - p.1).powi(2)).sqrt()
                    })
                    .collect(),
            )
        };
    let res = residuals(&fit, &panel, &camera).ok_or_else(|| fail("a singular map".into()))?;
    let mut sorted = res.clone();
    sorted.sort_by(f64::total_cmp);
    let limit = 3.0 * sorted[sorted.len() / 2] + 0.05;
    let keep: Vec<usize> = (0..res.len()).filter(|&i| res[i] <= limit).collect();
    if keep.len() >= 8 && keep.len() < res.len() {
        let p: Vec<_> = keep.iter().map(|&i| panel[i]).collect();
        let c: Vec<_> = keep.iter().map(|&i| camera[i]).collect();
        if let Some(f) = Homography::fit(&p, &c) {
            fit = f;
            panel = p;
            camera = c;
        }
    }
    let res = residuals(&fit, &panel, &camera).ok_or_else(|| fail("a singular map".into()))?;
    let rms = (res.iter().map(|r| r * r).sum::<f64>() / res.len() as f64).sqrt();
    let max = res.iter().cloned().fold(0.0, f64::max);
    if rms > MAX_REGISTRATION_RMS_PX {
        return Err(fail(format!(
            "the corners fit a homography to {rms:.3} panel pixels RMS, more than {MAX_REGISTRATION_RMS_PX}"
        )));
    }
    Ok((
        fit,
        RegistrationNote {
            capture: board_file,
            points: panel.len(),
            rms_px: rms,
            max_px: max,
        },
    ))
}

/// Mean gradient over mean level: the sharpest checkerboard has the most.
fn sharpness(f: &Frame) -> f64 {
    let w = f.width;
    let (mut grad, mut level) = (0.0f64, 0.0f64);
    for y in 0..f.height.saturating_sub(1) {
        for x in 0..w.saturating_sub(1) {
            let v = f.values[y * w + x] as f64;
            grad += (f.values[y * w + x + 1] as f64 - v).abs()
                + (f.values[(y + 1) * w + x] as f64 - v).abs();
            level += v.abs();
        }
    }
    grad / level.max(1e-30)
}
