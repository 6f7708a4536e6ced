//! System PSF and MTF (docs/model.md §11): the system PSF is the retinal PSF
//! convolved with one display pixel (a 2×2-cell box); its MTF is reported
//! along x in cycles per degree. The veil (light outside the window, spread
//! uniformly) counts in the zero-frequency term, so it lowers the MTF at
//! every other frequency, as a haze does.

use std::f64::consts::PI;

use super::psf::Psf;

/// h ∗ (one display pixel): a (W+1)×(W+1) array, energy kept (the box sums to 1).
pub fn system_psf(psf: &Psf) -> Vec<f64> {
    let w = psf.window;
    let n = w + 1;
    let mut out = vec![0.0; n * n];
    for y in 0..w {
        for x in 0..w {
            let v = psf.cells[y * w + x] / 4.0;
            for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                out[(y + dy) * n + x + dx] += v;
            }
        }
    }
    out
}

/// MTF along x of a square `n`×`n` cell array of pitch `cell_rad`, at
/// `freqs_cpd` (cycles per degree): |DTFT of the column sums| over the total
/// light (cells plus `veil`).
pub fn mtf_x(cells: &[f64], n: usize, veil: f64, cell_rad: f64, freqs_cpd: &[f64]) -> Vec<f64> {
    let marginal: Vec<f64> = (0..n)
        .map(|x| (0..n).map(|y| cells[y * n + x]).sum())
        .collect();
    let total: f64 = marginal.iter().sum::<f64>() + veil;
    let centre = (n as f64 - 1.0) / 2.0;
    freqs_cpd
        .iter()
        .map(|f| {
            let cycles_per_rad = f * 180.0 / PI;
            let (mut re, mut im) = (0.0, 0.0);
            for (x, v) in marginal.iter().enumerate() {
                let a = -2.0 * PI * cycles_per_rad * (x as f64 - centre) * cell_rad;
                re += v * a.cos();
                im += v * a.sin();
            }
            re.hypot(im) / total
        })
        .collect()
}

/// MTF of the system PSF (retinal PSF ∗ pixel) along x.
pub fn system_mtf(psf: &Psf, cell_rad: f64, freqs_cpd: &[f64]) -> Vec<f64> {
    mtf_x(
        &system_psf(psf),
        psf.window + 1,
        psf.veil,
        cell_rad,
        freqs_cpd,
    )
}

/// Central row of the system PSF through the on-axis cell (a cross-section).
pub fn cross_section(psf: &Psf) -> Vec<f64> {
    let w = psf.window;
    let c = w / 2;
    psf.cells[c * w..(c + 1) * w].to_vec()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::propagate::mft_cells;
    use crate::pupil::{PupilGrid, pupil_field};
    use nedrt_core::calib::Calibration;

    #[test]
    fn pixel_box_mtf_is_cos_of_half_the_pixel() {
        // A delta PSF: the system MTF is the pixel's |cos(π f Δθ)| (2-cell box).
        let dtheta = 1.5226e-4;
        let mut cells = vec![0.0; 9];
        cells[4] = 1.0;
        let p = Psf {
            window: 3,
            cells,
            veil: 0.0,
        };
        let f = 30.0;
        let got = system_mtf(&p, dtheta, &[0.0, f]);
        let want = (PI * f * 180.0 / PI * dtheta).cos().abs();
        assert!((got[0] - 1.0).abs() < 1e-12);
        assert!((got[1] - want).abs() < 1e-12, "{} vs {want}", got[1]);
        // A veil lowers every non-zero frequency by its share.
        let hazy = Psf {
            veil: 0.25,
            ..p.clone()
        };
        let m = mtf_x(&hazy.cells, 3, 0.25, dtheta, &[0.0, f]);
        assert!((m[0] - 0.8).abs() < 1e-12);
    }

    #[test]
    fn in_focus_lens_mtf_at_30_cpd_matches_optics_md() {
        // docs/model.md §6, §19: the lens-only in-focus MTF at 30 CPD reads 0.986 from
        // centre samples but 0.884 from cell-integrated ones (the MTF of h on
        // the retinal grid, without the pixel).
        let c = Calibration::default_embedded().expect("calib");
        let grid = PupilGrid::covering(c.aperture_radius_m, 6e-6);
        let q = pupil_field(grid, c.aperture_radius_m, 0.0, None);
        let dtheta = c.retinal_step_rad();
        let w = 161;
        let m = |sub| {
            let cells = mft_cells(&q, grid, 530e-9, w, dtheta, sub);
            mtf_x(&cells, w, 0.0, dtheta, &[30.0])[0]
        };
        let centre = m(1);
        let integrated = m(6);
        assert!((centre - 0.986).abs() < 0.01, "centre-sampled {centre}");
        assert!((integrated - 0.884).abs() < 0.01, "integrated {integrated}");
    }
}
