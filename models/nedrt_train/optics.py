"""Differentiable display optics (docs/model.md §4–§10) in PyTorch: the pupil with
the DOE's height map, PSFs on the retinal grid by matrix Fourier transform
with complex autograd, and the perceived image. Conventions are those of
tests/golden/vectors.json, which the tests reproduce:

- pupil grid: the DOE's own grid, N = ceil(2r/Δs) + 1 samples at
  s_n = (n − (N−1)/2)·Δs; aperture A = clamp((r − ρ)/Δs + ½, 0, 1);
- Q = A·exp(j(Φ_λ + Ψρ²)), Φ_λ = 2π(n_λ − 1)·d/λ;
- cells integrated exactly over their squares (the m → ∞ limit of m×m
  midpoint sums, as nedrt's `exact_period_cells`): with the pupil's
  autocorrelation A_ℓ, cell c holds Σ_ℓ A_ℓ sinc(ℓ_y/P) sinc(ℓ_x/P)
  e^{−2πiℓ·c/P} / (P²·Σ|Q|²), P = λ/(Δs Δθ), cells centred at
  (c − (W−1)/2)·Δθ; veil = 1 − Σ cells (light outside the window).

This 2-D model is the free-form option (GPU runs); the default trainer
optics is the radial model of `radial.py`, 20–40× cheaper on a CPU.
"""
import math

import torch
import torch.nn as nn

from .calib import Calib


def grid(calib: Calib, pitch_m: float, dtype=torch.float64) -> torch.Tensor:
    n = math.ceil(2 * calib.aperture_radius_m / pitch_m - 1e-9) + 1
    return (torch.arange(n, dtype=dtype) - (n - 1) / 2) * pitch_m


def three_lens_init(calib: Calib, s: torch.Tensor) -> torch.Tensor:
    """Heights (m) of the three-lens initial DOE on the grid s (docs/model.md §5)."""
    r = calib.aperture_radius_m
    rho2 = (s[None, :] ** 2 + s[:, None] ** 2) / r ** 2
    g = calib.design_channel
    total = sum(torch.exp(-1j * calib.psi_rad(g, d) * rho2) for d in calib.main_d)
    phi = torch.remainder(torch.angle(total), 2 * math.pi)
    return phi / (2 * math.pi) * calib.wave_height_m


class DoeHeight(nn.Module):
    """A height map kept within [0, max] by construction: d = max·sigmoid(θ)."""

    def __init__(self, init_m: torch.Tensor, max_height_m: float, eps: float = 1e-4):
        super().__init__()
        self.max_height_m = max_height_m
        ratio = (init_m / max_height_m).clamp(eps, 1 - eps)
        self.logit = nn.Parameter(torch.log(ratio) - torch.log1p(-ratio))

    def forward(self) -> torch.Tensor:
        return self.max_height_m * torch.sigmoid(self.logit)


