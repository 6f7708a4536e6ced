//! Wiener deconvolution preprocessing at display resolution (docs/model.md §13):
//! I_d = clamp(F⁻¹{G·F{I}}, 0, 1), G = H̄*/(|H̄|² + K) scaled to unit gain at
//! zero frequency, H̄ the system PSF averaged over the accommodation range
//! and taken to the display grid by the exact 2×2 relation
//! down2(up2(x) ∗ h) = x ∗ k.

use std::sync::Arc;

use num_complex::Complex32 as c32;

use rayon::prelude::*;

use super::SimError;
use super::convolve::{Fft2, SizeCache};
use crate::Psf;
use nedrt_core::image::{Image, extend_plane};
use nedrt_core::preprocess::{Preprocess, PreprocessError, check_frame};

/// Display-grid kernel k of a retinal PSF h (odd window W, centred):
/// k[n, m] = ¼ Σ_{a,b ∈ {−1,0,1}} w_a w_b h[2n + a, 2m + b], w = (1, 2, 1).
/// It follows from up2 (a pixel fills cells 2i, 2i+1) and down2 (the mean of
/// a 2×2 block); Σk = Σh. Returns (kernel, side), side odd.
pub fn display_kernel(psf: &Psf) -> (Vec<f64>, usize) {
    let w = psf.window as isize;
    let c = w / 2;
    let half = (c + 1) / 2;
    let side = (2 * half + 1) as usize;
    let weight = |a: isize| if a == 0 { 2.0 } else { 1.0 };
    let h = |y: isize, x: isize| {
        if (0..w).contains(&y) && (0..w).contains(&x) {
            psf.cells[(y * w + x) as usize]
        } else {
            0.0
        }
    };
    let mut k = vec![0.0; side * side];
    for n in -half..=half {
        for m in -half..=half {
            let mut acc = 0.0;
            for a in -1..=1 {
                for b in -1..=1 {
                    acc += weight(a) * weight(b) * h(c + 2 * n + a, c + 2 * m + b);
                }
            }
            k[((n + half) as usize) * side + (m + half) as usize] = acc / 4.0;
        }
    }
    (k, side)
}

/// The w×h first quadrant of a mirrored 2w×2h plane: the frame.
pub(crate) fn first_quadrant(full: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        out.extend_from_slice(&full[y * 2 * w..y * 2 * w + w]);
    }
    out
}

/// A spectrum of the mirrored 2w×2h grid (as [`Fft2`] stores it:
/// transposed, bin (ky, kx) at kx·2h + ky) as the device's DCT filter
/// takes it: its real part at ky < h, kx < w, row-major. Mirror-symmetric
/// kernels have real, even spectra, so DCT-II · gain · DCT-III of the w×h
/// frame is exactly the mirrored filter (docs/gpu-fft.md); a spectrum with
/// an imaginary part beyond round-off (an asymmetric kernel) has no such
/// form and is refused (`channel` names it).
pub(crate) fn dct_plane(
    spectrum: &[c32],
    w: usize,
    h: usize,
    channel: usize,
) -> Result<Vec<f32>, SimError> {
    let rows = 2 * h;
    let peak = spectrum.iter().map(|v| v.norm()).fold(0.0f32, f32::max);
    let imag = spectrum.iter().map(|v| v.im.abs()).fold(0.0f32, f32::max);
    if imag > 1e-4 * peak.max(f32::MIN_POSITIVE) || spectrum.len() < (w + 1) * rows {
        return Err(SimError::Invalid(format!(
            "channel {channel}'s spectrum is not real (|Im| up to {imag:e} of {peak:e}): its kernel is \
             not mirror-symmetric, and the DCT filter cannot apply it"
        )));
    }
    Ok((0..h * w)
        .map(|i| spectrum[(i % w) * rows + i / w].re)
        .collect())
}

/// A Wiener prefilter for one display system: one display-grid kernel per channel.
#[derive(Debug)]
pub struct WienerFilter {
    pub k_reg: f64,
    kernels: Vec<(Vec<f64>, usize, f64)>,
    /// Plans of the frame sizes seen last, newest at the end: the gain
    /// spectra depend only on the size, so frames after the first pay for
    /// two transforms per channel instead of three and no planning.
    plans: SizeCache<WienerPlan>,
}

/// Frame sizes whose plans a filter keeps (a 1080p plan holds 100 MB of
/// gain spectra; the simulator scores images of a few sizes and one
/// latency frame).
const PLANS_KEPT: usize = 4;

