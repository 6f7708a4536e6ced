//! Radial (Hankel) propagation for rotationally symmetric pupils: pure
//! functions from a pupil profile Q(ρ) to retinal cells, each holding
//! ∫_cell |U|² dθ over the light through the aperture (docs/model.md §6 in polar
//! form). For Q(ρ) the 2-D transform is a Hankel transform,
//!
//!   U(t) = Σ_n Q(ρ_n) · J0(2π ρ_n t / λ) · w_n,   ρ_n = (n + ½)Δρ,
//!   w_n = π (min(b_n, r)² − a_n²),  a_n = nΔρ,  b_n = (n + 1)Δρ,
//!
//! the continuous hard-edged aperture in annuli (Σ w_n = π r² exactly; the
//! midpoint rule in ρ). The aperture's edge is taken out of the sum and
//! added back exactly: with Q_r the pupil's value at ρ = r,
//!
//!   U(t) = Σ_n (Q_n − Q_r) w_n J0(2π ρ_n t / λ) + Q_r · 2π r² J1(x)/x,  x = 2π r t / λ,
//!
//! because the jump of Q at r is what the midpoint rule aliases: near the
//! kernel's Nyquist angle λ/(2Δρ) it would inflate the edge-diffraction tail
//! (which holds the last 0.1 % of the light) up to 2.5×; with the edge exact
//! the tail stays within a few per cent, and an in-focus pupil is exact.
//! The angular energy density p(t) = |U(t)|² / (λ² E), E = Σ |Q_n|² w_n,
//! integrates to 1 over the plane. A retinal cell holds
//! Σ_i p(t_i) · area(cell ∩ annulus_i) over annuli [iδ, (i + 1)δ) of width
//! δ = Δθ / m_t, t_i their midpoints, with the areas in closed form
//! ([`disk_rect_area`]). That rule is second order in δ with a large
//! constant at the axis (t_i is not the annulus's area centroid), so the
//! cells are its Richardson extrapolation from m_t and m_t / 2
//! ([`WindowCells`]): fourth order. The cost is one J0 kernel per channel
//! (N_ρ × annuli, evaluated in row blocks, never stored whole; `kernel`:
//! `libm::j0` below x = 25, Hankel's asymptotic expansion with rotations
//! along t above) times the pupils of every PSF of that channel at once,
//! against two 2-D FFTs of ≥ (2N)² per PSF on the 2-D path.

use std::f64::consts::PI;

use faer::{Accum, Mat, MatRef, Par};
use num_complex::Complex64 as c64;
use rayon::prelude::*;

/// Annuli per retinal cell, m_t, of the finer of the two rules that
/// [`WindowCells`] extrapolates from (the coarser has m_t / 2). The in-focus
/// lens PSF is the hardest case (its Airy core, radius 0.42 Δθ, is smaller
/// than a cell). At 32 its cells change by < 0.05 % of the peak when m_t
/// doubles (16 would do for that) and the light in the window by < 5e-5
/// (16 would not: 4e-4, enough to move the 0.1 % energy window by tens of
/// cells); `tests::cells_converge_in_the_annulus_width`, docs/optics-model.md.
pub const ANNULI_PER_CELL: usize = 32;

/// Rows of t per J0 kernel block: a block of N_ρ ≈ 2500 nodes is 1.3 MB.
const KERNEL_BLOCK_ROWS: usize = 64;

/// Annulus quadrature of a circular aperture of radius `radius_m`: node n
/// at ρ_n = (n + ½)·`step_m` for every n with nΔρ < r, weight the area of
/// its annulus inside the aperture.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RadialGrid {
    pub step_m: f64,
    pub radius_m: f64,
}

impl RadialGrid {
    /// N equal annuli, Δρ = r / N: the aperture edge is the last annulus's
    /// outer edge, so every node is an annulus midpoint.
    pub fn with_nodes(radius_m: f64, nodes: usize) -> Self {
        Self {
            step_m: radius_m / nodes.max(1) as f64,
            radius_m,
        }
    }

