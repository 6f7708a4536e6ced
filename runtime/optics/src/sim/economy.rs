//! Economies of the PSF model (docs/model.md §8): a PSF window cut to the
//! energy it must hold, and perception on the 1-arcmin display grid. The
//! fidelity study (`nedrt tradeoff`) prices each against the exhaustive
//! model.

use super::Image;
use super::convolve::PreparedKernel;
use super::wiener::display_kernel;
use crate::Psf;
use crate::propagate::{centred_window_energies, crop_centred};

/// `psf` cut to the smallest centred window holding `energy` of the light
/// (the rest joins the veil), as the PSF model's rule 5 does on a period.
pub fn shrink_window(psf: &Psf, energy: f64) -> Psf {
    let e = centred_window_energies(&psf.cells, psf.window);
    let inside = e.last().copied().unwrap_or(0.0);
    let half = e.iter().position(|&v| v >= energy).unwrap_or(e.len() - 1);
    let window = 2 * half + 1;
    Psf {
        window,
        cells: crop_centred(&psf.cells, psf.window, window),
        veil: psf.veil + (inside - e[half]).max(0.0),
    }
}

/// The perceived image on a 1-arcmin grid (one cell per display pixel,
/// the PSF taken to the display grid by the exact 2×2 relation), shown
/// on the 0.5-arcmin grid by pixel replication so it is scored like
/// every other setting.
pub fn perceive_one_arcmin(display: &Image, psfs: &[Psf]) -> Image {
    let means = display.plane_means();
    let planes = display
        .planes()
        .zip(psfs)
        .zip(means)
        .map(|((plane, psf), mean)| {
            let (k, side) = display_kernel(psf);
            let mut out = PreparedKernel::new(&k, side, display.width, display.height).apply(plane);
            let veil = (psf.veil * mean) as f32;
            out.iter_mut().for_each(|v| *v += veil);
            out
        })
        .collect();
    Image::from_planes(display.width, display.height, planes).up2()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ring_psf(window: usize) -> Psf {
        let c = (window / 2) as isize;
        let mut cells: Vec<f64> = (0..window * window)
            .map(|i| {
                let (x, y) = ((i % window) as isize - c, (i / window) as isize - c);
                1.0 / (1.0 + (x * x + y * y) as f64)
            })
            .collect();
        let s: f64 = cells.iter().sum();
        cells.iter_mut().for_each(|v| *v *= 0.98 / s);
        Psf {
            window,
            cells,
            veil: 0.02,
        }
    }

    #[test]
    fn shrinking_keeps_the_energy_and_meets_the_target() {
        let p = ring_psf(41);
        let s = shrink_window(&p, 0.9);
        assert!(s.window < 41 && s.window % 2 == 1);
        let total = s.cells.iter().sum::<f64>() + s.veil;
        assert!((total - 1.0).abs() < 1e-12);
        assert!(s.cells.iter().sum::<f64>() >= 0.9 - 1e-12);
        let smaller = shrink_window(&p, 0.0);
        assert_eq!(smaller.window, 1);
        // A target the window cannot hold keeps the whole window.
        assert_eq!(shrink_window(&p, 0.999).window, 41);
    }

    #[test]
    fn mixing_centres_windows_and_conserves_energy() {
        let (a, b) = (ring_psf(5), ring_psf(9));
        let m = Psf::weighted_sum([(&a, 0.25), (&b, 0.75)]).expect("terms");
        assert_eq!(m.window, 9);
        assert!((m.cells.iter().sum::<f64>() + m.veil - 1.0).abs() < 1e-12);
        let peak = m.cells.iter().copied().fold(0.0, f64::max);
        assert_eq!(m.cells[4 * 9 + 4], peak);
    }

    #[test]
    fn one_arcmin_perception_of_a_point_psf_is_the_display_image() {
        let mut cells = vec![0.0; 9];
        cells[4] = 1.0;
        let psf = Psf {
            window: 3,
            cells,
            veil: 0.0,
        };
        let planes: Vec<Vec<f32>> = (0..3)
            .map(|c| {
                (0..64)
                    .map(|i| ((i * (c + 2)) % 11) as f32 / 10.0)
                    .collect()
            })
            .collect();
        let im = Image::from_planes(8, 8, planes);
        let out = perceive_one_arcmin(&im, &[psf.clone(), psf.clone(), psf]);
        let up = im.up2();
        for (a, b) in out.data().iter().zip(up.data().iter()) {
            assert!((a - b).abs() < 1e-5);
        }
    }
}
