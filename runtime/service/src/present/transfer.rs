//! The panel's transfer curve: linear intensity in [0, 1] to 8-bit code
//! values, per channel. The panel emits code^γ, so intensity x is sent as
//! round(255·x^(1/γ)). The curve is held as the 255 decision thresholds
//! t_c = ((c − ½)/255)^γ: the code of x is the number of thresholds ≤ x.
//! Comparisons alone decide the code, so every implementation of this
//! table (this one, the recorder, a GPU shader) gives identical codes, and
//! a measured panel LUT fits the same form.

use nedrt_core::Image;
use nedrt_core::calib::PanelSettings;

/// Code values of an 8-bit panel.
pub const CODES: usize = 256;

/// Bins of the direct lookup that starts each search.
pub const BINS: usize = 4096;

/// Per-channel encoding thresholds of the panel's transfer curve.
#[derive(Debug, Clone, PartialEq)]
pub struct Transfer {
    /// `thresholds[c][k]`: the smallest intensity sent as code k + 1.
    thresholds: [Vec<f32>; 3],
    /// `start[c][i]`: the code of i/BINS; the code of any x in the bin is
    /// at least this, and a few threshold steps (several only in the
    /// steep dark end of a gamma curve) reach it exactly.
    start: [Vec<u8>; 3],
}

impl Transfer {
    /// A power-law panel with one exponent per channel.
    pub fn from_gamma(gamma: [f64; 3]) -> Self {
        let table = |g: f64| -> Vec<f32> {
            (1..CODES)
                .map(|c| ((c as f64 - 0.5) / (CODES - 1) as f64).powf(g) as f32)
                .collect()
        };
        let thresholds = gamma.map(table);
        let start = std::array::from_fn(|c| {
            let t: &Vec<f32> = &thresholds[c];
            (0..=BINS)
                .map(|i| t.partition_point(|&th| th <= i as f32 / BINS as f32) as u8)
                .collect()
        });
        Self { thresholds, start }
    }

    /// The calibration's panel (which has been validated to three channels).
    pub fn from_panel(panel: &PanelSettings) -> Self {
        let g = |i: usize| panel.transfer_gamma.get(i).copied().unwrap_or(1.0);
        Self::from_gamma([g(0), g(1), g(2)])
    }

    /// The decision thresholds of `channel` (255, ascending): what a GPU
    /// encoder searches to give the same codes.
    pub fn thresholds(&self, channel: usize) -> &[f32] {
        &self.thresholds[channel]
    }

    /// The code of i/[`BINS`] for i in 0..=BINS in `channel`: where the
    /// search for any x in bin i starts (the GPU encoder starts there too).
    pub fn start_codes(&self, channel: usize) -> &[u8] {
        &self.start[channel]
    }

    /// The code of linear intensity `x` in channel `channel`; values outside
    /// [0, 1] clamp (the panel cannot show them), NaN is black.
    pub fn code(&self, channel: usize, x: f32) -> u8 {
        if x.is_nan() || x <= 0.0 {
            return 0;
        }
        let t = &self.thresholds[channel];
        // Scaling by a power of two is exact, so bin/BINS ≤ x.
        let bin = ((x * BINS as f32) as usize).min(BINS);
        let mut code = self.start[channel][bin] as usize;
        while code < t.len() && t[code] <= x {
            code += 1;
        }
        code as u8
    }

    /// Encodes a planar linear frame as interleaved RGBA8 (alpha 255).
    pub fn encode_rgba8(&self, frame: &Image, out: &mut Vec<u8>) {
        let n = frame.width * frame.height;
        out.clear();
        out.resize(4 * n, 255);
        for c in 0..3 {
            let plane = frame.plane(c);
            for (px, &x) in out.chunks_exact_mut(4).zip(plane) {
                px[c] = self.code(c, x);
            }
        }
    }

    /// The intensity the panel emits for `code` (the curve's inverse), for
    /// reports and tests.
    pub fn emitted(gamma: f64, code: u8) -> f64 {
        (code as f64 / (CODES - 1) as f64).powf(gamma)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn codes_are_the_rounded_inverse_power_law() {
        let t = Transfer::from_gamma([2.2, 1.0, 2.4]);
        assert_eq!(t.code(0, 0.0), 0);
        assert_eq!(t.code(0, 1.0), 255);
        assert_eq!(t.code(0, 2.0), 255);
        assert_eq!(t.code(0, -1.0), 0);
        assert_eq!(t.code(0, f32::NAN), 0);
        // Linear channel: round(255·x).
        for k in 0..=255u32 {
            assert_eq!(t.code(1, k as f32 / 255.0), k as u8);
        }
        // Mid-grey at γ = 2.2: 0.5^(1/2.2)·255 = 186.08.
        assert_eq!(t.code(0, 0.5), 186);
        // γ = 2.4: 0.5^(1/2.4)·255 = 190.5…: a threshold case decided by the table.
        let exact = 0.5f64.powf(1.0 / 2.4) * 255.0;
        assert_eq!(t.code(2, 0.5), exact.round() as u8);
    }

    proptest! {
        #[test]
        fn encoding_is_monotone_and_within_half_a_code(x in 0.0f32..=1.0, y in 0.0f32..=1.0, g in 1.0f64..3.0) {
            let t = Transfer::from_gamma([g, g, g]);
            let (lo, hi) = if x <= y { (x, y) } else { (y, x) };
            prop_assert!(t.code(0, lo) <= t.code(0, hi));
            let ideal = (x as f64).powf(1.0 / g) * 255.0;
            prop_assert!((t.code(0, x) as f64 - ideal).abs() <= 0.5 + 1e-3);
        }

        #[test]
        fn emitted_intensity_round_trips_through_the_code(code in 0u8..=255, g in 1.0f64..3.0) {
            let t = Transfer::from_gamma([g, g, g]);
            prop_assert_eq!(t.code(0, Transfer::emitted(g, code) as f32), code);
        }
    }

    #[test]
    fn the_bin_lookup_equals_the_full_threshold_search() {
        let t = Transfer::from_gamma([2.2, 1.0, 3.5]);
        for c in 0..3 {
            for i in 0..=200_000u32 {
                let x = i as f32 / 200_000.0;
                let full = t.thresholds[c].partition_point(|&th| th <= x) as u8;
                assert_eq!(t.code(c, x), full, "channel {c}, x = {x}");
            }
            // Every threshold itself and its neighbours.
            for &th in &t.thresholds[c] {
                for x in [
                    th,
                    f32::from_bits(th.to_bits() - 1),
                    f32::from_bits(th.to_bits() + 1),
                ] {
                    let full = t.thresholds[c].partition_point(|&v| v <= x) as u8;
                    assert_eq!(t.code(c, x), full, "channel {c}, x = {x}");
                }
            }
        }
    }

    #[test]
    fn frames_encode_to_interleaved_rgba() {
        let t = Transfer::from_gamma([1.0, 1.0, 1.0]);
        let frame = Image::rgb(2, 1, vec![0.0, 1.0, 0.5, 0.25, 1.0, 0.0]);
        let mut out = Vec::new();
        t.encode_rgba8(&frame, &mut out);
        assert_eq!(out, vec![0, 128, 255, 255, 255, 64, 0, 255]);
    }
}
