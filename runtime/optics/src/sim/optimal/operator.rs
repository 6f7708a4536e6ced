//! Σ_D A_Dᵀ A_D and Σ_D A_Dᵀ t_D, the two ways (mirrored display-grid
//! convolutions, or the cropped render and its exact adjoint), and the
//! retinal-grid terms they are made from. Apart from the solver that
//! steps with them and the problem that owns the optics.

use super::DisplayProblem;
use crate::Psf;
use crate::sampling::smooth_size_at_least;
use crate::sim::convolve::Fft2;
use crate::sim::wiener::first_quadrant;
use nedrt_core::image::{extend_plane, symmetric_index, up2_plane};
use num_complex::Complex32 as c32;
use rayon::prelude::*;

/// Σ_D A_Dᵀ A_D and Σ_D A_Dᵀ t_D, two ways.
#[derive(Debug)]
pub(super) enum Operator {
    /// Mirror-symmetric PSFs (every rotationally symmetric system): on the
    /// frame mirrored to 2w×2h, which is exactly periodic, the perceived
    /// image of the mirrored frame is the mirror image of the perceived
    /// image, so the objective is four times the frame's, and both sums are
    /// convolutions on the display grid. A step is one FFT pair of the
    /// Wiener prefilter's size, whatever the PSF window.
    Mirrored(MirroredOperator),
    /// Any PSFs: each depth's perceived image rendered as the simulator
    /// does, cropped, and its residual taken back through the exact
    /// adjoint; 2 + 2·depths FFTs of the padded retinal grid per step.
    Cropped(CroppedOperator),
}

#[derive(Debug)]
pub(super) struct MirroredOperator {
    /// The mirrored 2w×2h display grid.
    pub(super) fft: Fft2,
    /// Spectrum of Σ_D A_Dᵀ A_D, per channel (real: the operator is symmetric).
    pub(super) normal: Vec<Vec<f32>>,
    /// Spectrum of the filter I ↦ Σ_D A_Dᵀ t_D(I), per channel.
    pub(super) adjoint_target: Vec<Vec<c32>>,
    /// Spectrum of Σ_D T_Dᵀ T_D (the objective's constant ½ Σ_D ‖t_D‖² as
    /// a quadratic form in I), per channel; only the trainer needs it.
    pub(super) target_gram: Vec<Vec<f32>>,
}

#[derive(Debug)]
pub(super) struct CroppedOperator {
    /// The retinal grid extended by `half` (the widest PSF's half-window)
    /// on every side, at least.
    fft: Fft2,
    half: usize,
    /// PSF spectra on `fft`'s grid and veils, [channel][depth].
    spectra: Vec<Vec<Vec<c32>>>,
    veils: Vec<Vec<f32>>,
}

/// The kernel on the w×h display grid of I ↦ up2ᵀ(k ⊛ up2(I)), k given by
/// its spectrum on the 2w×2h retinal grid (both periodic):
/// κ[n, m] = Σ_{a,b ∈ {−1,0,1}} w_a w_b k[2n + a, 2m + b], w = (1, 2, 1).
pub(super) fn fold_to_display(retinal: &Fft2, spectrum: Vec<c32>, display: &Fft2) -> Vec<c32> {
    let k = retinal.inverse(spectrum);
    let (rw, rh) = (retinal.width, retinal.height);
    let (dw, dh) = (display.width, display.height);
    let weight = |a: isize| if a == 0 { 2.0f32 } else { 1.0 };
    let mut out = vec![0.0f32; dw * dh];
    out.par_chunks_mut(dw).enumerate().for_each(|(n, row)| {
        for (m, o) in row.iter_mut().enumerate() {
            let mut acc = 0.0f32;
            for a in -1isize..=1 {
                let y = (2 * n as isize + a).rem_euclid(rh as isize) as usize;
                for b in -1isize..=1 {
                    let x = (2 * m as isize + b).rem_euclid(rw as isize) as usize;
                    acc += weight(a) * weight(b) * k[y * rw + x];
                }
            }
            *o = acc;
        }
    });
    display.forward(&out)
}