    /// Number of nodes: every annulus that starts inside the aperture.
    pub fn nodes(&self) -> usize {
        (self.radius_m / self.step_m - 1e-9).ceil().max(1.0) as usize
    }

    /// Node radii ρ_n = (n + ½)Δρ, metres.
    pub fn radii_m(&self) -> Vec<f64> {
        (0..self.nodes())
            .map(|n| (n as f64 + 0.5) * self.step_m)
            .collect()
    }

    /// The radii at which a pupil is sampled: the node radii, then the
    /// aperture edge r (for the exact edge term), metres.
    pub fn sample_radii_m(&self) -> Vec<f64> {
        let mut radii = self.radii_m();
        radii.push(self.radius_m);
        radii
    }

    /// Annulus areas inside the aperture, π(min(b_n, r)² − a_n²), m².
    pub fn areas_m2(&self) -> Vec<f64> {
        (0..self.nodes())
            .map(|n| {
                let a = n as f64 * self.step_m;
                let b = ((n + 1) as f64 * self.step_m).min(self.radius_m);
                PI * (b * b - a * a)
            })
            .collect()
    }
}

/// A pupil profile: its samples at the nodes and its value at the aperture
/// edge (dimensionless).
#[derive(Debug, Clone, PartialEq)]
pub struct RadialPupil {
    pub nodes: Vec<c64>,
    pub edge: c64,
}

/// Samples Q = exp(j(Φ + Ψ ρ²/r²)) at the nodes of `grid` and at the edge
/// (the aperture is the quadrature's hard edge, A = 1 inside).
/// `doe_phase_rad` is the DOE's phase at [`RadialGrid::sample_radii_m`]
/// (N_ρ + 1 values), or `None` for the lens alone.
pub fn pupil_profile(grid: RadialGrid, psi_rad: f64, doe_phase_rad: Option<&[f64]>) -> RadialPupil {
    let r2 = grid.radius_m * grid.radius_m;
    let mut q: Vec<c64> = grid
        .sample_radii_m()
        .iter()
        .enumerate()
        .map(|(n, rho)| {
            let phi = psi_rad * rho * rho / r2 + doe_phase_rad.map_or(0.0, |p| p[n]);
            c64::from_polar(1.0, phi)
        })
        .collect();
    let edge = q.pop().unwrap_or(c64::new(1.0, 0.0));
    RadialPupil { nodes: q, edge }
}

/// Light through the aperture, E = Σ |Q_n|² w_n, m².
pub fn pupil_energy_m2(grid: RadialGrid, pupil: &RadialPupil) -> f64 {
    pupil
        .nodes
        .iter()
        .zip(grid.areas_m2())
        .map(|(q, w)| q.norm_sqr() * w)
        .sum()
}

/// J0(2π ρ_n t_i / λ) for angles `t_rad` (> 0, rad) and node radii `rho_m`
/// (increasing, m), `wavenumber_per_m` = 2π/λ: the radial kernel, row-major
/// (rows t), as [`angular_density`] builds it block by block (exposed for
/// `nedrt bench radial`).
pub fn j0_kernel(wavenumber_per_m: f64, t_rad: &[f64], rho_m: &[f64]) -> Vec<f64> {
    kernel::j0_block(wavenumber_per_m, t_rad, rho_m)
}

/// Field of the uniform disk of radius r at angle t: 2π r² J1(x)/x,
/// x = 2π r t / λ (π r² on axis), m².
fn disk_field_m2(radius_m: f64, wavenumber_per_m: f64, t_rad: f64) -> f64 {
    let x = wavenumber_per_m * radius_m * t_rad;
    if x.abs() < 1e-8 {
        PI * radius_m * radius_m
    } else {
        2.0 * PI * radius_m * radius_m * libm::j1(x) / x
    }
}

