//! Focus cues measured on perceived images: how sharp the eye sees a frame
//! at each accommodation, relative to the input, in a band of spatial
//! frequency (the image-domain counterpart of the paper's Fig. 5b–d, which
//! plots MTFs of the PSFs alone).
//!
//! PSNR against the sharp image cannot show focus cues: an all-sharp design
//! scores well and gives the eye nothing to focus on. What drives
//! accommodation is contrast that rises and falls with focus, so this module
//! measures band contrast of the perceived image (docs/evaluation.md):
//!
//! - S_f = sqrt(P_f(perceived) / P_f(up2(sharp))), where P_f is the power of
//!   (image − its mean) × a separable Hann window, summed over the annulus
//!   f·[2^(−1/4), 2^(1/4)] (a half-octave band) of the 2-D spectrum on the
//!   retinal grid; one S per colour channel, averaged over the channels.
//! - FC_f(D) = S_f(D) − ½(S_f(D − 0.5) + S_f(D + 0.5)): how far sharpness
//!   falls half a diopter away, the one existing side at the range's ends.
//!
//! The Hann window keeps the frame's edges (where reflection padding meets
//! the image) from leaking broadband power into the band; the half-octave
//! band is wide enough to hold many spectral bins on small frames and narrow
//! enough that 5 and 10 CPD do not overlap.

use num_complex::Complex32 as c32;

use super::convolve::Fft2;
use nedrt_core::image::Image;

/// The frequencies at which focus cues are reported, cycles per degree:
/// 5 CPD carries the coarse detail that drives accommodation, 10 CPD the
/// finer detail (the paper's Fig. 5c–d).
pub const FOCUS_FREQUENCIES_CPD: [f64; 2] = [5.0, 10.0];

/// Half-width of the band around each frequency, in octaves (the band is
/// f·[2^(−1/4), 2^(1/4)], half an octave wide).
pub const BAND_HALF_WIDTH_OCTAVES: f64 = 0.25;

/// Step of the accommodation sweep, diopters (the Wiener average's step, so
/// the sweep's PSFs are mostly ones the simulator already computes).
pub const SWEEP_STEP_D: f64 = 0.1;

/// How far from a main depth the focus-cue score looks, diopters: half the
/// 1 D spacing of the main depths, where the target is blurred (the
/// intermediate depths).
pub const CUE_OFFSET_D: f64 = 0.5;

/// A band with less power than this fraction of the sharp image's total
/// (windowed, mean-free) power has nothing to measure: its S is undefined.
const EMPTY_BAND_FRACTION: f64 = 1e-10;

/// Depths closer than this are the same depth, diopters.
const SAME_DEPTH_D: f64 = 1e-9;

/// Band powers of one image: `band[channel][frequency]`, and each channel's
/// total power (mean-free, windowed), which decides whether a band is empty.
#[derive(Debug, Clone, PartialEq)]
pub struct BandPowers {
    pub band: Vec<Vec<f64>>,
    pub total: Vec<f64>,
}

/// Measures band powers of retinal-grid images of one size: the transform,
/// the window and the bins of each band, planned once.
#[derive(Debug)]
pub struct SharpnessMeter {
    fft: Fft2,
    window_x: Vec<f32>,
    window_y: Vec<f32>,
    /// Per frequency: (spectrum index, weight) of the bins in its band; the
    /// weight is 2 for half-spectrum bins that stand for a conjugate pair.
    bands: Vec<Vec<(usize, f64)>>,
    frequencies_cpd: Vec<f64>,
}

/// Hann window over `n` samples, sin²(π(i + ½)/n): symmetric about the
/// centre and never zero, so no sample is thrown away.
fn hann(n: usize) -> Vec<f32> {
    (0..n)
        .map(|i| {
            let s = (std::f64::consts::PI * (i as f64 + 0.5) / n as f64).sin();
            (s * s) as f32
        })
        .collect()
}