/// One depth's terms of the mirrored objective on the retinal grid:
/// |H_D|², H_D* T_D and |T_D|² (T_D = 1 for the sharp image, h_b's spectrum
/// for a blurred target), the veils at zero frequency.
pub(super) struct RetinalTerms<'a> {
    problem: &'a DisplayProblem,
    retinal: Fft2,
    /// h_b's spectrum per channel, when a target is blurred.
    blur: Option<Vec<Vec<c32>>>,
}

impl<'a> RetinalTerms<'a> {
    pub(super) fn new(problem: &'a DisplayProblem, width: usize, height: usize) -> Self {
        let retinal = Fft2::new(4 * width, 4 * height);
        let blur = problem
            .blur
            .as_ref()
            .filter(|_| problem.blurred.iter().any(|&b| b))
            .map(|b| b.iter().map(|p| Self::spectrum(&retinal, p)).collect());
        Self {
            problem,
            retinal,
            blur,
        }
    }

    /// The veil is uniform light: on the periodic grid a constant kernel,
    /// i.e. its weight at zero frequency.
    fn spectrum(retinal: &Fft2, p: &Psf) -> Vec<c32> {
        let mut s = retinal.kernel_spectrum(&p.cells, p.window);
        s[0] += c32::new(p.veil as f32, 0.0);
        s
    }

    pub(super) fn depth(&self, c: usize, depth: usize) -> [Vec<c32>; 3] {
        let h = Self::spectrum(&self.retinal, &self.problem.psfs[c][depth]);
        let gram = h.par_iter().map(|v| c32::new(v.norm_sqr(), 0.0)).collect();
        match (&self.blur, self.problem.blurred[depth]) {
            (Some(b), true) => [
                gram,
                h.par_iter()
                    .zip(&b[c])
                    .map(|(hv, bv)| hv.conj() * bv)
                    .collect(),
                b[c].par_iter()
                    .map(|v| c32::new(v.norm_sqr(), 0.0))
                    .collect(),
            ],
            _ => [
                gram,
                h.par_iter().map(|v| v.conj()).collect(),
                vec![c32::new(1.0, 0.0); h.len()],
            ],
        }
    }

    pub(super) fn fold(&self, spectrum: Vec<c32>, display: &Fft2) -> Vec<c32> {
        fold_to_display(&self.retinal, spectrum, display)
    }
}

impl MirroredOperator {
    pub(super) fn new(problem: &DisplayProblem, width: usize, height: usize) -> (Self, Vec<f64>) {
        let terms = RetinalTerms::new(problem, width, height);
        let fft = Fft2::new(2 * width, 2 * height);
        let mut normal = Vec::new();
        let mut adjoint_target = Vec::new();
        let mut target_gram = Vec::new();
        let mut lipschitz = Vec::new();
        for c in 0..problem.channels() {
            // Summed over the depths on the retinal grid, folded once.
            let n = terms.retinal.bins() * terms.retinal.height;
            let mut sums = [(); 3].map(|_| vec![c32::new(0.0, 0.0); n]);
            for depth in 0..problem.depths_d.len() {
                for (sum, term) in sums.iter_mut().zip(terms.depth(c, depth)) {
                    sum.par_iter_mut().zip(&term).for_each(|(o, v)| *o += v);
                }
            }
            let [gram, cross, targets] = sums;
            let m: Vec<f32> = terms.fold(gram, &fft).into_iter().map(|v| v.re).collect();
            lipschitz.push(m.iter().fold(0.0f32, |a, v| a.max(*v)) as f64);
            normal.push(m);
            adjoint_target.push(terms.fold(cross, &fft));
            target_gram.push(
                terms
                    .fold(targets, &fft)
                    .into_iter()
                    .map(|v| v.re)
                    .collect(),
            );
        }
        (
            Self {
                fft,
                normal,
                adjoint_target,
                target_gram,
            },
            lipschitz,
        )
    }

    fn mirror(plane: &[f32], w: usize, h: usize) -> Vec<f32> {
        extend_plane(plane, w, h, 0, 0, 2 * w, 2 * h)
    }

