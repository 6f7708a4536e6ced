//! Measured PSF bundles (docs/calibration.md): the retinal PSFs of a built
//! display, per accommodation and channel, measured from camera captures
//! (`nedrt calib psfs`) or written as the truth of synthetic captures
//! (`nedrt calib synth`). A bundle is a folder: `psfs.safetensors` (tensor
//! `psfs`, accommodation × channel × N × N float64, each cell's share of
//! the light as in `nedrt psf --at`; `veil`, accommodation × channel) and
//! `bundle.toml`, its card: the accommodations, wavelengths, the tensor
//! file's hash, and how it was measured.
//!
//! A bundle may also hold field zones (`zones = [columns, rows]` in the
//! card; tensors `zone_psfs`, zone × accommodation × channel × N × N, and
//! `zone_veil`): the PSFs measured from the dots in each of equal
//! rectangles over the panel, row by row, for a display whose PSF changes
//! across the field. `psfs` is then the whole field's, every dot alike.
//!
//! Between the measured accommodations a PSF is interpolated linearly in
//! diopters; outside them it is an error, never an extrapolation.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::psf::Psf;

mod io;
mod mirror;

/// The card's `format`.
pub const FORMAT: &str = "nedrt psf bundle 1";
pub const CARD_FILE: &str = "bundle.toml";
pub const PSFS_FILE: &str = "psfs.safetensors";
/// Largest card read (a few KB in practice).
const MAX_CARD_BYTES: u64 = 1 << 20;
/// Accommodations closer than this are the same (diopters).
const DEPTH_TOLERANCE_D: f64 = 1e-6;
/// Most field zones a bundle holds (the simulator's 8 × 8).
pub const MAX_ZONES: usize = 64;

/// Whether `columns` × `rows` field zones are a grid a bundle can hold.
pub fn zones_valid(columns: usize, rows: usize) -> bool {
    columns > 0 && rows > 0 && columns.saturating_mul(rows) <= MAX_ZONES
}

/// The field zone (row by row) of panel position (`x`, `y`), pixels, on a
/// `width` × `height` panel cut in `columns` × `rows` equal rectangles.
pub fn zone_at(
    (columns, rows): (usize, usize),
    (width, height): (usize, usize),
    x: f64,
    y: f64,
) -> usize {
    let i = ((x * columns as f64 / width as f64) as usize).min(columns - 1);
    let j = ((y * rows as f64 / height as f64) as usize).min(rows - 1);
    j * columns + i
}

/// A bundle that cannot be read, written or used, naming the file.
#[derive(Debug, thiserror::Error)]
pub enum BundleError {
    #[error("{}: {reason}", path.display())]
    Invalid { path: PathBuf, reason: String },
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "the PSF bundle {} was measured at {lo}–{hi} D; {accommodation_d} D lies outside (a bundle is \
         interpolated between its accommodations, never extrapolated: measure the range you need)",
        path.display()
    )]
    OutOfRange {
        path: PathBuf,
        accommodation_d: f64,
        lo: f64,
        hi: f64,
    },
}

/// How the PSFs were measured (absent in a synthetic truth).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Measurement {
    /// The captures folder and its manifest's hash.
    pub captures: String,
    pub manifest_blake3: String,
    /// The capture the camera-to-panel map was fitted to, and its residual
    /// over the checkerboard's corners, panel pixels (RMS and largest).
    pub registration_capture: String,
    pub registration_model: String,
    pub registration_points: usize,
    pub registration_rms_px: f64,
    pub registration_max_px: f64,
    /// Dots averaged per channel (each accommodation alike).
    pub dots_per_channel: Vec<usize>,
    /// Cells under this share of a dot's light were set to 0, per
    /// accommodation × channel (3 × the background's standard deviation
    /// after averaging).
    pub noise_floor: Vec<Vec<f64>>,
    /// Each capture's file and BLAKE3 hash.
    pub capture_hashes: Vec<[String; 2]>,
}

/// `bundle.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BundleCard {
    pub format: String,
    /// What made it (`nedrt calib psfs`, `nedrt calib synth` truth, …).
    pub made_by: String,
    pub accommodations_d: Vec<f64>,
    pub wavelengths_nm: Vec<f64>,
    /// N: each PSF is N×N retinal cells (half a panel pixel each way).
    pub window_cells: usize,
    pub psfs_blake3: String,
    /// Field zones, columns × rows over the panel (absent: one, the
    /// whole field).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zones: Option<[usize; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measurement: Option<Measurement>,
}

