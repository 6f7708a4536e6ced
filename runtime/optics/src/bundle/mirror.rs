//! A bundle made mirror-symmetric, for the objective's kernel form.

use super::{PsfBundle, psfs_hash};
use crate::psf::Psf;

impl PsfBundle {
    /// The bundle with each PSF averaged with its mirror images in x and
    /// in y (cells and veil; the light and its centroid on the axis kept),
    /// and the largest share of a PSF that this removed (relative L2 of
    /// the cells). The objective's kernel form (`nedrt prefilter
    /// --operator`, the trainer's loss) exists only for mirror-symmetric
    /// PSFs; a built display's are not quite (noise, decentre).
    pub fn mirrored(&self) -> (Self, f64) {
        let mut worst = 0.0f64;
        let mut mirror = |p: &Psf| {
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
        };
        let psfs: Vec<Psf> = self.psfs.iter().map(&mut mirror).collect();
        let zone_psfs: Vec<Psf> = self.zone_psfs.iter().map(&mut mirror).collect();
        let mut card = self.card.clone();
        card.made_by = format!("{} (mirror-averaged)", card.made_by);
        // Not the file's hash (it was not saved) but the PSFs' own, so that
        // what is keyed by a bundle's hash never mistakes one for the other.
        card.psfs_blake3 = psfs_hash(psfs.iter().chain(&zone_psfs));
        (
            Self {
                path: self.path.clone(),
                card,
                psfs,
                zone_psfs,
            },
            worst,
        )
    }
}