    /// Σ_D A_Dᵀ t_D(I) on the frame (the mirrored result's first quadrant).
    pub(super) fn adjoint_target(&self, c: usize, input: &[f32], w: usize, h: usize) -> Vec<f32> {
        let mut s = self.fft.forward(&Self::mirror(input, w, h));
        s.par_iter_mut()
            .zip(&self.adjoint_target[c])
            .for_each(|(x, k)| *x *= k);
        first_quadrant(&self.fft.inverse(s), w, h)
    }

    /// The mirrored spectrum of Σ_D A_Dᵀ t_D(I): the split solver's data
    /// term, made once a frame.
    pub(super) fn adjoint_target_spectrum(
        &self,
        c: usize,
        input: &[f32],
        w: usize,
        h: usize,
    ) -> Vec<c32> {
        let mut s = self.fft.forward(&Self::mirror(input, w, h));
        s.par_iter_mut()
            .zip(&self.adjoint_target[c])
            .for_each(|(x, k)| *x *= k);
        s
    }

    /// argmin_x ½ xᵀ(Σ_D A_Dᵀ A_D)x − bᵀx + ρ/2 ‖x − v‖², exactly: the
    /// normal operator is diagonal in this basis, so (N + ρ) x = b + ρ v
    /// is one division per frequency (`b` from
    /// [`MirroredOperator::adjoint_target_spectrum`]).
    pub(super) fn penalised_solve(
        &self,
        c: usize,
        b: &[c32],
        v: &[f32],
        rho: f32,
        w: usize,
        h: usize,
    ) -> Vec<f32> {
        let mut s = self.fft.forward(&Self::mirror(v, w, h));
        s.par_iter_mut()
            .zip(b.par_iter().zip(&self.normal[c]))
            .for_each(|(x, (bv, m))| *x = (bv + *x * rho) / (m + rho));
        first_quadrant(&self.fft.inverse(s), w, h)
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn value_and_gradient(
        &self,
        c: usize,
        display: &[f32],
        w: usize,
        h: usize,
        adjoint_target: &[f32],
        constant: f64,
        gradient: Option<&mut Vec<f32>>,
    ) -> f64 {
        let mut s = self.fft.forward(&Self::mirror(display, w, h));
        s.par_iter_mut()
            .zip(&self.normal[c])
            .for_each(|(x, m)| *x *= *m);
        let normal = first_quadrant(&self.fft.inverse(s), w, h);
        let value: f64 = display
            .iter()
            .zip(&normal)
            .zip(adjoint_target)
            .map(|((d, m), b)| (*d as f64) * (0.5 * *m as f64 - *b as f64))
            .sum();
        if let Some(g) = gradient {
            g.clear();
            g.extend(normal.iter().zip(adjoint_target).map(|(m, b)| m - b));
        }
        value + constant
    }
}

impl CroppedOperator {
    pub(super) fn new(problem: &DisplayProblem, width: usize, height: usize) -> Self {
        let half = problem
            .psfs
            .iter()
            .flatten()
            .map(|p| p.window / 2)
            .max()
            .unwrap_or(0);
        let fw = smooth_size_at_least((2 * width + 2 * half) as f64);
        let fh = smooth_size_at_least((2 * height + 2 * half) as f64);
        let fft = Fft2::new(fw, fh);
        let spectra = problem
            .psfs
            .iter()
            .map(|ch| {
                ch.iter()
                    .map(|p| fft.kernel_spectrum(&p.cells, p.window))
                    .collect()
            })
            .collect();
        let veils = problem
            .psfs
            .iter()
            .map(|ch| ch.iter().map(|p| p.veil as f32).collect())
            .collect();
        Self {
            fft,
            half,
            spectra,
            veils,
        }
    }

    /// Power iteration on Σ_D A_Dᵀ A_D for channel `c`.
    pub(super) fn largest_eigenvalue(&self, c: usize, w: usize, h: usize) -> f64 {
        let n = w * h;
        let zero = vec![0.0f32; 4 * n];
        let targets: Vec<&[f32]> = vec![&zero; self.spectra[c].len()];
        let norm = |x: &[f32]| x.iter().map(|a| (*a as f64).powi(2)).sum::<f64>().sqrt();
        // A pattern with every frequency, so no eigenvector is missed.
        let mut v: Vec<f32> = (0..n)
            .map(|i| 1.0 + ((i * 7919) % 101) as f32 / 101.0)
            .collect();
        let mut g = Vec::new();
        let mut eig = 0.0;
        for _ in 0..POWER_STEPS {
            self.value_and_gradient(c, &v, w, h, &targets, Some(&mut g));
            let (ng, nv) = (norm(&g), norm(&v));
            if ng == 0.0 || nv == 0.0 {
                break;
            }
            eig = ng / nv;
            v = g.iter().map(|a| (*a as f64 / ng) as f32).collect();
        }
        eig
    }