/// A bundle's PSFs and card.
#[derive(Debug, Clone, PartialEq)]
pub struct PsfBundle {
    /// Where it was read from (for messages), or where it will be written.
    pub path: PathBuf,
    pub card: BundleCard,
    /// Accommodation-major: `psfs[a * channels + c]`.
    pub psfs: Vec<Psf>,
    /// With zones, zone-major (row by row), then as `psfs`:
    /// `zone_psfs[(z * accommodations + a) * channels + c]`; else empty.
    pub zone_psfs: Vec<Psf>,
}

/// The BLAKE3 hash of PSFs' values (cells, then veil, little-endian): the
/// identity of a bundle made in memory, not saved.
pub(crate) fn psfs_hash<'a>(psfs: impl IntoIterator<Item = &'a Psf>) -> String {
    let mut hasher = blake3::Hasher::new();
    for p in psfs {
        for v in p.cells.iter().chain(std::iter::once(&p.veil)) {
            hasher.update(&v.to_le_bytes());
        }
    }
    hasher.finalize().to_hex().to_string()
}

/// How many field zones the card names (0 without), checked.
fn zone_count(card: &BundleCard, path: &Path) -> Result<usize, BundleError> {
    match card.zones {
        None => Ok(0),
        Some([x, y]) if !zones_valid(x, y) => Err(invalid(
            path,
            format!("zones [{x}, {y}]: give 1 to {MAX_ZONES} zones in all"),
        )),
        Some([x, y]) => Ok(x * y),
    }
}

