//! A bundle's folder read and written.

use std::path::Path;

use safetensors::{Dtype, SafeTensors, tensor::TensorView};

use super::{
    BundleCard, BundleError, CARD_FILE, MAX_CARD_BYTES, PSFS_FILE, PsfBundle, invalid, zone_count,
};
use crate::psf::Psf;

impl PsfBundle {
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
        let psfs_of = |cells: Vec<f64>, veils: Vec<f64>| -> Vec<Psf> {
            cells
                .chunks_exact(n * n.max(1))
                .zip(veils)
                .map(|(c, veil)| Psf {
                    window: n,
                    cells: c.to_vec(),
                    veil,
                })
                .collect()
        };
        let psfs = psfs_of(f64s("psfs", &[na, nc, n, n])?, f64s("veil", &[na, nc])?);
        let zone_psfs = match zone_count(&card, &card_path)? {
            0 => Vec::new(),
            nz => psfs_of(
                f64s("zone_psfs", &[nz, na, nc, n, n])?,
                f64s("zone_veil", &[nz, na, nc])?,
            ),
        };
        let bundle = Self {
            path: dir.to_path_buf(),
            card,
            psfs,
            zone_psfs,
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
        let cells_of = |psfs: &[Psf]| -> Vec<u8> {
            psfs.iter()
                .flat_map(|p| p.cells.iter().flat_map(|v| v.to_le_bytes()))
                .collect()
        };
        let veils_of =
            |psfs: &[Psf]| -> Vec<u8> { psfs.iter().flat_map(|p| p.veil.to_le_bytes()).collect() };
        let (cells, veils) = (cells_of(&self.psfs), veils_of(&self.psfs));
        let (zone_cells, zone_veils) = (cells_of(&self.zone_psfs), veils_of(&self.zone_psfs));
        let nz = self.zone_psfs.len() / self.psfs.len().max(1);
        let tensor_err = |e: safetensors::SafeTensorError| invalid(dir, e.to_string());
        let mut tensors = vec![
            (
                "psfs",
                TensorView::new(Dtype::F64, vec![na, nc, n, n], &cells).map_err(tensor_err)?,
            ),
            (
                "veil",
                TensorView::new(Dtype::F64, vec![na, nc], &veils).map_err(tensor_err)?,
            ),
        ];
        if self.card.zones.is_some() {
            tensors.push((
                "zone_psfs",
                TensorView::new(Dtype::F64, vec![nz, na, nc, n, n], &zone_cells)
                    .map_err(tensor_err)?,
            ));
            tensors.push((
                "zone_veil",
                TensorView::new(Dtype::F64, vec![nz, na, nc], &zone_veils).map_err(tensor_err)?,
            ));
        }
        let meta = std::collections::HashMap::from([(
            "definition".to_string(),
            "psfs[a, c, y, x]: the fraction of channel c's light in retinal cell (x, y) with the eye \
             accommodated at bundle.toml's accommodations_d[a], the axis at the centre cell; \
             veil[a, c]: the fraction outside the window; zone_psfs[z, a, c, y, x] and \
             zone_veil[z, a, c] (with bundle.toml's zones = [columns, rows]): the same from the \
             dots of field zone z alone, row by row"
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