/// Angular energy density p(t) = |U(t)|² / (λ² E) (sr⁻¹) of each pupil (all
/// on `grid`, at one wavelength) at the angles `t_rad` from the axis, the
/// aperture edge exact (module doc). J0(2π ρ_n t / λ) is evaluated in
/// blocks of rows of t and multiplied by the matrix of every pupil at once
/// (real GEMM on [Re (Q − Q_r)·w | Im (Q − Q_r)·w]). Returns one density
/// per pupil, each `t_rad.len()` long.
pub fn angular_density(
    grid: RadialGrid,
    wavelength_m: f64,
    pupils: &[RadialPupil],
    t_rad: &[f64],
) -> Vec<Vec<f64>> {
    let n_rho = grid.nodes();
    let count = pupils.len();
    let rho = grid.radii_m();
    let areas = grid.areas_m2();
    let scale: Vec<f64> = pupils
        .iter()
        .map(|q| 1.0 / (wavelength_m * wavelength_m * pupil_energy_m2(grid, q)))
        .collect();
    // Columns 2j and 2j + 1: Re and Im of pupil j less its edge value,
    // annulus areas folded in.
    let weighted = Mat::<f64>::from_fn(n_rho, 2 * count, |n, c| {
        let q = &pupils[c / 2];
        let z = (q.nodes[n] - q.edge) * areas[n];
        if c % 2 == 0 { z.re } else { z.im }
    });
    let k = 2.0 * PI / wavelength_m;
    let mut flat = vec![0.0; t_rad.len() * count];
    flat.par_chunks_mut(KERNEL_BLOCK_ROWS * count.max(1))
        .zip(t_rad.par_chunks(KERNEL_BLOCK_ROWS))
        .for_each(|(out, ts)| {
            let kernel = kernel::j0_block(k, ts, &rho);
            let kernel = MatRef::from_row_major_slice(&kernel, ts.len(), n_rho);
            let mut u = Mat::<f64>::zeros(ts.len(), 2 * count);
            faer::linalg::matmul::matmul(
                u.as_mut(),
                Accum::Replace,
                kernel,
                weighted.as_ref(),
                1.0,
                Par::Seq,
            );
            for (i, row) in out.chunks_mut(count.max(1)).enumerate() {
                let disk = disk_field_m2(grid.radius_m, k, ts[i]);
                for (j, p) in row.iter_mut().enumerate() {
                    let edge = pupils[j].edge * disk;
                    let (re, im) = (u[(i, 2 * j)] + edge.re, u[(i, 2 * j + 1)] + edge.im);
                    *p = (re * re + im * im) * scale[j];
                }
            }
        });
    (0..count)
        .map(|j| flat.iter().skip(j).step_by(count).copied().collect())
        .collect()
}

/// Area of disk(r) ∩ [0, x] × [0, y] for x, y ≥ 0, in closed form:
/// y·min(u*, x') + G(x') − G(min(u*, x')), x' = min(x, r), u* = √(r² − y²)⁺,
/// G(u) = ∫₀^u √(r² − s²) ds = ½(u√(r² − u²) + r² asin(u/r)).
fn quadrant_area(x: f64, y: f64, r: f64) -> f64 {
    if x <= 0.0 || y <= 0.0 || r <= 0.0 {
        return 0.0;
    }
    if x * x + y * y <= r * r {
        return x * y; // the rectangle lies inside the disk
    }
    let g = |u: f64| 0.5 * (u * (r * r - u * u).max(0.0).sqrt() + r * r * (u / r).min(1.0).asin());
    let xp = x.min(r);
    let m = (r * r - y * y).max(0.0).sqrt().min(xp);
    y * m + g(xp) - g(m)
}

/// Area of the disk of radius `r` about the origin inside the rectangle
/// [x0, x1] × [y0, y1] (any signs, x0 ≤ x1, y0 ≤ y1), exact: signed
/// quadrant areas F_s(x, y) = sign(x) sign(y) F(|x|, |y|) combined over the
/// four corners.
pub fn disk_rect_area(r: f64, x0: f64, x1: f64, y0: f64, y1: f64) -> f64 {
    let f = |x: f64, y: f64| x.signum() * y.signum() * quadrant_area(x.abs(), y.abs(), r);
    f(x1, y1) - f(x0, y1) - f(x1, y0) + f(x0, y0)
}