/// The prefilter prepared for frames of one size: the FFT of the mirrored
/// 2w×2h frame and each channel's gain G over its half spectrum.
#[derive(Debug)]
pub struct WienerPlan {
    pub width: usize,
    pub height: usize,
    fft: Fft2,
    gains: Vec<Vec<c32>>,
}

impl WienerPlan {
    /// Gains G = H̄*/((|H̄|² + K)·G(0)), so a flat field passes unchanged.
    fn new(kernels: &[(Vec<f64>, usize, f64)], k_reg: f64, width: usize, height: usize) -> Self {
        let fft = Fft2::new(2 * width, 2 * height);
        let k = k_reg as f32;
        let gains = kernels
            .iter()
            .map(|(kernel, side, veil)| {
                let mut hs = fft.kernel_spectrum(kernel, *side);
                hs[0] += c32::new(*veil as f32, 0.0);
                let h0 = hs[0].re;
                let g0 = h0 / (h0 * h0 + k);
                hs.iter_mut()
                    .for_each(|hv| *hv = hv.conj() / ((hv.norm_sqr() + k) * g0));
                hs
            })
            .collect();
        Self {
            width,
            height,
            fft,
            gains,
        }
    }

    /// Any per-channel gains over the half spectrum of `fft`, which must be
    /// the mirrored 2·`width`×2·`height` grid (the linear least-squares
    /// prefilter of `optimal.rs`).
    pub(crate) fn from_gains(fft: Fft2, width: usize, height: usize, gains: Vec<Vec<c32>>) -> Self {
        debug_assert_eq!((fft.width, fft.height), (2 * width, 2 * height));
        Self {
            width,
            height,
            fft,
            gains,
        }
    }

    /// The gains as the device's DCT filter takes them (nedrt-gpu's
    /// `DctFilter`): per channel, `height` rows of `width` values, the
    /// mirrored grid's gain at (ky, kx) for ky < h, kx < w. Mirror-symmetric
    /// kernels have real, even spectra, so DCT-II · gain · DCT-III of the
    /// w×h frame is exactly the mirrored filter (docs/gpu-fft.md); gains
    /// with an imaginary part beyond round-off (an asymmetric kernel) have
    /// no such form and are refused.
    pub fn dct_gains(&self) -> Result<Vec<Vec<f32>>, SimError> {
        self.gains
            .iter()
            .enumerate()
            .map(|(c, g)| dct_plane(g, self.width, self.height, c))
            .collect()
    }

    /// The filter as convolution kernels on the mirrored 2w×2h grid, per
    /// channel (row-major 2h×2w, periodic, origin at [0, 0]): the filtered
    /// frame is the first quadrant of the kernel convolved with the
    /// mirrored frame.
    pub fn mirrored_kernels(&self) -> Vec<Vec<f32>> {
        self.gains
            .iter()
            .map(|g| self.fft.inverse(g.clone()))
            .collect()
    }

    /// The prefiltered frame before the panel's clamp. The frame is
    /// mirrored to 2w×2h, which is exactly periodic, so the FFT's circular
    /// convolution equals convolution of the symmetrically extended frame.
    pub(crate) fn apply_unclamped(&self, image: &Image) -> Image {
        let (w, h) = (self.width, self.height);
        let planes = image
            .planes()
            .zip(&self.gains)
            .map(|(plane, gain)| {
                let extended = extend_plane(plane, w, h, 0, 0, 2 * w, 2 * h);
                let mut spec = self.fft.forward(&extended);
                spec.par_iter_mut().zip(gain).for_each(|(s, g)| *s *= g);
                first_quadrant(&self.fft.inverse(spec), w, h)
            })
            .collect();
        Image::from_planes(w, h, planes)
    }
}

impl WienerFilter {
    /// From the accommodation-averaged retinal PSF of each channel (its
    /// veil, uniform light, enters H̄ at zero frequency) and the constant K.
    pub fn new(mean_psfs: &[Psf], k_reg: f64) -> Self {
        let kernels = mean_psfs
            .iter()
            .map(|p| {
                let (k, side) = display_kernel(p);
                (k, side, p.veil)
            })
            .collect();
        Self {
            k_reg,
            kernels,
            plans: SizeCache::new(PLANS_KEPT),
        }
    }

