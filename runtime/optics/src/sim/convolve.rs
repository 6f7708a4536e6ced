//! Real 2-D FFTs (realfft rows, rustfft columns) and the convolution of
//! docs/model.md §9: pad by symmetric reflection by the kernel half-width,
//! convolve, crop back, so no light wraps around the frame.

use std::sync::Arc;

use num_complex::Complex32 as c32;
use rayon::prelude::*;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};

use crate::sampling::smooth_size_at_least;
use nedrt_core::image::extend_plane;

/// Plans for real 2-D transforms of `width`×`height` arrays. Spectra are
/// stored transposed: (width/2 + 1) rows of `height` complex values.
pub struct Fft2 {
    pub width: usize,
    pub height: usize,
    r2c: Arc<dyn RealToComplex<f32>>,
    c2r: Arc<dyn ComplexToReal<f32>>,
    col_fwd: Arc<dyn Fft<f32>>,
    col_inv: Arc<dyn Fft<f32>>,
}

impl std::fmt::Debug for Fft2 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Fft2({}×{})", self.width, self.height)
    }
}

impl Fft2 {
    pub fn new(width: usize, height: usize) -> Self {
        let mut rp = RealFftPlanner::<f32>::new();
        let mut cp = FftPlanner::<f32>::new();
        Self {
            width,
            height,
            r2c: rp.plan_fft_forward(width),
            c2r: rp.plan_fft_inverse(width),
            col_fwd: cp.plan_fft_forward(height),
            col_inv: cp.plan_fft_inverse(height),
        }
    }

    /// Number of complex bins per row of the real transform.
    pub fn bins(&self) -> usize {
        self.width / 2 + 1
    }

    /// Forward transform of a row-major `width`×`height` real array.
    pub fn forward(&self, data: &[f32]) -> Vec<c32> {
        let (w, h, b) = (self.width, self.height, self.bins());
        let mut rows = vec![c32::new(0.0, 0.0); h * b];
        rows.par_chunks_mut(b)
            .zip(data.par_chunks(w))
            .for_each_init(
                || (self.r2c.make_input_vec(), self.r2c.make_scratch_vec()),
                |(input, scratch), (out, src)| {
                    input.copy_from_slice(src);
                    // Lengths match by construction, so this cannot fail.
                    let _ = self.r2c.process_with_scratch(input, out, scratch);
                },
            );
        let mut cols = transpose(&rows, h, b);
        cols.par_chunks_mut(h).for_each_init(
            || vec![c32::new(0.0, 0.0); self.col_fwd.get_inplace_scratch_len()],
            |scratch, col| self.col_fwd.process_with_scratch(col, scratch),
        );
        cols
    }

    /// Inverse of [`Fft2::forward`], including the 1/(width·height) scale.
    pub fn inverse(&self, mut spectrum: Vec<c32>) -> Vec<f32> {
        let (w, h, b) = (self.width, self.height, self.bins());
        spectrum.par_chunks_mut(h).for_each_init(
            || vec![c32::new(0.0, 0.0); self.col_inv.get_inplace_scratch_len()],
            |scratch, col| self.col_inv.process_with_scratch(col, scratch),
        );
        let mut rows = transpose(&spectrum, b, h);
        let scale = 1.0 / (w * h) as f32;
        let mut out = vec![0.0f32; w * h];
        out.par_chunks_mut(w)
            .zip(rows.par_chunks_mut(b))
            .for_each_init(
                || self.c2r.make_scratch_vec(),
                |scratch, (dst, src)| {
                    // A real signal's DC and Nyquist bins are real; drop round-off.
                    src[0].im = 0.0;
                    if w % 2 == 0 {
                        src[b - 1].im = 0.0;
                    }
                    let _ = self.c2r.process_with_scratch(src, dst, scratch);
                    dst.iter_mut().for_each(|v| *v *= scale);
                },
            );
        out
    }

    /// Spectrum of an odd k×k kernel centred on the origin (wrapped).
    pub fn kernel_spectrum(&self, kernel: &[f64], k: usize) -> Vec<c32> {
        let (w, h) = (self.width, self.height);
        let half = (k / 2) as isize;
        let mut placed = vec![0.0f32; w * h];
        for ky in 0..k {
            let y = (ky as isize - half).rem_euclid(h as isize) as usize;
            for kx in 0..k {
                let x = (kx as isize - half).rem_euclid(w as isize) as usize;
                placed[y * w + x] += kernel[ky * k + kx] as f32;
            }
        }
        self.forward(&placed)
    }
}

fn transpose<T: Copy + Send + Sync + Default>(data: &[T], rows: usize, cols: usize) -> Vec<T> {
    let mut out = vec![T::default(); rows * cols];
    out.par_chunks_mut(rows).enumerate().for_each(|(c, dst)| {
        for (r, v) in dst.iter_mut().enumerate() {
            *v = data[r * cols + c];
        }
    });
    out
}

/// Work prepared per frame size (plans, gain spectra), kept for the
/// `kept` sizes used last, the most recent at the end: frames after the
/// first of a size pay no planning.
pub(crate) struct SizeCache<T> {
    kept: usize,
    items: std::sync::Mutex<Vec<Sized<T>>>,
}