/// Exact overlaps (rad²) of the cells of a (2H + 1)² window with annuli of
/// width δ = Δθ / m_t about the axis. Cell (kx, ky) is the square
/// [(kx − ½)Δθ, (kx + ½)Δθ] × [(ky − ½)Δθ, (ky + ½)Δθ]; it meets only the
/// annuli between its nearest and farthest point's radius, so each cell
/// stores its first annulus and those weights. The window's 8-fold symmetry
/// means only the octant 0 ≤ ky ≤ kx ≤ H is stored.
#[derive(Debug, Clone)]
pub struct CellWeights {
    half_cells: usize,
    cell_rad: f64,
    annuli_per_cell: usize,
    annuli: usize,
    /// Per octant cell (index kx(kx + 1)/2 + ky): first annulus.
    first: Vec<usize>,
    /// Per octant cell: its weights are `weights[start[c]..start[c + 1]]`.
    start: Vec<usize>,
    weights: Vec<f64>,
}

fn octant_index(kx: usize, ky: usize) -> usize {
    kx * (kx + 1) / 2 + ky
}

impl CellWeights {
    /// Weights of the window of half-width `half_cells` (W = 2H + 1) for
    /// cells of `cell_rad` and `annuli_per_cell` annuli per cell width.
    pub fn new(half_cells: usize, cell_rad: f64, annuli_per_cell: usize) -> Self {
        let m = annuli_per_cell.max(1) as f64;
        // Work in cell units (Δθ = 1) for conditioning; scale at the end.
        let per_column: Vec<Vec<(usize, Vec<f64>)>> = (0..=half_cells)
            .into_par_iter()
            .map(|kx| {
                (0..=kx)
                    .map(|ky| {
                        let (x0, x1) = (kx as f64 - 0.5, kx as f64 + 0.5);
                        let (y0, y1) = (ky as f64 - 0.5, ky as f64 + 0.5);
                        let near = x0.max(0.0).hypot(y0.max(0.0));
                        let far = x1.hypot(y1);
                        let first = (near * m + 1e-9).floor() as usize;
                        let last = (far * m - 1e-9).ceil() as usize;
                        let mut prev = disk_rect_area(first as f64 / m, x0, x1, y0, y1);
                        let w = (first + 1..=last)
                            .map(|i| {
                                let a = disk_rect_area(i as f64 / m, x0, x1, y0, y1);
                                let d = (a - prev) * cell_rad * cell_rad;
                                prev = a;
                                d
                            })
                            .collect();
                        (first, w)
                    })
                    .collect()
            })
            .collect();
        let mut first = Vec::new();
        let mut start = vec![0];
        let mut weights = Vec::new();
        for (f, w) in per_column.into_iter().flatten() {
            first.push(f);
            weights.extend_from_slice(&w);
            start.push(weights.len());
        }
        let h = half_cells as f64 + 0.5;
        Self {
            half_cells,
            cell_rad,
            annuli_per_cell,
            annuli: (h.hypot(h) * m - 1e-9).ceil() as usize,
            first,
            start,
            weights,
        }
    }

    /// Window side W = 2H + 1, cells.
    pub fn window(&self) -> usize {
        2 * self.half_cells + 1
    }

    /// Annuli needed to reach the window's corner.
    pub fn annuli(&self) -> usize {
        self.annuli
    }

    /// Annulus width δ = Δθ / m_t, radians.
    pub fn annulus_width_rad(&self) -> f64 {
        self.cell_rad / self.annuli_per_cell.max(1) as f64
    }