class PsfModel(nn.Module):
    """PSFs of the lens (+ DOE) on a window of retinal cells, per channel,
    for a free-form 2-D height map.

    The DOE is parameterised on the pupil grid `pitch_m` (the 6 µm design
    grid); the window is fixed at construction, so the lag-to-cell Fourier
    matrices and the sinc weights are computed once.
    """

    def __init__(self, calib: Calib, pitch_m: float, window: int,
                 doe_init_m: torch.Tensor | None = None, dtype=torch.float64):
        super().__init__()
        if window % 2 != 1:
            raise ValueError(f"window = {window}: an odd number of cells puts a cell centre on the axis")
        if calib.eye_pupil_diameter_m is not None:
            # Only the radial model puts the eye's pupil in the pupil.
            raise ValueError("the 2-D optics model the paper's eye only (no eye.pupil_diameter_mm); "
                             "train a radial profile for an eye with a pupil (docs/model.md §4a)")
        self.calib, self.pitch_m, self.window = calib, pitch_m, window
        s = grid(calib, pitch_m, dtype)
        n = len(s)
        r = calib.aperture_radius_m
        rho = torch.hypot(s[None, :], s[:, None])
        self.register_buffer("amplitude", ((r - rho) / pitch_m + 0.5).clamp(0, 1))
        self.register_buffer("rho2", rho ** 2 / r ** 2)
        # Lags −(N−1) … N−1 of the autocorrelation, and their rows in an FFT of size 2N.
        lags = torch.arange(-(n - 1), n, dtype=torch.float64)
        self.register_buffer("lag_rows", torch.remainder(torch.arange(-(n - 1), n), 2 * n))
        cells = torch.arange(window, dtype=torch.float64) - (window - 1) / 2
        for ch, c in enumerate(calib.channels):
            period = c.wavelength_m / (pitch_m * calib.retinal_step_rad)
            e = torch.exp(-2j * math.pi * torch.outer(cells, lags) / period)
            self.register_buffer(f"fourier_{ch}", e.to(torch.complex128 if dtype == torch.float64 else torch.complex64))
            self.register_buffer(f"sinc_{ch}", torch.sinc(lags / period).to(dtype))
        init = three_lens_init(calib, s) if doe_init_m is None else doe_init_m.to(dtype)
        self.doe = DoeHeight(init, calib.doe_max_height_m)

    def psf(self, ch: int, psi_rad: float, with_doe: bool = True, height_m: torch.Tensor | None = None):
        """(cells W×W, veil) for channel `ch` at defocus Ψ; `height_m`
        overrides the module's DOE (for functional use and gradient checks)."""
        c = self.calib.channels[ch]
        phase = psi_rad * self.rho2
        if with_doe:
            height = self.doe() if height_m is None else height_m
            phase = phase + self.calib.doe_phase_per_m(ch) * height
        q = self.amplitude * torch.exp(1j * phase)
        n = q.shape[0]
        spectrum = torch.fft.fft2(q, s=(2 * n, 2 * n))
        autocorr = torch.fft.ifft2(spectrum.real ** 2 + spectrum.imag ** 2)
        autocorr = autocorr.index_select(0, self.lag_rows).index_select(1, self.lag_rows)
        sinc = getattr(self, f"sinc_{ch}")
        weighted = autocorr * (sinc[:, None] * sinc[None, :])
        e = getattr(self, f"fourier_{ch}")
        period = c.wavelength_m / (self.pitch_m * self.calib.retinal_step_rad)
        energy = (self.amplitude ** 2).sum()
        cells = (e @ weighted @ e.transpose(0, 1)).real / (period ** 2 * energy)
        return cells, 1 - cells.sum()

    def system(self, accommodation_d: float, with_doe: bool = True):
        """Per-channel (cells, veil) of the display at an accommodation."""
        return [self.psf(ch, self.calib.psi_rad(ch, accommodation_d), with_doe) for ch in range(len(self.calib.channels))]

    def target_blur(self):
        return [self.psf(ch, self.calib.target_blur_psi_rad, with_doe=False) for ch in range(len(self.calib.channels))]


def symmetric_index(n_out: int, offset: int, n: int, device=None) -> torch.Tensor:
    """Indices of a symmetric (half-sample, edge repeated) extension."""
    i = torch.arange(n_out, device=device) - offset
    k = torch.remainder(i, 2 * n)
    return torch.where(k < n, k, 2 * n - 1 - k)


def up2(x: torch.Tensor) -> torch.Tensor:
    """Each display pixel → a 2×2 block of retinal cells."""
    return x.repeat_interleave(2, dim=-2).repeat_interleave(2, dim=-1)


def convolve(x: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """x (…, H, W) ∗ odd k×k kernel, symmetric padding by the half-width, cropped back."""
    a = kernel.shape[-1] // 2
    h, w = x.shape[-2:]
    iy = symmetric_index(h + 2 * a, a, h, x.device)
    ix = symmetric_index(w + 2 * a, a, w, x.device)
    padded = x.index_select(-2, iy).index_select(-1, ix)
    shape = padded.shape[-2:]
    # Kernel at the origin corner: full[p] = Σ_j padded[p − j]·k[j]; output y is p = y + 2a.
    spec = torch.fft.rfft2(padded) * torch.fft.rfft2(kernel.to(padded.dtype), s=shape)
    full = torch.fft.irfft2(spec, s=shape)
    return full[..., 2 * a:2 * a + h, 2 * a:2 * a + w]


def perceive(display: torch.Tensor, psfs) -> torch.Tensor:
    """Î = up2(I_d) ∗ h + veil·mean(I_d), per channel; display is (…, C, H, W)."""
    up = up2(display)
    out = []
    for ch, (cells, veil) in enumerate(psfs):
        plane = up[..., ch, :, :]
        mean = display[..., ch, :, :].mean(dim=(-2, -1), keepdim=True)
        out.append(convolve(plane, cells) + veil * mean)
    return torch.stack(out, dim=-3)


def target(image: torch.Tensor, calib: Calib, accommodation_d: float, blur_psfs) -> torch.Tensor:
    """The multifocal target: up2(I) at a main depth, up2(I) ∗ h_b elsewhere."""
    if calib.is_main_depth(accommodation_d):
        return up2(image)
    return perceive(image, blur_psfs)