impl SharpnessMeter {
    /// A meter for `width`×`height` images on a grid of `cell_rad` (the
    /// retinal step Δθ) at `frequencies_cpd`.
    pub fn new(width: usize, height: usize, cell_rad: f64, frequencies_cpd: &[f64]) -> Self {
        let fft = Fft2::new(width, height);
        // cycles per cell × (π/180)/Δθ = cycles per degree.
        let cpd_per_cycle_per_cell = std::f64::consts::PI / 180.0 / cell_rad;
        let bins = fft.bins();
        let lo = 2f64.powf(-BAND_HALF_WIDTH_OCTAVES);
        let hi = 2f64.powf(BAND_HALF_WIDTH_OCTAVES);
        let bands = frequencies_cpd
            .iter()
            .map(|&f| {
                let mut band = Vec::new();
                for kx in 0..bins {
                    // Columns 0 and (for even widths) width/2 have no mirror
                    // in the half spectrum; every other one stands for two bins.
                    let weight = if kx == 0 || 2 * kx == width { 1.0 } else { 2.0 };
                    let fx = kx as f64 / width as f64;
                    for ky in 0..height {
                        let signed = if 2 * ky > height {
                            ky as f64 - height as f64
                        } else {
                            ky as f64
                        };
                        let fy = signed / height as f64;
                        let cpd = fx.hypot(fy) * cpd_per_cycle_per_cell;
                        if cpd >= f * lo && cpd <= f * hi {
                            band.push((kx * height + ky, weight));
                        }
                    }
                }
                band
            })
            .collect();
        Self {
            fft,
            window_x: hann(width),
            window_y: hann(height),
            bands,
            frequencies_cpd: frequencies_cpd.to_vec(),
        }
    }

    /// Whether the meter was planned for `width`×`height` images.
    pub fn has_size(&self, width: usize, height: usize) -> bool {
        (self.fft.width, self.fft.height) == (width, height)
    }

    pub fn frequencies_cpd(&self) -> &[f64] {
        &self.frequencies_cpd
    }

    /// Number of spectral bins (half spectrum) in each band.
    pub fn band_bins(&self) -> Vec<usize> {
        self.bands.iter().map(Vec::len).collect()
    }

    /// Band powers of every channel of `image` (which must have the meter's size).
    pub fn band_powers(&self, image: &Image) -> BandPowers {
        assert!(
            image.width == self.fft.width && image.height == self.fft.height,
            "sharpness meter planned for {}×{}, image is {}×{}",
            self.fft.width,
            self.fft.height,
            image.width,
            image.height
        );
        let w = image.width;
        let mut band = Vec::with_capacity(image.channels());
        let mut total = Vec::with_capacity(image.channels());
        for plane in image.planes() {
            let mean = plane.iter().map(|v| *v as f64).sum::<f64>() / plane.len().max(1) as f64;
            let windowed: Vec<f32> = plane
                .iter()
                .enumerate()
                .map(|(i, v)| {
                    ((*v as f64 - mean) * (self.window_y[i / w] * self.window_x[i % w]) as f64)
                        as f32
                })
                .collect();
            let spectrum = self.fft.forward(&windowed);
            let power = |c: &c32| (c.re as f64).powi(2) + (c.im as f64).powi(2);
            // Parseval over the half spectrum (same weights as the bands).
            let h = self.fft.height;
            total.push(
                spectrum
                    .iter()
                    .enumerate()
                    .map(|(i, c)| {
                        let kx = i / h;
                        let weight = if kx == 0 || 2 * kx == w { 1.0 } else { 2.0 };
                        weight * power(c)
                    })
                    .sum(),
            );
            band.push(
                self.bands
                    .iter()
                    .map(|b| b.iter().map(|&(i, wgt)| wgt * power(&spectrum[i])).sum())
                    .collect(),
            );
        }
        BandPowers { band, total }
    }
}

/// S per frequency for one image: sqrt(band power of `perceived` / band
/// power of `sharp`) per channel, averaged over the channels whose sharp
/// band holds something to measure; `None` where no channel does.
pub fn sharpness(perceived: &BandPowers, sharp: &BandPowers) -> Vec<Option<f64>> {
    let n_freq = sharp.band.first().map_or(0, Vec::len);
    (0..n_freq)
        .map(|fi| {
            let ratios: Vec<f64> = sharp
                .band
                .iter()
                .zip(&sharp.total)
                .zip(&perceived.band)
                .filter(|((s, total), _)| s[fi] > EMPTY_BAND_FRACTION * **total && s[fi] > 0.0)
                .map(|((s, _), p)| (p[fi] / s[fi]).sqrt())
                .collect();
            (!ratios.is_empty()).then(|| ratios.iter().sum::<f64>() / ratios.len() as f64)
        })
        .collect()
}