    /// ½ Σ_D ‖A_D d − t_D‖² for channel `c`, and its gradient Σ_D A_Dᵀ r_D
    /// into `gradient` when given.
    pub(super) fn value_and_gradient(
        &self,
        c: usize,
        display: &[f32],
        w: usize,
        h: usize,
        targets: &[&[f32]],
        gradient: Option<&mut Vec<f32>>,
    ) -> f64 {
        let a = self.half;
        let (w2, h2) = (2 * w, 2 * h);
        let (fw, fh) = (self.fft.width, self.fft.height);
        let up = up2_plane(display, w, h);
        let u = self.fft.forward(&extend_plane(&up, w2, h2, a, a, fw, fh));
        let mean = display.iter().map(|&v| v as f64).sum::<f64>() / (w * h) as f64;
        let want_gradient = gradient.is_some();
        let mut acc = want_gradient.then(|| vec![c32::new(0.0, 0.0); u.len()]);
        let mut veil_adjoint = 0.0f64;
        let mut value = 0.0f64;
        for (d, (spectrum, &veil)) in self.spectra[c].iter().zip(&self.veils[c]).enumerate() {
            let mut s = u.clone();
            s.par_iter_mut().zip(spectrum).for_each(|(x, k)| *x *= k);
            let full = self.fft.inverse(s);
            let lift = (veil as f64 * mean) as f32;
            let mut placed = want_gradient.then(|| vec![0.0f32; fw * fh]);
            let mut residual_sum = 0.0f64;
            for y in 0..h2 {
                let row = &full[(y + a) * fw + a..(y + a) * fw + a + w2];
                let target = &targets[d][y * w2..(y + 1) * w2];
                for x in 0..w2 {
                    let r = row[x] + lift - target[x];
                    value += (r as f64) * (r as f64);
                    residual_sum += r as f64;
                    if let Some(p) = placed.as_mut() {
                        p[(y + a) * fw + a + x] = r;
                    }
                }
            }
            if let (Some(p), Some(acc)) = (placed, acc.as_mut()) {
                let rs = self.fft.forward(&p);
                acc.par_iter_mut()
                    .zip(rs.par_iter().zip(spectrum))
                    .for_each(|(o, (r, k))| *o += k.conj() * r);
                veil_adjoint += veil as f64 * residual_sum;
            }
        }
        if let (Some(g), Some(acc)) = (gradient, acc) {
            let full = self.fft.inverse(acc);
            // Adjoint of the symmetric extension: fold the padded grid back.
            let xs: Vec<usize> = (0..w2 + 2 * a)
                .map(|x| symmetric_index(x as isize - a as isize, w2))
                .collect();
            let mut retinal = vec![0.0f32; w2 * h2];
            for y in 0..h2 + 2 * a {
                let sy = symmetric_index(y as isize - a as isize, h2);
                let dst = &mut retinal[sy * w2..(sy + 1) * w2];
                for (x, &sx) in xs.iter().enumerate() {
                    dst[sx] += full[y * fw + x];
                }
            }
            // Adjoint of up2 (sum of each 2×2 block) and of the veil's mean.
            let lift = (veil_adjoint / (w * h) as f64) as f32;
            g.clear();
            g.resize(w * h, 0.0);
            for y in 0..h {
                for x in 0..w {
                    let i = 2 * y * w2 + 2 * x;
                    g[y * w + x] =
                        retinal[i] + retinal[i + 1] + retinal[i + w2] + retinal[i + w2 + 1] + lift;
                }
            }
        }
        0.5 * value
    }
}

/// Power-iteration steps and the margin on what they find (power iteration
/// approaches the largest eigenvalue from below).
pub(super) const POWER_STEPS: usize = 30;

pub(super) const POWER_MARGIN: f64 = 1.05;