    /// The warning for a K that cannot sharpen: the prefilter's gain
    /// H̄*(1 + K)/(|H̄|² + K) exceeds 1 only where |H̄| > K (for |H̄| ≤ 1),
    /// so with K ≥ max |H̄| = H̄(0) it attenuates every frequency and is a
    /// blur, worse than no prefilter (docs/stability.md).
    pub fn blur_only_warning(&self) -> Option<String> {
        let h0 = self
            .kernels
            .iter()
            .map(|(k, _, veil)| k.iter().sum::<f64>() + veil)
            .fold(0.0, f64::max);
        // H̄(0) is 1 up to round-off for an energy-conserving system.
        (self.k_reg >= h0 * (1.0 - 1e-9)).then(|| {
            format!(
                "Wiener K = {:e} is at least the system's largest transfer |H(0)| = {h0:.3}: the prefilter amplifies no frequency and only blurs; lower K (nedrt tune-wiener) — see docs/stability.md",
                self.k_reg
            )
        })
    }

    /// Same kernels, another K (for the K search).
    pub fn with_k(&self, k_reg: f64) -> Self {
        Self {
            k_reg,
            kernels: self.kernels.clone(),
            plans: SizeCache::new(PLANS_KEPT),
        }
    }

    /// The plan for `width`×`height` frames, made once per size and kept
    /// for the [`PLANS_KEPT`] sizes used last.
    pub fn plan(&self, width: usize, height: usize) -> Arc<WienerPlan> {
        self.plans.get_or_make(width, height, || {
            WienerPlan::new(&self.kernels, self.k_reg, width, height)
        })
    }

    /// The colour channels it filters.
    pub fn channels(&self) -> usize {
        self.kernels.len()
    }

    /// Prefilters a frame and clamps it to the panel's [0, 1].
    pub fn apply(&self, image: &Image) -> Image {
        self.apply_unclamped(image).clamped()
    }

    /// Prefilters a frame and clamps it, warning when the clamp cuts more
    /// than [`CLIP_WARN_FRACTION`] of the values: the filter rings more
    /// than the panel can show, and the clamp, not K, is then shaping the
    /// image (docs/stability.md). Returns the clipped fraction too.
    pub fn apply_checked(&self, image: &Image) -> (Image, f64) {
        let raw = self.apply_unclamped(image);
        let clipped = clipped_fraction(&raw);
        if let Some(w) = clipping_warning(self.k_reg, clipped) {
            tracing::warn!("{w}");
        }
        (raw.clamped(), clipped)
    }

    /// The prefiltered frame before the panel's clamp (see [`WienerPlan`]).
    pub fn apply_unclamped(&self, image: &Image) -> Image {
        self.plan(image.width, image.height).apply_unclamped(image)
    }
}

/// A Wiener filter as the preprocessing of a display system: what
/// `nedrt sim`, `nedrt eval` and `nedrt run --preprocess ai` put on the panel.
#[derive(Debug, Clone)]
pub struct WienerPrefilter {
    /// The method whose optics the filter inverts ("ai", "doe+wiener").
    pub method: &'static str,
    pub filter: Arc<WienerFilter>,
    /// The clamp warning is given once, not once per frame.
    warned: bool,
}

impl WienerPrefilter {
    pub fn new(method: &'static str, filter: Arc<WienerFilter>) -> Self {
        Self {
            method,
            filter,
            warned: false,
        }
    }
}

impl Preprocess for WienerPrefilter {
    fn describe(&self) -> String {
        format!(
            "Wiener prefilter of {} (K = {:e})",
            self.method, self.filter.k_reg
        )
    }

    fn run(&mut self, input: &Image) -> Result<Image, PreprocessError> {
        check_frame(input, self.filter.kernels.len())?;
        let raw = self.filter.apply_unclamped(input);
        if !self.warned {
            if let Some(w) = clipping_warning(self.filter.k_reg, clipped_fraction(&raw)) {
                tracing::warn!("{w}");
            }
            self.warned = true;
        }
        Ok(raw.clamped())
    }
}

/// Share of the values the panel's clamp cuts, above which a Wiener
/// prefilter warns. docs/stability.md: at the best K the clamp already
/// cuts 14–48 % of the values (the prefilter's sharpening needs more range
/// than the panel has), and the mean PSNR still rises; past half the
/// values (K ≤ 1e-3 on the test images) the clamp, not K, shapes the
/// frame and the PSNR falls by 2–4 dB per decade.
pub const CLIP_WARN_FRACTION: f64 = 0.5;

