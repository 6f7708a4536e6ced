//! Image quality as docs/model.md §16 defines it: PSNR with peak 1 over the whole
//! frame, and SSIM (Wang et al. 2004) with an 11×11 Gaussian window
//! (σ = 1.5), K1 = 0.01, K2 = 0.03, data range 1, population covariance,
//! per channel, averaged over the windows inside the frame (a 5-sample border
//! excluded): scikit-image's `structural_similarity(gaussian_weights=True,
//! use_sample_covariance=False, data_range=1)`, checked against it in tests.

use rayon::prelude::*;

use nedrt_core::image::Image;

/// Peak signal-to-noise ratio in dB (peak 1) over all channels and pixels.
pub fn psnr(a: &Image, b: &Image) -> f64 {
    assert_same_shape(a, b);
    let n = (a.width * a.height * a.channels()) as f64;
    let sse: f64 = a
        .planes()
        .zip(b.planes())
        .map(|(p, q)| {
            p.iter()
                .zip(q)
                .map(|(x, y)| ((x - y) as f64).powi(2))
                .sum::<f64>()
        })
        .sum();
    if sse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (n / sse).log10()
    }
}

const SSIM_RADIUS: usize = 5;
const SSIM_SIGMA: f64 = 1.5;

fn gaussian_taps() -> [f64; 2 * SSIM_RADIUS + 1] {
    let mut t = [0.0; 2 * SSIM_RADIUS + 1];
    for (i, v) in t.iter_mut().enumerate() {
        let x = i as f64 - SSIM_RADIUS as f64;
        *v = (-x * x / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let s: f64 = t.iter().sum();
    t.iter_mut().for_each(|v| *v /= s);
    t
}

/// Mean SSIM over channels. Frames smaller than 11×11 have no interior window: NaN.
pub fn ssim(a: &Image, b: &Image) -> f64 {
    assert_same_shape(a, b);
    let n = (a.width * a.height).max(1);
    let per: Vec<f64> = a
        .data()
        .par_chunks(n)
        .zip(b.data().par_chunks(n))
        .map(|(p, q)| ssim_plane(p, q, a.width, a.height))
        .collect();
    per.iter().sum::<f64>() / per.len() as f64
}

/// SSIM of one plane.
pub fn ssim_plane(x: &[f32], y: &[f32], w: usize, h: usize) -> f64 {
    let r = SSIM_RADIUS;
    if w <= 2 * r || h <= 2 * r {
        return f64::NAN;
    }
    let taps = gaussian_taps();
    let (ow, oh) = (w - 2 * r, h - 2 * r);
    // Horizontal pass over all rows for the five moments, valid columns only.
    let moments = |f: &dyn Fn(usize) -> f64| -> Vec<f64> {
        let mut tmp = vec![0.0; h * ow];
        for row in 0..h {
            for c in 0..ow {
                tmp[row * ow + c] = taps
                    .iter()
                    .enumerate()
                    .map(|(k, t)| t * f(row * w + c + k))
                    .sum();
            }
        }
        let mut out = vec![0.0; oh * ow];
        for row in 0..oh {
            for c in 0..ow {
                out[row * ow + c] = taps
                    .iter()
                    .enumerate()
                    .map(|(k, t)| t * tmp[(row + k) * ow + c])
                    .sum();
            }
        }
        out
    };
    let xv = |i: usize| x[i] as f64;
    let yv = |i: usize| y[i] as f64;
    let ux = moments(&xv);
    let uy = moments(&yv);
    let uxx = moments(&|i| xv(i) * xv(i));
    let uyy = moments(&|i| yv(i) * yv(i));
    let uxy = moments(&|i| xv(i) * yv(i));
    let c1 = (0.01f64).powi(2);
    let c2 = (0.03f64).powi(2);
    let mut total = 0.0;
    for i in 0..ow * oh {
        let (mx, my) = (ux[i], uy[i]);
        let vx = uxx[i] - mx * mx;
        let vy = uyy[i] - my * my;
        let vxy = uxy[i] - mx * my;
        total +=
            ((2.0 * mx * my + c1) * (2.0 * vxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
    }
    total / (ow * oh) as f64
}

fn assert_same_shape(a: &Image, b: &Image) {
    assert!(
        a.width == b.width && a.height == b.height && a.channels() == b.channels(),
        "metrics need images of one shape"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_of_a_known_error() {
        let a = Image::from_planes(2, 2, vec![vec![0.5; 4]; 3]);
        let mut b = a.clone();
        b.planes_mut()
            .for_each(|p| p.iter_mut().for_each(|v| *v += 0.1));
        assert!((psnr(&a, &b) - 20.0).abs() < 1e-5);
        assert!(psnr(&a, &a).is_infinite());
    }

    #[test]
    fn ssim_of_identical_images_is_one_and_gaussian_is_normalised() {
        let a = Image::from_planes(
            16,
            12,
            vec![(0..192).map(|i| (i % 7) as f32 / 7.0).collect(); 3],
        );
        assert!((ssim(&a, &a) - 1.0).abs() < 1e-12);
        assert!((gaussian_taps().iter().sum::<f64>() - 1.0).abs() < 1e-15);
        assert!(ssim(&Image::zeros(10, 10, 3), &Image::zeros(10, 10, 3)).is_nan());
    }

    /// Values from scikit-image 0.26 on the same inputs (tools/golden/make_metric_golden.py).
    #[test]
    fn matches_scikit_image() {
        let text = include_str!("../../../../tests/golden/metrics.json");
        let v: serde_json::Value = serde_json::from_str(text).expect("json");
        for case in v["cases"].as_array().expect("cases") {
            let (w, h) = (
                case["width"].as_u64().expect("w") as usize,
                case["height"].as_u64().expect("h") as usize,
            );
            let planes = |key: &str| -> Vec<Vec<f32>> {
                case[key]
                    .as_array()
                    .expect("planes")
                    .iter()
                    .map(|p| {
                        p.as_array()
                            .expect("plane")
                            .iter()
                            .map(|x| x.as_f64().expect("f") as f32)
                            .collect()
                    })
                    .collect()
            };
            let a = Image::from_planes(w, h, planes("a"));
            let b = Image::from_planes(w, h, planes("b"));
            let s = case["ssim"].as_f64().expect("ssim");
            let p = case["psnr"].as_f64().expect("psnr");
            assert!(
                (ssim(&a, &b) - s).abs() < 1e-6,
                "ssim {} vs skimage {s}",
                ssim(&a, &b)
            );
            assert!(
                (psnr(&a, &b) - p).abs() < 1e-4,
                "psnr {} vs skimage {p}",
                psnr(&a, &b)
            );
        }
    }
}
