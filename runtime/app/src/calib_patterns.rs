//! `nedrt calib patterns`: what a lab shows on the built display to
//! calibrate it from camera captures (docs/calibration.md). Per colour
//! channel a grid of single lit pixels, far enough apart that their PSFs
//! never overlap at any accommodation of the calibrated range; a
//! checkerboard that registers camera pixels to panel pixels; flat and dark
//! fields; and `patterns.toml`, which names each image.

use std::path::Path;

use nedrt_optics::psf::Psf;
use nedrt_optics::sim::Method;
use serde::{Deserialize, Serialize};

use crate::{AppError, CommonOptions};

/// The share of a PSF's light (its cells, the veil aside) inside the
/// radius the dot spacing is built on. The DOE's PSFs have long tails
/// (docs/calibration.md has their radii at 90, 99 and 99.9 %). At 99 % the
/// 1 % beyond is spread thinly over a neighbour's window, where the
/// extraction's background removal takes it out.
pub const ENERGY_SHARE: f64 = 0.99;

/// `patterns.toml`: the panel, the dot grid, and each image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PatternsManifest {
    pub panel: PanelInfo,
    pub dots: DotGrid,
    pub pattern: Vec<Pattern>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PanelInfo {
    pub width_px: usize,
    pub height_px: usize,
    pub pixel_pitch_um: f64,
    /// The calibration the patterns were made for (its file).
    pub calibration: String,
}

/// What every dot pattern shares: its lit pixels are `spacing_px` apart
/// (each pattern gives its grid's first pixel and size), and the grid is
/// shifted by a `shifts`-th of the spacing across and down between the
/// patterns of a channel, so that together they sample the field more
/// densely than one grid can.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DotGrid {
    pub spacing_px: usize,
    pub shifts: usize,
    /// The design PSF's radius holding `ENERGY_SHARE` of its light, the
    /// largest over the accommodations in `depths_d` and the channels, in
    /// panel pixels.
    pub psf_radius_px: f64,
    /// The room left for the built optics: dots are 2 × margin × radius
    /// apart, and margin × radius from the panel's edges.
    pub margin: f64,
    pub depths_d: Vec<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pattern {
    pub file: String,
    /// `dots`, `checkerboard`, `flat` or `dark`.
    pub kind: String,
    /// The lit channel of a dot pattern (the calibration's order).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channel: Option<usize>,
    /// A dot pattern's first lit pixel, and how many columns and rows of
    /// dots follow, `spacing_px` apart.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub origin_px: Option<[usize; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub columns: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rows: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wavelength_nm: Option<f64>,
    /// A checkerboard's square; its first square (top left) is lit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub square_px: Option<usize>,
}

/// The radius, in the PSF's cells from its window's centre, inside which
/// `share` of its cells' light lies.
pub fn energy_radius_cells(psf: &Psf, share: f64) -> f64 {
    let n = psf.window;
    let c = (n as f64 - 1.0) / 2.0;
    let mut by_radius: Vec<(f64, f64)> = psf
        .cells
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            let (x, y) = ((i % n) as f64 - c, (i / n) as f64 - c);
            ((x * x + y * y).sqrt(), v.max(0.0))
        })
        .collect();
    by_radius.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = by_radius.iter().map(|&(_, v)| v).sum();
    let mut inside = 0.0;
    for (r, v) in by_radius {
        inside += v;
        if inside >= share * total {
            return r;
        }
    }
    c * std::f64::consts::SQRT_2
}

/// One shifted dot grid: its shift (across, down), first dot, columns, rows.
pub type Grid = ([usize; 2], [usize; 2], usize, usize);

/// The dot grids on a `width`×`height` panel for PSFs of radius
/// `radius_px`: the spacing, and for each of the `shifts`² shifts (across,
/// down) the first dot and the columns and rows, dots at least
/// margin × radius from every edge. None if no dot fits.
pub fn dot_grids(
    width: usize,
    height: usize,
    radius_px: f64,
    margin: f64,
    shifts: usize,
) -> Option<(usize, Vec<Grid>)> {
    let room = (margin * radius_px).ceil() as usize;
    let spacing = ((2.0 * margin * radius_px).ceil() as usize + 1).max(2);
    let fit = |len: usize, first: usize| {
        (len > first + room).then(|| (len - 1 - room - first) / spacing + 1)
    };
    let mut grids = Vec::new();
    for sy in 0..shifts {
        for sx in 0..shifts {
            let first = [room + sx * spacing / shifts, room + sy * spacing / shifts];
            if let (Some(columns), Some(rows)) = (fit(width, first[0]), fit(height, first[1])) {
                grids.push(([sx, sy], first, columns, rows));
            }
        }
    }
    (!grids.is_empty() && grids[0].1 == [room, room]).then_some((spacing, grids))
}

