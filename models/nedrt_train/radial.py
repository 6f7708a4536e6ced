"""Rotationally symmetric optics (docs/optics-model.md, "Radial path"): the
PSF of a radial pupil by a Hankel transform, every retinal cell integrated
over its square, in PyTorch with autograd through the DOE's heights.

Lens, aperture and the three-lens DOE are rotationally symmetric, so the
pupil is a profile Q(ρ) and the field in angle is a Hankel transform

    U(t) = Σ_n Q(ρ_n) · J0(2π ρ_n t / λ) · w_n,   ρ_n = (n + ½)Δρ,
    w_n = π (min(b_n, r)² − a_n²),  a_n = nΔρ, b_n = (n + 1)Δρ,

the continuous hard-edged aperture in annuli (Σ w_n = π r² exactly). The
angular energy density is p(t) = |U(t)|² / (λ² E), E = Σ |Q_n|² w_n, which
integrates to 1 over the plane. A retinal cell holds Σ_i p(t_i)·area(cell ∩
annulus_i) over annuli of width δ = Δθ/m_t with t_i their midpoints, the
areas exact geometry (`disk_rect_area`), extrapolated in m_t (Richardson,
see `ANNULI_PER_CELL`). Light outside the window is the uniform veil, as in
the 2-D model.

Nedrt's radial path (runtime/optics/src/radial.rs) uses the same
conventions; a DOE file with a radial profile stores heights at (n + ½)·pitch.
"""
import math

import numpy as np
import torch
import torch.nn as nn

from .calib import Calib
from .keys import keys_taps

#: Annuli per retinal cell. The midpoint rule in t is second order; the
#: in-focus Airy core (radius 0.42 Δθ at r = 5 mm) is the hardest case:
#: 0.75 % of the peak off at m_t = 16, 0.19 % at 32. Richardson's
#: combination (4·cells(m_t) − cells(m_t/2))/3 cancels the second-order term:
#: ≤ 0.07 % of the peak at m_t = 16 for 1.5× the cost of m_t = 16 alone
#: (tests/test_radial.py::test_cells_converge_in_the_annulus_width).
ANNULI_PER_CELL = 16


