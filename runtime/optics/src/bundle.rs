//! Measured PSF bundles (docs/calibration.md): the retinal PSFs of a built
//! display, per accommodation and channel, measured from camera captures
//! (`nedrt calib psfs`) or written as the truth of synthetic captures
//! (`nedrt calib synth`). A bundle is a folder: `psfs.safetensors` (tensor
//! `psfs`, accommodation × channel × N × N float64, each cell's share of
//! the light as in `nedrt psf --at`; `veil`, accommodation × channel) and
//! `bundle.toml`, its card: the accommodations, wavelengths, the tensor
//! file's hash, and how it was measured.
//!
//! Between the measured accommodations a PSF is interpolated linearly in
//! diopters; outside them it is an error, never an extrapolation.

use std::path::{Path, PathBuf};

use safetensors::{Dtype, SafeTensors, tensor::TensorView};
use serde::{Deserialize, Serialize};

use crate::psf::Psf;

/// The card's `format`.
pub const FORMAT: &str = "nedrt psf bundle 1";
pub const CARD_FILE: &str = "bundle.toml";
pub const PSFS_FILE: &str = "psfs.safetensors";
/// Largest card read (a few KB in practice).
const MAX_CARD_BYTES: u64 = 1 << 20;
/// Accommodations closer than this are the same (diopters).
const DEPTH_TOLERANCE_D: f64 = 1e-6;

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
                measurement,
            },
            psfs,
        };
        bundle.check()?;
        Ok(bundle)
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
        for (i, psf) in self.psfs.iter().enumerate() {
            let (a, ch) = (i / c.wavelengths_nm.len(), i % c.wavelengths_nm.len());
            let at = format!("the PSF at {} D, channel {ch}", c.accommodations_d[a]);
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

    /// The bundle with each PSF averaged with its mirror images in x and
    /// in y (cells and veil; the light and its centroid on the axis kept),
    /// and the largest share of a PSF that this removed (relative L2 of
    /// the cells). The objective's kernel form (`nedrt prefilter
    /// --operator`, the trainer's loss) exists only for mirror-symmetric
    /// PSFs; a built display's are not quite (noise, decentre).
    pub fn mirrored(&self) -> (Self, f64) {
        let mut worst = 0.0f64;
        let psfs = self
            .psfs
            .iter()
            .map(|p| {
                let n = p.window;
                let at = |x: usize, y: usize| p.cells[y * n + x];
                let cells: Vec<f64> = (0..n * n)
                    .map(|i| {
                        let (x, y) = (i % n, i / n);
                        let (mx, my) = (n - 1 - x, n - 1 - y);
                        0.25 * (at(x, y) + at(mx, y) + at(x, my) + at(mx, my))
                    })
                    .collect();
                let norm = p.cells.iter().map(|v| v * v).sum::<f64>().sqrt();
                let off = p
                    .cells
                    .iter()
                    .zip(&cells)
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum::<f64>()
                    .sqrt();
                if norm > 0.0 {
                    worst = worst.max(off / norm);
                }
                Psf {
                    window: n,
                    cells,
                    veil: p.veil,
                }
            })
            .collect::<Vec<Psf>>();
        let mut card = self.card.clone();
        card.made_by = format!("{} (mirror-averaged)", card.made_by);
        // Not the file's hash (it was not saved) but the PSFs' own, so that
        // what is keyed by a bundle's hash never mistakes one for the other.
        let mut hasher = blake3::Hasher::new();
        for p in &psfs {
            for v in p.cells.iter().chain(std::iter::once(&p.veil)) {
                hasher.update(&v.to_le_bytes());
            }
        }
        card.psfs_blake3 = hasher.finalize().to_hex().to_string();
        (
            Self {
                path: self.path.clone(),
                card,
                psfs,
            },
            worst,
        )
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

    /// Reads and checks a bundle folder.
    pub fn load(dir: &Path) -> Result<Self, BundleError> {
        let card_path = dir.join(CARD_FILE);
        let io = |path: &Path, source| BundleError::Io {
            path: path.to_path_buf(),
            source,
        };
        let bytes = nedrt_core::util::read_capped(&card_path, MAX_CARD_BYTES)
            .map_err(|e| io(&card_path, e))?;
        let text = String::from_utf8(bytes).map_err(|_| invalid(&card_path, "not UTF-8 text"))?;
        let card: BundleCard =
            toml::from_str(&text).map_err(|e| invalid(&card_path, e.message().to_string()))?;
        let tensor_path = dir.join(PSFS_FILE);
        let bytes = std::fs::read(&tensor_path).map_err(|e| io(&tensor_path, e))?;
        let hash = blake3::hash(&bytes).to_hex().to_string();
        if hash != card.psfs_blake3 {
            return Err(invalid(
                &tensor_path,
                format!(
                    "its BLAKE3 hash {hash} is not the card's {} ({CARD_FILE}): the file was changed or \
                     belongs to another bundle",
                    card.psfs_blake3
                ),
            ));
        }
        let bad = |r: String| invalid(&tensor_path, r);
        let t = SafeTensors::deserialize(&bytes)
            .map_err(|e| bad(format!("not a safetensors file ({e})")))?;
        let (na, nc, n) = (
            card.accommodations_d.len(),
            card.wavelengths_nm.len(),
            card.window_cells,
        );
        let f64s = |name: &str, shape: &[usize]| -> Result<Vec<f64>, BundleError> {
            let v = t
                .tensor(name)
                .map_err(|e| bad(format!("tensor {name}: {e}")))?;
            if v.dtype() != Dtype::F64 || v.shape() != shape {
                return Err(bad(format!(
                    "tensor {name} is {:?} {:?}; the card asks F64 {shape:?}",
                    v.dtype(),
                    v.shape()
                )));
            }
            Ok(v.data()
                .chunks_exact(8)
                .map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
                .collect())
        };
        let cells = f64s("psfs", &[na, nc, n, n])?;
        let veils = f64s("veil", &[na, nc])?;
        let psfs = cells
            .chunks_exact(n * n.max(1))
            .zip(veils)
            .map(|(c, veil)| Psf {
                window: n,
                cells: c.to_vec(),
                veil,
            })
            .collect();
        let bundle = Self {
            path: dir.to_path_buf(),
            card,
            psfs,
        };
        bundle.check()?;
        Ok(bundle)
    }

    /// Writes the bundle into `dir`: both files into a fresh sibling
    /// folder first, which then takes `dir`'s place, so that a failure
    /// leaves no half-written bundle. An existing `dir` is replaced only
    /// if it is a bundle (holds `bundle.toml` and nothing but bundle files).
    pub fn save(&mut self, dir: &Path) -> Result<(), BundleError> {
        let io = |path: &Path, source| BundleError::Io {
            path: path.to_path_buf(),
            source,
        };
        if dir.exists() {
            let entries: Vec<String> = std::fs::read_dir(dir)
                .map_err(|e| io(dir, e))?
                .filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect();
            let ours = entries.iter().all(|e| e == CARD_FILE || e == PSFS_FILE);
            if !(entries.is_empty() || (ours && entries.iter().any(|e| e == CARD_FILE))) {
                return Err(invalid(
                    dir,
                    "exists and is not a PSF bundle (it holds other files); give a new folder",
                ));
            }
        }
        let (na, nc, n) = (
            self.card.accommodations_d.len(),
            self.channels(),
            self.card.window_cells,
        );
        let cells: Vec<u8> = self
            .psfs
            .iter()
            .flat_map(|p| p.cells.iter().flat_map(|v| v.to_le_bytes()))
            .collect();
        let veils: Vec<u8> = self
            .psfs
            .iter()
            .flat_map(|p| p.veil.to_le_bytes())
            .collect();
        let tensor_err = |e: safetensors::SafeTensorError| invalid(dir, e.to_string());
        let tensors = vec![
            (
                "psfs",
                TensorView::new(Dtype::F64, vec![na, nc, n, n], &cells).map_err(tensor_err)?,
            ),
            (
                "veil",
                TensorView::new(Dtype::F64, vec![na, nc], &veils).map_err(tensor_err)?,
            ),
        ];
        let meta = std::collections::HashMap::from([(
            "definition".to_string(),
            "psfs[a, c, y, x]: the fraction of channel c's light in retinal cell (x, y) with the eye \
             accommodated at bundle.toml's accommodations_d[a], the axis at the centre cell; \
             veil[a, c]: the fraction outside the window"
                .to_string(),
        )]);
        let bytes = safetensors::serialize(tensors, Some(meta)).map_err(tensor_err)?;
        self.card.psfs_blake3 = blake3::hash(&bytes).to_hex().to_string();
        let card = toml::to_string(&self.card).map_err(|e| invalid(dir, e.to_string()))?;
        let staging = nedrt_core::util::staging_sibling(dir).map_err(|e| io(dir, e))?;
        let result = (|| {
            let write = |file: &str, data: &[u8]| {
                let p = staging.join(file);
                std::fs::write(&p, data).map_err(|e| io(&p, e))
            };
            write(PSFS_FILE, &bytes)?;
            write(CARD_FILE, card.as_bytes())?;
            if dir.exists() {
                std::fs::remove_dir_all(dir).map_err(|e| io(dir, e))?;
            }
            std::fs::rename(&staging, dir).map_err(|e| io(dir, e))
        })();
        if result.is_err() {
            let _ = std::fs::remove_dir_all(&staging);
        }
        self.path = dir.to_path_buf();
        result
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