/// Writes the patterns into `out_dir` and says what it wrote. The design
/// PSFs are computed first: a refused request leaves no folder behind.
pub fn write(
    common: &CommonOptions,
    out_dir: &Path,
    margin: f64,
    shifts: usize,
) -> Result<String, AppError> {
    if !(margin.is_finite() && margin >= 1.0) {
        return Err(AppError::option(
            format!("--margin {margin}"),
            "must be at least 1 (dots 2 × margin × the PSF's radius apart)",
        ));
    }
    if !(1..=8).contains(&shifts) {
        return Err(AppError::option(
            format!("--shifts {shifts}"),
            "must lie in [1, 8] (shifted grids across and down, each a pattern a channel)",
        ));
    }
    let calib = common.calibration()?;
    let [lo, hi] = calib.range_d;
    let depths_d = vec![lo, (lo + hi) / 2.0, hi];
    // The largest radius over the depths and channels at each share, the
    // spacing's (ENERGY_SHARE) among them; the others are reported.
    let shares = [0.9, ENERGY_SHARE, 0.999];
    let mut radii_px = [0.0f64; 3];
    let (at, _) =
        crate::frames::psfs_at(common, Method::DoeWiener, &depths_d, "the calibrated range")?;
    for psfs in &at {
        for psf in psfs {
            for (r, &share) in radii_px.iter_mut().zip(&shares) {
                // A display pixel is 2×2 retinal cells.
                *r = r.max(energy_radius_cells(psf, share) / 2.0);
            }
        }
    }
    let radius_px = radii_px[1];
    let (w, h) = (calib.panel.width_px, calib.panel.height_px);
    let (spacing, grids) = dot_grids(w, h, radius_px, margin, shifts).ok_or_else(|| {
        AppError::input(
            &calib.source,
            format!(
                "the {w}×{h} panel holds no dot: a dot needs {:.0} px of room each side \
                 (the design PSF's radius {radius_px:.1} px × margin {margin})",
                (margin * radius_px).ceil()
            ),
        )
    })?;
    let mut images: Vec<(Pattern, image::RgbImage)> = Vec::new();
    for (c, ch) in calib.channels.iter().enumerate().take(3) {
        for &([sx, sy], origin, columns, rows) in &grids {
            let mut img = image::RgbImage::new(w as u32, h as u32);
            for j in 0..rows {
                for i in 0..columns {
                    let (x, y) = (origin[0] + i * spacing, origin[1] + j * spacing);
                    img.get_pixel_mut(x as u32, y as u32)[c] = 255;
                }
            }
            let name = ch.name.to_lowercase();
            images.push((
                Pattern {
                    file: if shifts == 1 {
                        format!("dots-{name}.png")
                    } else {
                        format!("dots-{name}-{sx}-{sy}.png")
                    },
                    kind: "dots".into(),
                    channel: Some(c),
                    origin_px: Some(origin),
                    columns: Some(columns),
                    rows: Some(rows),
                    wavelength_nm: Some(ch.wavelength_m * 1e9),
                    square_px: None,
                },
                img,
            ));
        }
    }
    let square = (w.min(h) / 16).max(4);
    let board = image::RgbImage::from_fn(w as u32, h as u32, |x, y| {
        let lit = (x as usize / square + y as usize / square).is_multiple_of(2);
        image::Rgb([if lit { 255 } else { 0 }; 3])
    });
    images.push((
        Pattern {
            file: "checkerboard.png".into(),
            kind: "checkerboard".into(),
            channel: None,
            origin_px: None,
            columns: None,
            rows: None,
            wavelength_nm: None,
            square_px: Some(square),
        },
        board,
    ));
    // One flat field a channel: a camera's response differs between the
    // primaries, and each channel's dots are normalised by its own flat.
    for (c, ch) in calib.channels.iter().enumerate().take(3) {
        let mut img = image::RgbImage::new(w as u32, h as u32);
        img.pixels_mut().for_each(|p| p[c] = 255);
        images.push((
            Pattern {
                file: format!("flat-{}.png", ch.name.to_lowercase()),
                kind: "flat".into(),
                channel: Some(c),
                origin_px: None,
                columns: None,
                rows: None,
                wavelength_nm: Some(ch.wavelength_m * 1e9),
                square_px: None,
            },
            img,
        ));
    }
    images.push((
        Pattern {
            file: "dark.png".into(),
            kind: "dark".into(),
            channel: None,
            origin_px: None,
            columns: None,
            rows: None,
            wavelength_nm: None,
            square_px: None,
        },
        image::RgbImage::new(w as u32, h as u32),
    ));
    let manifest = PatternsManifest {
        panel: PanelInfo {
            width_px: w,
            height_px: h,
            pixel_pitch_um: calib.pixel_pitch_m * 1e6,
            calibration: calib.source.clone(),
        },
        dots: DotGrid {
            spacing_px: spacing,
            shifts,
            psf_radius_px: (radius_px * 1000.0).round() / 1000.0,
            margin,
            depths_d,
        },
        pattern: images.iter().map(|(p, _)| p.clone()).collect(),
    };
    let text = toml::to_string(&manifest)
        .map_err(|e| AppError::Internal(format!("patterns.toml: {e}")))?;
    crate::create_dir(out_dir)?;
    for (p, img) in &images {
        let path = out_dir.join(&p.file);
        img.save(&path).map_err(|e| AppError::output(&path, e))?;
    }
    let manifest_path = out_dir.join("patterns.toml");
    crate::write_text(&manifest_path, &text)?;
    Ok(format!(
        "{} patterns in {}: dots every {spacing} px ({} a pattern, {shifts}×{shifts} shifted grids a \
         channel; the design PSF's \
         {:.1} % radius {radius_px:.1} px × margin {margin}), a checkerboard of {square} px squares, \
         a flat field a channel and a dark field; {}\n\
         the design PSF's radius, the largest over the channels at {depths}: 90 % of its light \
         within {:.1} px, 99 % within {:.1} px, 99.9 % within {:.1} px\n",
        images.len(),
        out_dir.display(),
        grids
            .iter()
            .map(|g| g.2 * g.3)
            .min()
            .map(|lo| {
                let hi = grids.iter().map(|g| g.2 * g.3).max().unwrap_or(lo);
                if lo == hi {
                    lo.to_string()
                } else {
                    format!("{lo}–{hi}")
                }
            })
            .unwrap_or_default(),
        ENERGY_SHARE * 100.0,
        manifest_path.display(),
        radii_px[0],
        radii_px[1],
        radii_px[2],
        depths = manifest
            .dots
            .depths_d
            .iter()
            .map(|d| format!("{d} D"))
            .collect::<Vec<_>>()
            .join(", "),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_energy_radius_of_a_disk_is_its_radius() {
        let n = 41;
        let c = 20.0;
        let cells: Vec<f64> = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f64 - c, (i / n) as f64 - c);
                if (x * x + y * y).sqrt() <= 10.0 {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        let psf = Psf {
            window: n,
            cells,
            veil: 0.0,
        };
        let r = energy_radius_cells(&psf, 0.999);
        assert!((9.5..=10.0).contains(&r), "{r}");
        // Half the light of a uniform disk lies within r/√2.
        let half = energy_radius_cells(&psf, 0.5);
        assert!((half - 10.0 / 2f64.sqrt()).abs() < 0.6, "{half}");
    }

    #[test]
    fn dots_stay_apart_and_inside_the_panel() {
        let (spacing, grids) = dot_grids(64, 48, 3.2, 1.5, 1).expect("a grid");
        assert_eq!(spacing, 11);
        assert!(spacing as f64 > 2.0 * 1.5 * 3.2);
        assert_eq!(grids, [([0, 0], [5, 5], 5, 4)]);
        assert!(5 + 4 * spacing + 5 <= 63 && 5 + 3 * spacing + 5 <= 47);
        // Two shifts: half a spacing across and down, each still inside.
        let (_, grids) = dot_grids(64, 48, 3.2, 1.5, 2).expect("grids");
        assert_eq!(grids.len(), 4);
        assert_eq!(grids[3].1, [5 + 5, 5 + 5]);
        for (_, [x0, y0], columns, rows) in grids {
            assert!(x0 + (columns - 1) * spacing + 5 <= 63);
            assert!(y0 + (rows - 1) * spacing + 5 <= 47);
        }
        assert!(dot_grids(8, 8, 5.0, 1.0, 1).is_none());
    }
}
