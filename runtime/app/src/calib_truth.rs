//! The true PSFs of a display as built (docs/calibration.md): the design's
//! optics moved by a [`Perturbation`], computed rather than photographed.
//! `calib synth` photographs through them (its `truth/`); `nedrt calib
//! truth` writes them alone, as the oracle a recovered bundle is judged
//! against, or a bundle to try a pipeline on without captures.
//!
//! A primary with a spectral width is the mean of its line PSFs over the
//! Gaussian line (five Gauss–Hermite nodes, [`Perturbation::spectral_nodes`]):
//! a camera behind a colour filter integrates the same spectrum.

use std::path::Path;

use crate::{AppError, CommonOptions};
use nedrt_optics::bundle::PsfBundle;
use nedrt_optics::perturb::Perturbation;
use nedrt_optics::psf::Psf;
use nedrt_optics::sim::{Method, Simulator};

/// Most of a PSF's light a bundle's window may leave to the veil.
const TRIM_LOST: f64 = 1e-6;

/// The PSFs (lens + DOE, with the veil) of the display `p` builds from
/// `common`'s design, at each of `accommodations_d`: a bundle, not yet
/// saved, its card naming the command that made it (`made_by`). Its
/// wavelengths are the built primaries' centres.
pub fn true_psfs(
    common: &CommonOptions,
    p: &Perturbation,
    accommodations_d: &[f64],
    made_by: &str,
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
    let doe = p.doe(&design_sim.doe);
    let channels = design.channels.len();
    // [accommodation][channel]: each node's PSFs with its weight.
    let mut terms: Vec<Vec<Vec<(Psf, f64)>>> =
        vec![vec![Vec::new(); channels]; accommodations_d.len()];
    for (weight, line) in p.spectral_nodes() {
        let built = Simulator::with_doe(line.calibration(&design), doe.clone(), common.cache());
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
    let mixed: Vec<Psf> = terms
        .iter()
        .flatten()
        .map(|t| {
            Psf::weighted_sum(t.iter().map(|(p, w)| (p, *w)))
                .ok_or_else(|| AppError::Internal("a PSF with no spectral node".into()))
        })
        .collect::<Result<_, _>>()?;
    // One window for the bundle: the widest that holds all but
    // TRIM_LOST of each PSF's light (a 2-D DOE's PSFs come a whole period
    // wide, hundreds of cells of nothing), the others centred in it.
    let mixed: Vec<Psf> = mixed.iter().map(|p| p.trimmed(TRIM_LOST)).collect();
    let widest = mixed.iter().map(|p| p.window).max().unwrap_or(1);
    let psfs = mixed.iter().map(|p| p.padded(widest)).collect();
    let centre = p.calibration(&design);
    PsfBundle::new(
        &format!("{made_by}: the true PSFs ({})", p.describe()),
        accommodations_d.to_vec(),
        centre
            .channels
            .iter()
            .map(|c| c.wavelength_m * 1e9)
            .collect(),
        psfs,
        None,
    )
    .map_err(|e| AppError::Internal(e.to_string()))
}

/// `nedrt calib truth`: the true PSFs saved as a bundle at `out` (a new
/// folder, or a bundle to replace); says what it wrote.
pub fn write(
    common: &CommonOptions,
    p: &Perturbation,
    accommodations_d: &[f64],
    out: &Path,
) -> Result<String, AppError> {
    if accommodations_d.is_empty() {
        return Err(AppError::option("--accommodations", "give at least one"));
    }
    let mut bundle = true_psfs(common, p, accommodations_d, "nedrt calib truth")?;
    bundle.save(out).map_err(|e| AppError::output(out, e))?;
    Ok(format!(
        "the true PSFs of the display as built ({}) at {} D, {}×{} cells, in {}\n",
        p.describe(),
        accommodations_d
            .iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        bundle.card.window_cells,
        bundle.card.window_cells,
        out.display()
    ))
}
