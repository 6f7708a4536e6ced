//! The true PSFs of a display as built (docs/calibration.md): the design's
//! optics moved by a [`Perturbation`], computed rather than photographed.
//! `calib synth` photographs through them (its `truth/`); `nedrt calib
//! truth` writes them alone, as the oracle a recovered bundle is judged
//! against, or a bundle to try a pipeline on without captures.
//!
//! A primary with a spectral width is the mean of its line PSFs over the
//! Gaussian line (five Gauss–Hermite nodes, [`Perturbation::spectral_nodes`]):
//! a camera behind a colour filter integrates the same spectrum.
//!
//! With field zones each zone's PSFs are those at its centre's field angle
//! (they differ where the eye's pupil is the stop), and the whole field's
//! are their mean: what averaging every dot of equal zones measures.

use std::path::Path;

use crate::{AppError, CommonOptions};
use nedrt_optics::bundle::PsfBundle;
use nedrt_optics::perturb::Perturbation;
use nedrt_optics::psf::Psf;
use nedrt_optics::sim::zones::{FieldGeometry, ZonePlan};
use nedrt_optics::sim::{Method, Simulator};

/// Most of a PSF's light a bundle's window may leave to the veil.
const TRIM_LOST: f64 = 1e-6;

/// The PSFs (lens + DOE, with the veil) of the display `p` builds from
/// `common`'s design, at each of `accommodations_d`, for the whole field
/// and, where `zones` (columns, rows) is not (1, 1), each field zone's: a
/// bundle, not yet saved, its card naming the command that made it
/// (`made_by`). Its wavelengths are the built primaries' centres.
pub fn true_psfs(
    common: &CommonOptions,
    p: &Perturbation,
    accommodations_d: &[f64],
    made_by: &str,
    zones: (usize, usize),
) -> Result<PsfBundle, AppError> {
    p.check()
        .map_err(|e| AppError::option("the perturbation", e))?;
    let design = common.calibration()?;
    for &d in accommodations_d {
        crate::check_accommodation_as(&design, d, "--accommodations")?;
    }
    let design_sim = Simulator::new(
        design.clone(),
        common.doe_path_for(&[Method::DoeOnly]).as_deref(),
        common.cache(),
    )?;
    let doe = p.doe(&design_sim.doe, design.doe_wave_height_m());
    crate::calib_psfs::check_zones(zones)?;
    let (nx, ny) = zones;
    let (w, h) = (design.panel.width_px, design.panel.height_px);
    let plan = ZonePlan {
        nx,
        ny,
        field: FieldGeometry::of(&design, w, h),
        note: String::new(),
    };
    let at = |field: Option<(f64, f64)>| {
        let psfs = line_mixture(common, p, &design, &doe, accommodations_d, field)?;
        Ok::<_, AppError>(
            psfs.iter()
                .map(|p| p.trimmed(TRIM_LOST))
                .collect::<Vec<_>>(),
        )
    };
    let (whole, zone_psfs) = if (nx, ny) == (1, 1) {
        (at(None)?, Vec::new())
    } else {
        let mut each = Vec::with_capacity(nx * ny);
        for j in 0..ny {
            for i in 0..nx {
                each.push(at(Some(plan.tan_at_zone(i, j)))?);
            }
        }
        let weight = 1.0 / each.len() as f64;
        let whole = (0..each[0].len())
            .map(|k| {
                let widest = each.iter().map(|z| z[k].window).max().unwrap_or(1);
                let padded: Vec<Psf> = each.iter().map(|z| z[k].padded(widest)).collect();
                Psf::weighted_sum(padded.iter().map(|p| (p, weight)))
                    .ok_or_else(|| AppError::Internal("no zone".into()))
            })
            .collect::<Result<Vec<_>, _>>()?;
        (whole, each.concat())
    };
    // One window for the bundle: the widest that holds all but
    // TRIM_LOST of each PSF's light (a 2-D DOE's PSFs come a whole period
    // wide, hundreds of cells of nothing), the others centred in it.
    let widest = whole
        .iter()
        .chain(&zone_psfs)
        .map(|p| p.window)
        .max()
        .unwrap_or(1);
    let pad = |v: Vec<Psf>| v.iter().map(|p| p.padded(widest)).collect::<Vec<_>>();
    let centre = p.calibration(&design);
    let suffix = match zones {
        (1, 1) => String::new(),
        _ => format!(", {nx}×{ny} field zones"),
    };
    PsfBundle::new(
        &format!("{made_by}: the true PSFs ({}{suffix})", p.describe()),
        accommodations_d.to_vec(),
        centre
            .channels
            .iter()
            .map(|c| c.wavelength_m * 1e9)
            .collect(),
        pad(whole),
        None,
    )
    .and_then(|b| match zones {
        (1, 1) => Ok(b),
        _ => b.with_zones(nx, ny, pad(zone_psfs)),
    })
    .map_err(|e| AppError::Internal(e.to_string()))
}

/// The built display's PSFs at each of `accommodations_d` (accommodation-
/// major), its primaries' spectra mixed, at the design's field or at
/// `field` (tangents, horizontal and vertical).
fn line_mixture(
    common: &CommonOptions,
    p: &Perturbation,
    design: &nedrt_core::calib::Calibration,
    doe: &nedrt_optics::doe::HeightMap,
    accommodations_d: &[f64],
    field: Option<(f64, f64)>,
) -> Result<Vec<Psf>, AppError> {
    let channels = design.channels.len();
    // [accommodation][channel]: each node's PSFs with its weight.
    let mut terms: Vec<Vec<Vec<(Psf, f64)>>> =
        vec![vec![Vec::new(); channels]; accommodations_d.len()];
    for (weight, line) in p.spectral_nodes() {
        let mut built = Simulator::with_doe(line.calibration(design), doe.clone(), common.cache());
        if let Some((tx, ty)) = field {
            built = built.at_field(tx, ty);
        }
        let prepared = built.prepare(&[Method::DoeOnly], accommodations_d, common.progress())?;
        for (a, &d) in accommodations_d.iter().enumerate() {
            for (c, psf) in prepared
                .system_psfs(Method::DoeOnly, d)?
                .into_iter()
                .enumerate()
            {
                terms[a][c].push((psf, weight));
            }
        }
    }
    terms
        .iter()
        .flatten()
        .map(|t| {
            Psf::weighted_sum(t.iter().map(|(p, w)| (p, *w)))
                .ok_or_else(|| AppError::Internal("a PSF with no spectral node".into()))
        })
        .collect()
}

/// `nedrt calib truth`: the true PSFs saved as a bundle at `out` (a new
/// folder, or a bundle to replace); says what it wrote.
pub fn write(
    common: &CommonOptions,
    p: &Perturbation,
    accommodations_d: &[f64],
    zones: (usize, usize),
    out: &Path,
) -> Result<String, AppError> {
    if accommodations_d.is_empty() {
        return Err(AppError::option("--accommodations", "give at least one"));
    }
    let mut bundle = true_psfs(common, p, accommodations_d, "nedrt calib truth", zones)?;
    bundle.save(out).map_err(|e| AppError::output(out, e))?;
    Ok(format!(
        "the true PSFs of the display as built ({}) at {} D, {}×{} cells{}, in {}\n",
        p.describe(),
        accommodations_d
            .iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        bundle.card.window_cells,
        bundle.card.window_cells,
        match zones {
            (1, 1) => String::new(),
            (x, y) => format!(", the whole field and {x}×{y} zones"),
        },
        out.display()
    ))
}