    /// The angles t_i = (i + ½)δ at which the density must be known, radians.
    pub fn annulus_midpoints_rad(&self) -> Vec<f64> {
        let d = self.annulus_width_rad();
        (0..self.annuli).map(|i| (i as f64 + 0.5) * d).collect()
    }

    /// First annulus and weights (rad²) of cell (kx, ky), any signs within the window.
    pub fn cell(&self, kx: isize, ky: isize) -> (usize, &[f64]) {
        let (a, b) = (kx.unsigned_abs(), ky.unsigned_abs());
        let c = octant_index(a.max(b), a.min(b));
        (
            self.first[c],
            &self.weights[self.start[c]..self.start[c + 1]],
        )
    }

    /// Cells of the window from the density at the annulus midpoints (sr⁻¹,
    /// at least [`CellWeights::annuli`] values): W×W row-major, rows along
    /// θy, the on-axis cell at (H, H).
    pub fn cells(&self, density: &[f64]) -> Vec<f64> {
        let h = self.half_cells;
        let w = self.window();
        let octant: Vec<f64> = (0..self.first.len())
            .into_par_iter()
            .map(|c| {
                let f = self.first[c];
                self.weights[self.start[c]..self.start[c + 1]]
                    .iter()
                    .zip(&density[f..])
                    .map(|(a, p)| a * p)
                    .sum()
            })
            .collect();
        let mut out = vec![0.0; w * w];
        for kx in 0..=h {
            for ky in 0..=kx {
                let v = octant[octant_index(kx, ky)];
                for (a, b) in [(kx, ky), (ky, kx)] {
                    for (row, col) in [
                        (h + a, h + b),
                        (h - a, h + b),
                        (h + a, h - b),
                        (h - a, h - b),
                    ] {
                        out[row * w + col] = v;
                    }
                }
            }
        }
        out
    }
}

/// The cells of a window by Richardson extrapolation of the exact-area rule
/// ([`CellWeights`]) from annuli of Δθ/m_t and Δθ/(m_t/2): (4·fine − coarse)/3.
/// The rule's error is c·δ² + O(δ³…) (tests: the change falls 4× per
/// doubling of m_t), so this cancels its leading term; it needs the density
/// at 1.5·m_t angles per cell width instead of the 4·m_t the plain rule
/// needs for the same accuracy.
#[derive(Debug, Clone)]
pub struct WindowCells {
    fine: CellWeights,
    coarse: CellWeights,
}

impl WindowCells {
    /// A window of half-width `half_cells` for cells of `cell_rad`, with
    /// `annuli_per_cell` (even, ≥ 2) annuli per cell width on the finer rule.
    pub fn new(half_cells: usize, cell_rad: f64, annuli_per_cell: usize) -> Self {
        let m = annuli_per_cell.max(2) & !1;
        Self {
            fine: CellWeights::new(half_cells, cell_rad, m),
            coarse: CellWeights::new(half_cells, cell_rad, m / 2),
        }
    }

    /// Window side W = 2H + 1, cells.
    pub fn window(&self) -> usize {
        self.fine.window()
    }

    /// Annuli per cell width of the finer rule.
    pub fn annuli_per_cell(&self) -> usize {
        self.fine.annuli_per_cell
    }

    /// The angles (rad) at which the density is needed: the finer rule's
    /// annulus midpoints, then the coarser rule's.
    pub fn angles_rad(&self) -> Vec<f64> {
        let mut t = self.fine.annulus_midpoints_rad();
        t.extend(self.coarse.annulus_midpoints_rad());
        t
    }

    /// Cells (W×W, row-major, on-axis at (H, H)) from the density at
    /// [`WindowCells::angles_rad`].
    pub fn cells(&self, density: &[f64]) -> Vec<f64> {
        let (fine, coarse) = density.split_at(self.fine.annuli());
        self.fine
            .cells(fine)
            .iter()
            .zip(self.coarse.cells(coarse))
            .map(|(f, c)| (4.0 * f - c) / 3.0)
            .collect()
    }
}

mod kernel;

#[cfg(test)]
mod tests;
