//! The J0 kernel of the radial path, J0(k ρ_n t_i), one block of rows of t
//! at a time. It is where the radial path spends its time (≈ 10⁸ entries
//! for a 999-cell window), so past x = 25 it uses Hankel's asymptotic
//! expansion J0(x) = √(2/(πx)) (P(x) cos χ − Q(x) sin χ), χ = x − π/4, with
//! four terms each of P and Q (absolute error < 1e-11 there, checked against
//! `libm::j0` in `tests`), and cos χ, sin χ stepped along each column by a
//! rotation (the angles t_i are evenly spaced within a grid), re-anchored
//! exactly at every block: ≈ 20 flops an entry instead of a libm call
//! (≈ 60 ns). Below x = 25 every value is `libm::j0` (musl's).

use std::f64::consts::{FRAC_1_SQRT_2, PI};

/// From this argument on the asymptotic expansion is used.
const ASYMPTOTIC_FROM: f64 = 25.0;

// P(x) = 1 + Σ p_k x^(−2k), Q(x) = Σ q_k x^(−2k−1): Hankel's coefficients
// a_k(0) = Π_{m=1..k} (−(2m − 1)²) / (k! 8^k), alternating.
const P1: f64 = -9.0 / 128.0;
const P2: f64 = 3675.0 / 32768.0;
const P3: f64 = -2_401_245.0 / 4_194_304.0;
const P4: f64 = 13_043_905_875.0 / 2_147_483_648.0;
const Q0: f64 = -1.0 / 8.0;
const Q1: f64 = 75.0 / 1024.0;
const Q2: f64 = -59535.0 / 262_144.0;
const Q3: f64 = 57_972_915.0 / 33_554_432.0;

/// The rows of a block split into runs of evenly spaced angles: (first
/// row, one past the last, spacing).
fn even_runs(t: &[f64]) -> Vec<(usize, usize, f64)> {
    let mut runs = Vec::new();
    let mut start = 0;
    while start < t.len() {
        let step = t.get(start + 1).map_or(0.0, |b| b - t[start]);
        let mut end = start + 1;
        while end < t.len() && ((t[end] - t[end - 1]) - step).abs() <= 1e-9 * step.abs() {
            end += 1;
        }
        runs.push((start, end, step));
        start = end;
    }
    runs
}

/// J0(k ρ_n t_i) for the rows `t_rad` (> 0) and columns `rho_m`
/// (increasing), k = 2π/λ: row-major, `t_rad.len()` × `rho_m.len()`. The
/// rotations run along t for every column at once, so the inner loops are
/// over columns, independent and vectorisable.
pub(super) fn j0_block(k: f64, t_rad: &[f64], rho_m: &[f64]) -> Vec<f64> {
    let cols = rho_m.len();
    let kr: Vec<f64> = rho_m.iter().map(|r| k * r).collect();
    let inv_kr: Vec<f64> = kr.iter().map(|v| 1.0 / v).collect();
    let amp_kr: Vec<f64> = kr.iter().map(|v| (2.0 / (PI * v)).sqrt()).collect();
    let (mut s, mut c) = (vec![0.0; cols], vec![0.0; cols]);
    let (mut ws, mut wc) = (vec![0.0; cols], vec![0.0; cols]);
    let mut data = vec![0.0; t_rad.len() * cols];
    for (start, end, step) in even_runs(t_rad) {
        for n in 0..cols {
            (ws[n], wc[n]) = (kr[n] * step).sin_cos();
        }
        // Columns from `anchored` on hold the rotation state of the last row.
        let mut anchored = cols;
        for i in start..end {
            let t = t_rad[i];
            let row = &mut data[i * cols..(i + 1) * cols];
            // x = k ρ_n t grows with n: a prefix of small arguments.
            let first = kr.partition_point(|v| v * t < ASYMPTOTIC_FROM);
            for n in 0..first {
                row[n] = libm::j0(kr[n] * t);
            }
            for (((s, c), ws), wc) in s[anchored..]
                .iter_mut()
                .zip(&mut c[anchored..])
                .zip(&ws[anchored..])
                .zip(&wc[anchored..])
            {
                (*s, *c) = (*s * wc + *c * ws, *c * wc - *s * ws);
            }
            for n in first..anchored.max(first) {
                // sin, cos of χ = x − π/4 from those of x.
                let (sx, cx) = (kr[n] * t).sin_cos();
                (s[n], c[n]) = ((sx - cx) * FRAC_1_SQRT_2, (cx + sx) * FRAC_1_SQRT_2);
            }
            anchored = anchored.min(first);
            let (inv_t, amp_t) = (1.0 / t, (1.0 / t).sqrt());
            let values = row[first..]
                .iter_mut()
                .zip(&inv_kr[first..])
                .zip(&amp_kr[first..])
                .zip(s[first..].iter().zip(&c[first..]));
            for (((out, inv_kr), amp_kr), (s, c)) in values {
                let inv_x = inv_kr * inv_t;
                let u = inv_x * inv_x;
                let p = 1.0 + u * (P1 + u * (P2 + u * (P3 + u * P4)));
                let q = inv_x * (Q0 + u * (Q1 + u * (Q2 + u * Q3)));
                *out = amp_kr * amp_t * (p * c - q * s);
            }
        }
    }
    data
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_kernel_is_libm_j0_to_1e_11() {
        // Two evenly spaced grids in one block (as the fine and coarse
        // annulus midpoints meet), arguments from 0 to ≈ 8000.
        let delta = 1.5e-4 / 32.0;
        let mut t: Vec<f64> = (0..40).map(|i| (i as f64 + 0.5) * delta).collect();
        t.extend((0..24).map(|j| (j as f64 + 0.5) * 2.0 * delta + 0.02));
        let rho: Vec<f64> = (0..700).map(|n| (n as f64 + 0.5) * 7.1e-6).collect();
        let k = 2.0 * PI / 450e-9;
        let block = j0_block(k, &t, &rho);
        let mut worst: f64 = 0.0;
        for (i, ti) in t.iter().enumerate() {
            for (n, r) in rho.iter().enumerate() {
                worst = worst.max((block[i * rho.len() + n] - libm::j0(k * ti * r)).abs());
            }
        }
        assert!(worst < 1e-11, "largest |kernel − libm::j0| = {worst:e}");
        assert_eq!(even_runs(&t).len(), 2);
    }
}