/// Fraction of the values of `image` outside [0, 1].
pub fn clipped_fraction(image: &Image) -> f64 {
    let n = image.data().len().max(1);
    let out = image
        .planes()
        .flatten()
        .filter(|v| !(0.0..=1.0).contains(*v))
        .count();
    out as f64 / n as f64
}

/// The warning for a frame whose prefilter output clipped `fraction` of
/// its values, if that is over [`CLIP_WARN_FRACTION`].
pub fn clipping_warning(k_reg: f64, fraction: f64) -> Option<String> {
    (fraction > CLIP_WARN_FRACTION).then(|| {
        format!(
            "Wiener prefilter (K = {k_reg:e}) rings: the panel's [0, 1] clamp cut {:.1} % of the frame's values (over {:.0} %); raise K (nedrt tune-wiener) — see docs/stability.md",
            100.0 * fraction,
            100.0 * CLIP_WARN_FRACTION
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::convolve::convolve_symmetric;

    fn psf(w: usize, seed: usize) -> Psf {
        let mut cells: Vec<f64> = (0..w * w)
            .map(|i| (((i + seed) * 7919) % 101) as f64 + 1.0)
            .collect();
        let s: f64 = cells.iter().sum();
        cells.iter_mut().for_each(|v| *v *= 0.95 / s);
        Psf {
            window: w,
            cells,
            veil: 0.05,
        }
    }

    fn block_mean(p: &[f32], w2: usize, h2: usize) -> Vec<f32> {
        let (w, h) = (w2 / 2, h2 / 2);
        let mut out = vec![0.0; w * h];
        for y in 0..h {
            for x in 0..w {
                out[y * w + x] = (p[2 * y * w2 + 2 * x]
                    + p[2 * y * w2 + 2 * x + 1]
                    + p[(2 * y + 1) * w2 + 2 * x]
                    + p[(2 * y + 1) * w2 + 2 * x + 1])
                    / 4.0;
            }
        }
        out
    }

    #[test]
    fn display_kernel_satisfies_down2_up2_relation() {
        // Away from the borders, down2(up2(x) ∗ h) = x ∗ k exactly.
        for w in [3, 5, 7, 9] {
            let p = psf(w, w);
            let (k, side) = display_kernel(&p);
            assert!((k.iter().sum::<f64>() - p.cells.iter().sum::<f64>()).abs() < 1e-12);
            let (iw, ih) = (16, 12);
            let x: Vec<f32> = (0..iw * ih)
                .map(|i| ((i * 31) % 13) as f32 / 13.0)
                .collect();
            let img = Image::from_planes(iw, ih, vec![x.clone()]);
            let up = img.up2();
            let retinal = convolve_symmetric(up.plane(0), 2 * iw, 2 * ih, &p.cells, w);
            let lhs = block_mean(&retinal, 2 * iw, 2 * ih);
            let rhs = convolve_symmetric(&x, iw, ih, &k, side);
            let m = side / 2 + 1;
            for y in m..ih - m {
                for xx in m..iw - m {
                    let (a, b) = (lhs[y * iw + xx], rhs[y * iw + xx]);
                    assert!((a - b).abs() < 1e-5, "w {w} at {xx},{y}: {a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn unit_dc_gain_and_near_inverse_for_small_k() {
        let p = Psf {
            window: 3,
            cells: vec![0.0, 0.1, 0.0, 0.1, 0.6, 0.1, 0.0, 0.1, 0.0],
            veil: 0.0,
        };
        // A flat field passes unchanged (unit gain at zero frequency).
        let flat = Image::from_planes(8, 8, vec![vec![0.4; 64]]);
        let out = WienerFilter::new(std::slice::from_ref(&p), 0.1).apply(&flat);
        assert!(out.plane(0).iter().all(|v| (v - 0.4).abs() < 1e-5));
        // With small K, blurring the prefiltered frame returns the frame.
        let x: Vec<f32> = (0..64)
            .map(|i| 0.5 + 0.02 * ((i * 5 % 9) as f32 / 9.0))
            .collect();
        let img = Image::from_planes(8, 8, vec![x.clone()]);
        let pre = WienerFilter::new(std::slice::from_ref(&p), 1e-7).apply(&img);
        let (k, side) = display_kernel(&p);
        let back = convolve_symmetric(pre.plane(0), 8, 8, &k, side);
        for (a, b) in back.iter().zip(&x) {
            assert!((a - b).abs() < 2e-3, "{a} vs {b}");
        }
    }

    #[test]
    fn small_k_rings_past_the_panel_range_and_warns() {
        let p = Psf {
            window: 5,
            cells: (0..25)
                .map(|i| {
                    let (x, y) = ((i % 5) as f64 - 2.0, (i / 5) as f64 - 2.0);
                    (-(x * x + y * y) / 2.0).exp() / std::f64::consts::TAU
                })
                .collect(),
            veil: 0.0,
        };
        // Black and white pixel checks: every pixel overshoots.
        let x: Vec<f32> = (0..32 * 32)
            .map(|i| if (i % 32 + i / 32) % 2 == 0 { 0.0 } else { 1.0 })
            .collect();
        let img = Image::from_planes(32, 32, vec![x]);
        let f = WienerFilter::new(std::slice::from_ref(&p), 1e-4);
        let (out, clipped) = f.apply_checked(&img);
        assert!(clipped > CLIP_WARN_FRACTION, "clipped {clipped}");
        assert!(out.plane(0).iter().all(|v| (0.0..=1.0).contains(v)));
        let w = clipping_warning(f.k_reg, clipped).expect("warns");
        assert!(w.contains("raise K") && w.contains("1e-4"), "{w}");
        // A flat field never clips, whatever K.
        let flat = Image::from_planes(32, 32, vec![vec![0.5; 1024]]);
        assert_eq!(f.apply_checked(&flat).1, 0.0);
        assert!(clipping_warning(1.0, 0.0).is_none());
        assert_eq!(clipped_fraction(&f.apply_unclamped(&flat)), 0.0);
    }

    #[test]
    fn k_at_or_above_the_dc_transfer_only_blurs_and_warns() {
        let p = Psf {
            window: 3,
            cells: vec![0.0, 0.1, 0.0, 0.1, 0.5, 0.1, 0.0, 0.1, 0.0],
            veil: 0.1,
        };
        let f = WienerFilter::new(std::slice::from_ref(&p), 1.0);
        let w = f.blur_only_warning().expect("K = H(0) warns");
        assert!(w.contains("only blurs"), "{w}");
        assert!(f.with_k(0.03).blur_only_warning().is_none());
        // It is a blur indeed: a checkerboard loses contrast.
        let x: Vec<f32> = (0..64).map(|i| ((i % 8 + i / 8) % 2) as f32).collect();
        let img = Image::from_planes(8, 8, vec![x.clone()]);
        let out = f.apply(&img);
        let contrast = |v: &[f32]| v.iter().map(|a| (a - 0.5).abs()).sum::<f32>();
        assert!(contrast(out.plane(0)) < contrast(&x));
    }

    #[test]
    fn a_kept_plan_gives_the_same_frame_and_sizes_past_the_limit_are_replanned() {
        let p = psf(5, 3);
        let f = WienerFilter::new(std::slice::from_ref(&p), 1e-2);
        let frame = |w: usize, h: usize| {
            let x = (0..w * h).map(|i| ((i * 29) % 11) as f32 / 11.0).collect();
            Image::from_planes(w, h, vec![x])
        };
        let first = f.apply_unclamped(&frame(12, 10));
        let plan = f.plan(12, 10);
        // Fill the list past its limit: the 12×10 plan is dropped, then rebuilt.
        for s in 1..=PLANS_KEPT {
            f.apply_unclamped(&frame(12 + s, 10));
        }
        assert_eq!(f.plans.len(), PLANS_KEPT);
        assert!(!Arc::ptr_eq(&plan, &f.plan(12, 10)));
        // Same size, same plan, without replanning.
        assert!(Arc::ptr_eq(&f.plan(12, 10), &f.plan(12, 10)));
        // A rebuilt plan and a fresh filter give the first frame bit for bit.
        assert_eq!(f.apply_unclamped(&frame(12, 10)).data(), first.data());
        let fresh = WienerFilter::new(std::slice::from_ref(&p), 1e-2);
        assert_eq!(fresh.apply_unclamped(&frame(12, 10)).data(), first.data());
        // Another K never reuses this filter's gains.
        let other = f.with_k(1e-1).apply_unclamped(&frame(12, 10));
        assert_ne!(other.data(), first.data());
    }
}