/// The mean of the defined values, `None` if there are none (images whose
/// band held nothing do not count towards the average).
pub fn mean_defined(values: impl IntoIterator<Item = Option<f64>>) -> Option<f64> {
    let (sum, n) = values
        .into_iter()
        .flatten()
        .fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// A sampled curve S(D): accommodation in diopters (ascending) and value,
/// undefined samples left out.
#[derive(Debug, Clone, PartialEq)]
pub struct Curve {
    pub points: Vec<(f64, f64)>,
}

/// A local maximum of a curve.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Peak {
    /// Where the maximum lies: the vertex of the parabola through the
    /// sample and its two neighbours (the sample itself at the range's ends).
    pub accommodation_d: f64,
    /// The curve's largest sample there.
    pub value: f64,
    /// The maximum is the first or last sample: the curve may rise further
    /// outside the sampled range.
    pub at_range_end: bool,
}

impl Curve {
    /// A curve from depths and values (`None` values are left out).
    pub fn new(depths_d: &[f64], values: &[Option<f64>]) -> Self {
        Self {
            points: depths_d
                .iter()
                .zip(values)
                .filter_map(|(d, v)| v.map(|v| (*d, v)))
                .collect(),
        }
    }

    /// S at `d` by linear interpolation between samples; `None` outside the
    /// sampled range.
    pub fn at(&self, d: f64) -> Option<f64> {
        let p = &self.points;
        let i = p.iter().position(|(x, _)| *x >= d - SAME_DEPTH_D)?;
        let (x1, y1) = p[i];
        if (x1 - d).abs() <= SAME_DEPTH_D {
            return Some(y1);
        }
        let (x0, y0) = *p.get(i.checked_sub(1)?)?;
        Some(y0 + (y1 - y0) * (d - x0) / (x1 - x0))
    }

    /// FC(D) = S(D) − ½(S(D − offset) + S(D + offset)); where one side lies
    /// outside the sampled range, S(D) minus the other side alone.
    pub fn focus_cue_score(&self, d: f64, offset_d: f64) -> Option<f64> {
        let centre = self.at(d)?;
        let sides: Vec<f64> = [d - offset_d, d + offset_d]
            .into_iter()
            .filter_map(|x| self.at(x))
            .collect();
        (!sides.is_empty()).then(|| centre - sides.iter().sum::<f64>() / sides.len() as f64)
    }

    /// Every local maximum, in order of depth: a sample above its left
    /// neighbour (or the first) whose run of equal samples is followed by a
    /// lower one (or the end): one per peak or plateau.
    pub fn local_maxima(&self) -> Vec<Peak> {
        let p = &self.points;
        let n = p.len();
        let mut peaks = Vec::new();
        for k in 0..n {
            let rises_into = k == 0 || p[k].1 > p[k - 1].1;
            let v = p[k].1;
            let falls_after = p[k..]
                .iter()
                .find(|(_, y)| *y != v)
                .is_none_or(|(_, y)| *y < v);
            if !(rises_into && falls_after) {
                continue;
            }
            let at_range_end = k == 0 || k + 1 == n;
            let accommodation_d = if at_range_end {
                p[k].0
            } else {
                parabola_vertex(p[k - 1], p[k], p[k + 1])
            };
            peaks.push(Peak {
                accommodation_d,
                value: v,
                at_range_end,
            });
        }
        peaks
    }

    /// The local maximum nearest to `d`.
    pub fn nearest_peak(&self, d: f64) -> Option<Peak> {
        self.local_maxima().into_iter().min_by(|a, b| {
            (a.accommodation_d - d)
                .abs()
                .total_cmp(&(b.accommodation_d - d).abs())
        })
    }
}

/// Abscissa of the vertex of the parabola through three points (the middle
/// one the largest), kept between the outer two's midpoints with the middle.
fn parabola_vertex((x0, y0): (f64, f64), (x1, y1): (f64, f64), (x2, y2): (f64, f64)) -> f64 {
    let num = (x1 - x0).powi(2) * (y1 - y2) - (x1 - x2).powi(2) * (y1 - y0);
    let den = (x1 - x0) * (y1 - y2) - (x1 - x2) * (y1 - y0);
    if den == 0.0 || !num.is_finite() || !den.is_finite() {
        return x1;
    }
    (x1 - 0.5 * num / den).clamp(0.5 * (x0 + x1), 0.5 * (x1 + x2))
}

#[cfg(test)]
mod tests;