fn invalid(path: &Path, reason: impl Into<String>) -> BundleError {
    BundleError::Invalid {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

impl PsfBundle {
    /// A bundle from PSFs (accommodation-major, one window), checked as a
    /// read one is.
    pub fn new(
        made_by: &str,
        accommodations_d: Vec<f64>,
        wavelengths_nm: Vec<f64>,
        psfs: Vec<Psf>,
        measurement: Option<Measurement>,
    ) -> Result<Self, BundleError> {
        let window = psfs.first().map_or(0, |p| p.window);
        let bundle = Self {
            path: PathBuf::from("(new bundle)"),
            card: BundleCard {
                format: FORMAT.into(),
                made_by: made_by.into(),
                accommodations_d,
                wavelengths_nm,
                window_cells: window,
                psfs_blake3: String::new(),
                zones: None,
                measurement,
            },
            psfs,
            zone_psfs: Vec::new(),
        };
        bundle.check()?;
        Ok(bundle)
    }

    /// The bundle with field zones: `columns` × `rows` of them, their PSFs
    /// ordered as [`PsfBundle::zone_psfs`], in the bundle's window.
    pub fn with_zones(
        mut self,
        columns: usize,
        rows: usize,
        zone_psfs: Vec<Psf>,
    ) -> Result<Self, BundleError> {
        self.card.zones = Some([columns, rows]);
        self.zone_psfs = zone_psfs;
        self.check()?;
        Ok(self)
    }

    /// Columns × rows of field zones (1 × 1: the whole field alone).
    pub fn zones(&self) -> (usize, usize) {
        self.card.zones.map_or((1, 1), |[x, y]| (x, y))
    }

    /// Zone (`column`, `row`)'s PSFs as a bundle of one zone, named by a
    /// hash of its own; `None` where the bundle has no such zone.
    pub fn zone(&self, column: usize, row: usize) -> Option<Self> {
        let (nx, ny) = self.zones();
        if self.card.zones.is_none() || column >= nx || row >= ny {
            return None;
        }
        let per_zone = self.psfs.len();
        let z = row * nx + column;
        let psfs = self.zone_psfs[z * per_zone..(z + 1) * per_zone].to_vec();
        let mut card = self.card.clone();
        card.zones = None;
        card.made_by = format!("{}, field zone ({column}, {row})", card.made_by);
        card.psfs_blake3 = psfs_hash(&psfs);
        Some(Self {
            path: self.path.clone(),
            card,
            psfs,
            zone_psfs: Vec::new(),
        })
    }

    pub fn channels(&self) -> usize {
        self.card.wavelengths_nm.len()
    }

    pub fn accommodations_d(&self) -> &[f64] {
        &self.card.accommodations_d
    }

    /// The measured PSF of `channel` at the `index`-th accommodation.
    pub fn measured(&self, index: usize, channel: usize) -> &Psf {
        &self.psfs[index * self.channels() + channel]
    }

    fn check(&self) -> Result<(), BundleError> {
        let p = &self.path;
        let c = &self.card;
        if c.format != FORMAT {
            return Err(invalid(
                p,
                format!("format {:?}: this nedrt reads {FORMAT:?}", c.format),
            ));
        }
        if c.accommodations_d.is_empty() || c.wavelengths_nm.is_empty() {
            return Err(invalid(p, "no accommodation or no channel"));
        }
        if c.accommodations_d.iter().any(|d| !d.is_finite())
            || c.accommodations_d
                .windows(2)
                .any(|w| w[1] - w[0] <= DEPTH_TOLERANCE_D)
        {
            return Err(invalid(
                p,
                format!(
                    "accommodations_d {:?}: must be finite and strictly ascending",
                    c.accommodations_d
                ),
            ));
        }
        if c.wavelengths_nm
            .iter()
            .any(|w| !(w.is_finite() && *w > 0.0))
        {
            return Err(invalid(p, "wavelengths_nm must be positive"));
        }
        let n = c.window_cells;
        if n == 0 || n.is_multiple_of(2) {
            return Err(invalid(
                p,
                format!("window_cells {n}: must be odd (the axis at the centre cell)"),
            ));
        }
        if self.psfs.len() != c.accommodations_d.len() * c.wavelengths_nm.len() {
            return Err(invalid(
                p,
                format!(
                    "{} PSFs for {} accommodations × {} channels",
                    self.psfs.len(),
                    c.accommodations_d.len(),
                    c.wavelengths_nm.len()
                ),
            ));
        }
        if c.zones.is_none() && !self.zone_psfs.is_empty() {
            return Err(invalid(p, "zone PSFs without the card's zones"));
        }
        let zones = zone_count(c, p)?;
        if self.zone_psfs.len() != zones * self.psfs.len() {
            return Err(invalid(
                p,
                format!(
                    "{} zone PSFs for {zones} zones × {} PSFs",
                    self.zone_psfs.len(),
                    self.psfs.len()
                ),
            ));
        }
        let per_zone = self.psfs.len().max(1);
        for (i, psf) in self.psfs.iter().chain(&self.zone_psfs).enumerate() {
            let (zone, i) = (i / per_zone, i % per_zone);
            let (a, ch) = (i / c.wavelengths_nm.len(), i % c.wavelengths_nm.len());
            let at = match zone {
                0 => format!("the PSF at {} D, channel {ch}", c.accommodations_d[a]),
                z => format!(
                    "zone {}'s PSF at {} D, channel {ch}",
                    z - 1,
                    c.accommodations_d[a]
                ),
            };
            if psf.window != n || psf.cells.len() != n * n {
                return Err(invalid(p, format!("{at}: not {n}×{n} cells")));
            }
            if psf.cells.iter().any(|v| !v.is_finite()) || !psf.veil.is_finite() {
                return Err(invalid(p, format!("{at}: values that are not finite")));
            }
            let sum: f64 = psf.cells.iter().sum::<f64>() + psf.veil;
            if !(0.0..=1.0 + 1e-3).contains(&psf.veil) || (sum - 1.0).abs() > 1e-3 {
                return Err(invalid(
                    p,
                    format!(
                        "{at}: cells and veil sum to {sum:.5} (veil {:.5}); a PSF holds all of its light",
                        psf.veil
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The PSF of `channel` at `accommodation_d`, interpolated linearly in
    /// diopters between the two measured accommodations around it.
    pub fn at(&self, accommodation_d: f64, channel: usize) -> Result<Psf, BundleError> {
        let ds = &self.card.accommodations_d;
        let (lo, hi) = (ds[0], ds[ds.len() - 1]);
        if channel >= self.channels() {
            return Err(invalid(
                &self.path,
                format!(
                    "channel {channel}: the bundle has {} channels",
                    self.channels()
                ),
            ));
        }
        if !(accommodation_d >= lo - DEPTH_TOLERANCE_D && accommodation_d <= hi + DEPTH_TOLERANCE_D)
        {
            return Err(BundleError::OutOfRange {
                path: self.path.clone(),
                accommodation_d,
                lo,
                hi,
            });
        }
        let upper = ds
            .iter()
            .position(|d| *d >= accommodation_d - DEPTH_TOLERANCE_D)
            .unwrap_or(ds.len() - 1);
        if (ds[upper] - accommodation_d).abs() <= DEPTH_TOLERANCE_D || upper == 0 {
            return Ok(self.measured(upper, channel).clone());
        }
        let t = (accommodation_d - ds[upper - 1]) / (ds[upper] - ds[upper - 1]);
        Psf::weighted_sum([
            (self.measured(upper - 1, channel), 1.0 - t),
            (self.measured(upper, channel), t),
        ])
        .ok_or_else(|| invalid(&self.path, "no PSF"))
    }

    /// Checks the bundle against a calibration's channels: as many (the
    /// bundle measures the built primaries, whatever wavelengths the
    /// calibration names).
    pub fn check_channels(&self, channels: usize) -> Result<(), BundleError> {
        if channels != self.channels() {
            return Err(invalid(
                &self.path,
                format!(
                    "{} channels; the calibration has {}",
                    self.channels(),
                    channels
                ),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bundle() -> PsfBundle {
        let psfs = [0.5, 1.0, 2.0]
            .iter()
            .flat_map(|s| [Psf::gaussian(*s, 0.01), Psf::gaussian(*s * 1.5, 0.02)])
            .map(|p| {
                // One window for all: pad each to 19×19.
                Psf::weighted_sum([(&p, 1.0), (&Psf::gaussian(3.0, 0.0), 0.0)]).expect("psf")
            })
            .collect();
        PsfBundle::new("test", vec![0.0, 1.0, 3.0], vec![610.0, 530.0], psfs, None)
            .expect("a valid bundle")
    }

    #[test]
    fn interpolates_in_diopters_and_refuses_to_extrapolate() {
        let b = bundle();
        assert_eq!(b.at(1.0, 1).expect("at 1 D"), *b.measured(1, 1));
        let mid = b.at(2.0, 0).expect("at 2 D");
        for (i, v) in mid.cells.iter().enumerate() {
            let want = 0.5 * b.measured(1, 0).cells[i] + 0.5 * b.measured(2, 0).cells[i];
            assert!((v - want).abs() < 1e-15);
        }
        assert!((mid.veil - 0.01).abs() < 1e-15);
        let err = b.at(3.5, 0).expect_err("beyond the range").to_string();
        assert!(err.contains("0–3 D") && err.contains("3.5 D"), "{err}");
        assert!(b.at(-0.1, 0).is_err() && b.at(f64::NAN, 0).is_err());
        assert!(b.at(1.0, 2).is_err());
    }

    #[test]
    fn mirroring_keeps_a_symmetric_psf_and_the_light_of_an_asymmetric_one() {
        let b = bundle();
        let (same, asym) = b.mirrored();
        assert!(asym < 1e-12, "{asym}");
        for (p, q) in b.psfs.iter().zip(&same.psfs) {
            p.cells
                .iter()
                .zip(&q.cells)
                .for_each(|(a, c)| assert!((a - c).abs() < 1e-15));
        }
        // A PSF with light one cell right of the axis: mirrored, half stays
        // and half moves to the left, the centroid back on the axis.
        let mut shifted = b.clone();
        let n = shifted.card.window_cells;
        for p in &mut shifted.psfs {
            let light: f64 = p.cells.iter().sum();
            p.cells.iter_mut().for_each(|v| *v = 0.0);
            p.cells[(n / 2) * n + n / 2 + 1] = light;
        }
        let (m, asym) = shifted.mirrored();
        assert!((asym - 0.5f64.sqrt()).abs() < 1e-12, "{asym}");
        let p = &m.psfs[0];
        let light: f64 = shifted.psfs[0].cells.iter().sum();
        assert!((p.cells[(n / 2) * n + n / 2 + 1] - light / 2.0).abs() < 1e-15);
        assert!((p.cells[(n / 2) * n + n / 2 - 1] - light / 2.0).abs() < 1e-15);
        assert!((p.cells.iter().sum::<f64>() - light).abs() < 1e-15);
        assert!(m.card.made_by.contains("mirror-averaged"));
        assert_ne!(m.card.psfs_blake3, shifted.card.psfs_blake3);
    }

    #[test]
    fn saves_loads_and_refuses_a_changed_file() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("b");
        let mut b = bundle();
        b.save(&path).expect("saved");
        let back = PsfBundle::load(&path).expect("loads");
        assert_eq!(back.psfs, b.psfs);
        assert_eq!(back.card, b.card);
        // Saving again replaces the bundle; a folder of other files is refused.
        b.save(&path).expect("replaced");
        let other = dir.path().join("other");
        std::fs::create_dir(&other).expect("mkdir");
        std::fs::write(other.join("notes.txt"), "keep").expect("write");
        assert!(b.save(&other).is_err());
        assert_eq!(
            std::fs::read_to_string(other.join("notes.txt")).expect("kept"),
            "keep"
        );
        // A changed tensor file no longer matches the card's hash.
        let t = path.join(PSFS_FILE);
        let mut bytes = std::fs::read(&t).expect("read");
        let last = bytes.len() - 1;
        bytes[last] ^= 1;
        std::fs::write(&t, bytes).expect("write");
        let err = PsfBundle::load(&path).expect_err("changed").to_string();
        assert!(
            err.contains("psfs.safetensors") && err.contains("hash"),
            "{err}"
        );
    }

    #[test]
    fn a_psf_that_loses_light_is_refused() {
        let mut p = Psf::gaussian(1.0, 0.0);
        p.cells.iter_mut().for_each(|v| *v *= 0.5);
        let err = PsfBundle::new("t", vec![0.0], vec![530.0], vec![p], None)
            .expect_err("half the light")
            .to_string();
        assert!(err.contains("sum to 0.5"), "{err}");
    }
}