/// A value and the (width, height) it was made for.
type Sized<T> = ((usize, usize), Arc<T>);

impl<T> SizeCache<T> {
    pub(crate) fn new(kept: usize) -> Self {
        Self {
            kept,
            items: std::sync::Mutex::new(Vec::new()),
        }
    }

    /// The value for `width`×`height`, made by `make` if it is not kept.
    pub(crate) fn get_or_make(
        &self,
        width: usize,
        height: usize,
        make: impl FnOnce() -> T,
    ) -> Arc<T> {
        // A poisoned lock only means another thread panicked mid-push; the
        // list of finished values is still valid.
        let mut items = self.items.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = items.iter().position(|(size, _)| *size == (width, height)) {
            let item = items.remove(i);
            let value = item.1.clone();
            items.push(item);
            return value;
        }
        let value = Arc::new(make());
        if items.len() == self.kept {
            items.remove(0);
        }
        items.push(((width, height), value.clone()));
        value
    }

    /// How many sizes are kept now.
    pub(crate) fn len(&self) -> usize {
        self.items.lock().unwrap_or_else(|e| e.into_inner()).len()
    }
}

impl<T> std::fmt::Debug for SizeCache<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SizeCache({} of {} sizes)", self.len(), self.kept)
    }
}

/// A kernel prepared for frames of one size: the padded FFT size and its spectrum.
#[derive(Debug)]
pub struct PreparedKernel {
    fft: Fft2,
    spectrum: Vec<c32>,
    half: usize,
    width: usize,
    height: usize,
}

impl PreparedKernel {
    /// Prepares an odd `k`×`k` kernel for `width`×`height` planes.
    pub fn new(kernel: &[f64], k: usize, width: usize, height: usize) -> Self {
        assert!(
            k % 2 == 1 && kernel.len() == k * k,
            "kernel must be odd and square"
        );
        let half = k / 2;
        let fw = smooth_size_at_least((width + 2 * half) as f64);
        let fh = smooth_size_at_least((height + 2 * half) as f64);
        let fft = Fft2::new(fw, fh);
        let spectrum = fft.kernel_spectrum(kernel, k);
        Self {
            fft,
            spectrum,
            half,
            width,
            height,
        }
    }

    /// Linear convolution of one plane, symmetric-reflection padded by the
    /// kernel half-width and cropped back to the plane's size.
    pub fn apply(&self, plane: &[f32]) -> Vec<f32> {
        let (w, h, a) = (self.width, self.height, self.half);
        let padded = extend_plane(plane, w, h, a, a, self.fft.width, self.fft.height);
        let mut spec = self.fft.forward(&padded);
        spec.par_iter_mut()
            .zip(&self.spectrum)
            .for_each(|(s, k)| *s *= k);
        let full = self.fft.inverse(spec);
        let mut out = Vec::with_capacity(w * h);
        for y in a..a + h {
            out.extend_from_slice(&full[y * self.fft.width + a..y * self.fft.width + a + w]);
        }
        out
    }
}

/// Convenience: convolve one plane with an odd k×k kernel (see [`PreparedKernel`]).
pub fn convolve_symmetric(
    plane: &[f32],
    width: usize,
    height: usize,
    kernel: &[f64],
    k: usize,
) -> Vec<f32> {
    PreparedKernel::new(kernel, k, width, height).apply(plane)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Direct convolution with symmetric extension, the reference.
    fn direct(plane: &[f32], w: usize, h: usize, kernel: &[f64], k: usize) -> Vec<f32> {
        let a = (k / 2) as isize;
        let mut out = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0f64;
                for ky in 0..k {
                    for kx in 0..k {
                        let sy =
                            nedrt_core::image::symmetric_index(y as isize - (ky as isize - a), h);
                        let sx =
                            nedrt_core::image::symmetric_index(x as isize - (kx as isize - a), w);
                        acc += kernel[ky * k + kx] * plane[sy * w + sx] as f64;
                    }
                }
                out[y * w + x] = acc as f32;
            }
        }
        out
    }

    #[test]
    fn fft_convolution_matches_direct_including_kernels_larger_than_the_frame() {
        let (w, h) = (13, 9);
        let plane: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 17) as f32 / 17.0).collect();
        for k in [1, 3, 7, 21] {
            let kernel: Vec<f64> = (0..k * k).map(|i| ((i * 13) % 7) as f64 + 0.5).collect();
            let got = convolve_symmetric(&plane, w, h, &kernel, k);
            let want = direct(&plane, w, h, &kernel, k);
            for (a, b) in got.iter().zip(&want) {
                assert!((a - b).abs() < 2e-4 * b.abs().max(1.0), "k {k}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn round_trip_is_identity() {
        let fft = Fft2::new(10, 6);
        let x: Vec<f32> = (0..60).map(|i| (i as f32 * 0.37).sin()).collect();
        let back = fft.inverse(fft.forward(&x));
        for (a, b) in back.iter().zip(&x) {
            assert!((a - b).abs() < 1e-5);
        }
    }
}