def radial_nodes(radius_m: float, pitch_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature nodes ρ_n = (n + ½)·pitch (m) and their annulus areas w_n
    (m²) inside the aperture, for every annulus that starts inside it."""
    n = math.ceil(radius_m / pitch_m - 1e-9)
    a = np.arange(n) * pitch_m
    b = np.minimum(a + pitch_m, radius_m)
    return (np.arange(n) + 0.5) * pitch_m, math.pi * (b ** 2 - a ** 2)


def three_lens_profile(calib: Calib, rho_m) -> torch.Tensor:
    """Heights (m) of the three-lens initial DOE (docs/model.md §5) at radii `rho_m`."""
    rho2 = torch.as_tensor(rho_m, dtype=torch.float64) ** 2 / calib.aperture_radius_m ** 2
    g = calib.design_channel
    total = sum(torch.exp(-1j * calib.psi_rad(g, d) * rho2) for d in calib.main_d)
    phi = torch.remainder(torch.angle(total), 2 * math.pi)
    return phi / (2 * math.pi) * calib.wave_height_m


def _quadrant_area(x: np.ndarray, y: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Area of disk(radius) ∩ [0, x] × [0, y] for x, y ≥ 0 (closed form)."""
    r = np.maximum(radius, 0.0)

    def g(u):  # ∫_0^u √(r² − s²) ds
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = np.where(r > 0, u / np.where(r > 0, r, 1), 0.0)
        return 0.5 * (u * np.sqrt(np.maximum(r * r - u * u, 0.0)) + r * r * np.arcsin(np.clip(ratio, -1, 1)))

    xp = np.minimum(x, r)
    u_full = np.sqrt(np.maximum(r * r - y * y, 0.0))
    m = np.minimum(u_full, xp)
    return y * m + g(xp) - g(m)


def disk_rect_area(radius, x0, x1, y0, y1) -> np.ndarray:
    """Area of the disk of `radius` about the origin inside the rectangle
    [x0, x1] × [y0, y1] (any signs), exact: signed quadrant areas."""
    def f(x, y):
        return np.sign(x) * np.sign(y) * _quadrant_area(np.abs(x), np.abs(y), radius)
    return f(x1, y1) - f(x0, y1) - f(x1, y0) + f(x0, y0)


def octant_cells(window: int):
    """Offsets (kx, ky), 0 ≤ ky ≤ kx ≤ W//2, of the cells a radial PSF's
    eight-fold symmetry leaves distinct, and for each of the W×W cells
    (row-major) the index of its octant representative."""
    half = window // 2
    kx, ky = np.meshgrid(np.arange(half + 1), np.arange(half + 1), indexing="xy")
    keep = ky <= kx
    kx, ky = kx[keep], ky[keep]
    lookup = -np.ones((half + 1, half + 1), dtype=np.int64)
    lookup[ky, kx] = np.arange(len(kx))
    off = np.abs(np.arange(window) - half)
    ay, ax = np.meshgrid(off, off, indexing="ij")
    full = lookup[np.minimum(ay, ax), np.maximum(ay, ax)].ravel()
    return kx, ky, full


def annulus_cell_weights(window: int, cell_rad: float, annuli_per_cell: int = ANNULI_PER_CELL):
    """For the octant cells of a window×window block centred on the axis
    (`octant_cells`): per cell the index of its first annulus and the areas
    (rad²) it shares with the following annuli (zeros past its last), and
    the annulus midpoints t_i."""
    delta = cell_rad / annuli_per_cell
    kx, ky, _ = octant_cells(window)
    cx, cy = kx * cell_rad, ky * cell_rad
    x0, x1 = cx - cell_rad / 2, cx + cell_rad / 2
    y0, y1 = cy - cell_rad / 2, cy + cell_rad / 2
    near = np.hypot(np.clip(0, x0, x1), np.clip(0, y0, y1))
    far = np.hypot(np.maximum(abs(x0), abs(x1)), np.maximum(abs(y0), abs(y1)))
    first = np.floor(near / delta + 1e-9).astype(np.int64)
    last = np.ceil(far / delta - 1e-9).astype(np.int64)          # exclusive
    k = int((last - first).max())
    edges = (first[:, None] + np.arange(k + 1)[None, :]) * delta
    disk = disk_rect_area(edges, x0[:, None], x1[:, None], y0[:, None], y1[:, None])
    weights = np.diff(disk, axis=1)
    n_annuli = int(last.max())
    index = np.minimum(first[:, None] + np.arange(k)[None, :], n_annuli - 1)
    weights[first[:, None] + np.arange(k)[None, :] >= n_annuli] = 0.0
    t = (np.arange(n_annuli) + 0.5) * delta
    return index, weights, t


def cell_operator(window: int, cell_rad: float, annuli_per_cell: int = ANNULI_PER_CELL, richardson: bool = True):
    """(index, weights, t): cells = Σ_k p(t[index[c, k]])·weights[c, k].
    With `richardson`, the annuli of width Δθ/m_t and Δθ/(m_t/2) together,
    weighted 4/3 and −1/3 (the extrapolation of the midpoint rule)."""
    fine = annulus_cell_weights(window, cell_rad, annuli_per_cell)
    if not richardson:
        return fine
    coarse = annulus_cell_weights(window, cell_rad, annuli_per_cell // 2)
    index = np.concatenate([fine[0], coarse[0] + len(fine[2])], axis=1)
    weights = np.concatenate([fine[1] * 4 / 3, coarse[1] * -1 / 3], axis=1)
    return index, weights, np.concatenate([fine[2], coarse[2]])


class RadialPsfModel(nn.Module):
    """PSFs of the lens (+ a radial DOE h(ρ)) on a window of retinal cells.

    The DOE is parameterised by its heights at (n + ½)·pitch (the 6 µm
    design pitch), kept within [0, max] by a sigmoid. The pupil is
    integrated on the finer quadrature pitch (by default the 3 µm
    fabrication pitch), the heights carried there by the same Keys cubic
    interpolation that makes the fabrication file: the model sees the
    element that is made. Sampling the wraps at 6 µm instead moves
    defocused PSFs by up to 10 % of their peak against the 3 µm element
    (docs/training.md). The J0 kernels (one per channel, annulus areas
    folded in) and the cell weights depend only on the geometry, so they
    are computed once.
    """

    def __init__(self, calib: Calib, pitch_m: float, window: int,
                 doe_init_m: torch.Tensor | None = None, dtype=torch.float64,
                 annuli_per_cell: int = ANNULI_PER_CELL, quadrature_pitch_m: float | None = None,
                 richardson: bool = True, pupil_diameter_m: float | None = None):
        super().__init__()
        from .optics import DoeHeight
        if window % 2 != 1:
            raise ValueError(f"window = {window}: an odd number of cells puts a cell centre on the axis")
        self.calib, self.pitch_m, self.window = calib, pitch_m, window
        quad = min(pitch_m, calib.doe_fabrication_pitch_m) if quadrature_pitch_m is None else quadrature_pitch_m
        self.quadrature_pitch_m = quad
        r = calib.aperture_radius_m
        design_rho, _ = radial_nodes(r, pitch_m)
        rho, area = radial_nodes(r, quad)
        index, weights, t = cell_operator(window, calib.retinal_step_rad, annuli_per_cell, richardson)
        # The kernel must resolve J0 out to the window's corner (Nyquist in ρ).
        lam_min = min(c.wavelength_m for c in calib.channels)
        t_max = float(t.max())
        if quad > lam_min / (2 * t_max):
            raise ValueError(
                f"pupil pitch {quad * 1e6:.2f} µm cannot resolve a {window}-cell window "
                f"(needs ≤ {lam_min / (2 * t_max) * 1e6:.2f} µm at {lam_min * 1e9:.0f} nm)")
        # Finer than the fabrication pitch, the heights go design → fabrication
        # file → quadrature, each by Keys, as nedrt simulates the fabrication file.
        fab = calib.doe_fabrication_pitch_m
        stages = [(len(design_rho), pitch_m, rho)]
        if quad < fab < pitch_m:
            fab_rho, _ = radial_nodes(r, fab)
            stages = [(len(design_rho), pitch_m, fab_rho), (len(fab_rho), fab, rho)]
        self.stages = len(stages)
        for i, (n_src, src_pitch, at) in enumerate(stages):
            taps, tap_weights = keys_taps(n_src, src_pitch, at)
            self.register_buffer(f"taps_{i}", torch.tensor(taps))
            self.register_buffer(f"tap_weights_{i}", torch.tensor(tap_weights, dtype=dtype))
        self.register_buffer("rho2", torch.tensor(rho ** 2 / r ** 2, dtype=dtype))
        self.register_buffer("area", torch.tensor(area, dtype=dtype))
        self.register_buffer("cell_index", torch.tensor(index))
        self.register_buffer("octant_of_cell", torch.tensor(octant_cells(window)[2]))
        self.register_buffer("cell_weight", torch.tensor(weights, dtype=dtype))
        self.register_buffer("t", torch.tensor(t, dtype=dtype))
        rho_t = torch.tensor(rho, dtype=torch.float64)
        t_t = torch.tensor(t, dtype=torch.float64)
        # The eye's pupil, centred (docs/model.md §4a): each channel's stop
        # r_e,λ clips the annuli (`pupil_diameter_m` overrides the
        # calibration's; the aperture's radius where no pupil limits).
        inner = np.arange(len(rho)) * quad
        outer = np.minimum(inner + quad, r)
        self.stop_radius_m = []
        for ch, c in enumerate(calib.channels):
            r_e = calib.stop_radius_m(ch, pupil_diameter_m)
            self.stop_radius_m.append(r_e)
            area_ch = area if r_e >= r else math.pi * (np.minimum(outer, r_e) ** 2 - np.minimum(inner, r_e) ** 2)
            j0 = torch.special.bessel_j0(2 * math.pi * torch.outer(t_t, rho_t) / c.wavelength_m)
            self.register_buffer(f"kernel_{ch}", (j0 * torch.tensor(area_ch)[None, :]).to(dtype))
            self.register_buffer(f"energy_{ch}", torch.tensor(float(area_ch.sum()), dtype=dtype))
        init = three_lens_profile(calib, design_rho) if doe_init_m is None else torch.as_tensor(doe_init_m, dtype=torch.float64)
        if init.shape != (len(design_rho),):
            raise ValueError(f"radial DOE has {tuple(init.shape)} samples; {len(design_rho)} at {pitch_m * 1e6} µm cover the aperture")
        self.doe = DoeHeight(init.to(dtype), calib.doe_max_height_m)
        self.register_buffer("design_rho_m", torch.tensor(design_rho, dtype=dtype))

    @property
    def rho_m(self) -> torch.Tensor:
        """Quadrature nodes (m)."""
        return self.rho2.sqrt() * self.calib.aperture_radius_m

    def heights_on_quadrature(self, design_height_m: torch.Tensor) -> torch.Tensor:
        """Design-pitch heights → the quadrature nodes (Keys cubic, clamped)."""
        h = design_height_m
        for i in range(self.stages):
            h = (h[getattr(self, f"taps_{i}")] * getattr(self, f"tap_weights_{i}")).sum(-1)
            h = h.clamp(0, self.calib.doe_max_height_m)
        return h

    def field(self, ch: int, psi_rad, with_doe: bool = True, height_m: torch.Tensor | None = None):
        """(Re U, Im U) at the annulus nodes `t` for each Ψ in `psi_rad`."""
        psi = torch.as_tensor(psi_rad, dtype=self.rho2.dtype, device=self.rho2.device).reshape(-1, 1)
        phase = psi * self.rho2[None, :]
        if with_doe:
            height = self.heights_on_quadrature(self.doe() if height_m is None else height_m)
            phase = phase + self.calib.doe_phase_per_m(ch) * height[None, :]
        kernel = getattr(self, f"kernel_{ch}")
        return torch.cos(phase) @ kernel.T, torch.sin(phase) @ kernel.T

    def density(self, ch: int, psi_rad, with_doe: bool = True, height_m: torch.Tensor | None = None):
        """Angular energy density p(t) = |U|²/(λ² E) (per rad²) at the nodes `t`."""
        re, im = self.field(ch, psi_rad, with_doe, height_m)
        energy = getattr(self, f"energy_{ch}")      # |Q| = 1 inside the stop
        return (re * re + im * im) / (self.calib.channels[ch].wavelength_m ** 2 * energy)

    def psfs(self, ch: int, psi_rad, with_doe: bool = True, height_m: torch.Tensor | None = None):
        """(cells B×W×W, veil B) for channel `ch` at each defocus Ψ in
        `psi_rad` (a sequence); `height_m` (design-pitch heights) overrides
        the module's DOE."""
        density = self.density(ch, psi_rad, with_doe, height_m)
        octant = (density[:, self.cell_index] * self.cell_weight[None]).sum(-1)
        cells = octant[:, self.octant_of_cell].reshape(-1, self.window, self.window)
        return cells, 1 - cells.sum(dim=(-2, -1))

    def psf(self, ch: int, psi_rad: float, with_doe: bool = True, height_m: torch.Tensor | None = None):
        """(cells W×W, veil) for one channel and defocus; the interface of
        the 2-D `PsfModel`, so `perceive` takes either."""
        cells, veil = self.psfs(ch, [psi_rad], with_doe, height_m)
        return cells[0], veil[0]

    def system(self, accommodation_d: float, with_doe: bool = True):
        return [self.psf(ch, self.calib.psi_rad(ch, accommodation_d), with_doe) for ch in range(len(self.calib.channels))]

    def target_blur(self):
        return [self.psf(ch, self.calib.target_blur_psi_rad, with_doe=False) for ch in range(len(self.calib.channels))]
