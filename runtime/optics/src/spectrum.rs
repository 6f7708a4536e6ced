//! Each primary's spectrum (docs/fidelity.md): an OLED primary is a
//! Gaussian of [`PRIMARY_FWHM_NM`], integrated by Gauss–Hermite nodes,
//! the index at each wavelength from a Cauchy fit n = A + B/λ² to the
//! calibration's three channels.

use nedrt_core::calib::Calibration;

/// Full width at half maximum of each primary's emission spectrum (nm):
/// an OLED microdisplay's primaries are 25–40 nm wide; 30 nm is assumed.
pub const PRIMARY_FWHM_NM: f64 = 30.0;

/// Gauss–Hermite nodes (in standard deviations) and weights for a normal
/// distribution: 1 point, or 5 points (exact for polynomials to degree 9).
pub fn spectral_nodes(samples: usize) -> Vec<(f64, f64)> {
    match samples {
        1 => vec![(0.0, 1.0)],
        _ => {
            // Probabilists' Hermite nodes of degree 5 and their weights.
            let a = (5.0 - 10f64.sqrt()).sqrt();
            let b = (5.0 + 10f64.sqrt()).sqrt();
            let wa = (7.0 + 2.0 * 10f64.sqrt()) / 60.0;
            let wb = (7.0 - 2.0 * 10f64.sqrt()) / 60.0;
            vec![(-b, wb), (-a, wa), (0.0, 8.0 / 15.0), (a, wa), (b, wb)]
        }
    }
}

/// Cauchy dispersion n(λ) = A + B/λ², least-squares fit to the channels.
pub fn cauchy_fit(calib: &Calibration) -> (f64, f64) {
    let xs: Vec<f64> = calib
        .channels
        .iter()
        .map(|c| c.wavelength_m.powi(-2))
        .collect();
    let ys: Vec<f64> = calib.channels.iter().map(|c| c.index).collect();
    let n = xs.len() as f64;
    let (mx, my) = (xs.iter().sum::<f64>() / n, ys.iter().sum::<f64>() / n);
    let sxy: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = xs.iter().map(|x| (x - mx).powi(2)).sum();
    let b = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    (my - b * mx, b)
}

/// The calibration with every channel moved by `offset_sd` standard
/// deviations of its spectrum, the index following the Cauchy fit (the
/// fit's residual at the channel's own wavelength is kept, so offset 0
/// is the calibration itself).
pub fn shifted_calibration(calib: &Calibration, offset_sd: f64) -> Calibration {
    let (a, b) = cauchy_fit(calib);
    let sigma_m = PRIMARY_FWHM_NM * 1e-9 / (8.0 * 2f64.ln()).sqrt();
    let mut c = calib.clone();
    for ch in &mut c.channels {
        let residual = ch.index - (a + b / ch.wavelength_m.powi(2));
        ch.wavelength_m += offset_sd * sigma_m;
        ch.index = a + b / ch.wavelength_m.powi(2) + residual;
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn five_point_rule_integrates_the_normal_moments() {
        let n = spectral_nodes(5);
        let moment = |k: i32| n.iter().map(|(x, w)| w * x.powi(k)).sum::<f64>();
        assert!((moment(0) - 1.0).abs() < 1e-12);
        assert!(moment(1).abs() < 1e-12);
        assert!((moment(2) - 1.0).abs() < 1e-12);
        assert!((moment(4) - 3.0).abs() < 1e-12);
        assert!((moment(8) - 105.0).abs() < 1e-9);
        assert_eq!(spectral_nodes(1), vec![(0.0, 1.0)]);
    }

    #[test]
    fn zero_shift_is_the_calibration_and_dispersion_is_normal() {
        let c = Calibration::default_embedded().expect("calib");
        assert_eq!(shifted_calibration(&c, 0.0).channels, c.channels);
        let (_, b) = cauchy_fit(&c);
        assert!(b > 0.0, "index falls with wavelength");
        let up = shifted_calibration(&c, 1.0);
        for (a, z) in c.channels.iter().zip(&up.channels) {
            assert!(z.wavelength_m > a.wavelength_m && z.index < a.index);
        }
    }
}
