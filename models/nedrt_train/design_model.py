"""The DOE stage's differentiable model (design.py optimises it; its
docstring and docs/training.md, "The DOE stage", give the maths): the
design's configuration and targets, the radial DOE with log κ through the
pupils it is made for, the display-grid transfer and the Wiener gain, and
the objective, the per-depth error as expected over natural-image spectra
("spectrum") or exact on clamped crops of the training photographs
("images"); and the fit of the spectrum's slope α on the photographs."""
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .radial import RadialPsfModel

#: The design targets (`--target`).
TARGETS = ("multifocal", "allsharp")


@dataclass(frozen=True)
class DesignConfig:
    target: str = "multifocal"
    steps: int = 600
    lr: float = 0.05
    # PSF window (cells) of the design model; light outside is the veil.
    window: int = 121
    # Display-grid frequency samples per axis of the expected error.
    frequencies: int = 128
    # Depth sweep of the objective (D), and the soft-min's temperature (dB)
    # and weight against the mean.
    design_range_d: tuple = (0.0, 2.5)
    design_step_d: float = 0.1
    softmin_db: float = 0.5
    worst_weight: float = 0.5
    # "images": the clamped error on fixed crops of the training photographs
    # (display-grid side `frequencies`/2, mirrored like nedrt's Wiener), by
    # Parseval; "spectrum": the expected error over S ∝ |f|^−α, unclamped.
    objective: str = "images"
    crops: int = 32
    # Spectral slope of natural images; None fits it on the training photos.
    spectrum_alpha: float | None = None
    initial_k: float = 0.03
    seed: int = 0
    checkpoint_every: int = 50
    # Eye pupils (mm) the design is made for, their objectives averaged (a
    # pupil that varies over a range: one design); empty: the calibration's
    # eye (docs/model.md §4a).
    pupils_mm: tuple = ()
    # The eye's chromatic aberration (Thibos 1992) on or off; None: the calibration's.
    eye_lca: bool | None = None
    # The calibration TOML: an absolute path the command line resolves
    # (--calib); no default here.
    calib: str | None = None


def fit_spectrum_alpha(images_dir: Path) -> float:
    """Slope α of the radially averaged power spectrum |F|² ∝ f^−α of the
    photographs in `images_dir`, fitted in log-log over 1/32–1/2 cycles per
    pixel (a Hann window against edge leakage)."""
    from PIL import Image
    logs_f, logs_p = [], []
    for p in sorted(images_dir.glob("*.png")):
        img = np.asarray(Image.open(p).convert("RGB"), dtype=np.float64) / 255
        h, w = img.shape[:2]
        win = np.outer(np.hanning(h), np.hanning(w))
        for c in range(3):
            x = img[..., c] - img[..., c].mean()
            power = np.abs(np.fft.fft2(x * win)) ** 2
            fy = np.fft.fftfreq(h)[:, None]
            fx = np.fft.fftfreq(w)[None, :]
            f = np.hypot(fy, fx)
            edges = np.geomspace(1 / 32, 0.5, 13)
            for lo, hi in zip(edges[:-1], edges[1:]):
                band = (f >= lo) & (f < hi)
                if band.any():
                    logs_f.append(math.log(math.sqrt(lo * hi)))
                    logs_p.append(math.log(power[band].mean()))
    if len(logs_f) < 2:
        raise ValueError(f"{images_dir}: no PNG photographs to fit the spectrum on")
    slope = np.polyfit(logs_f, logs_p, 1)[0]
    return float(-slope)


class DesignModel(torch.nn.Module):
    """The radial DOE, log κ, and the expected-error objective."""

    def __init__(self, cfg: DesignConfig, calib, alpha: float, dtype=torch.float64, crops: torch.Tensor | None = None):
        super().__init__()
        if cfg.objective not in ("images", "spectrum"):
            raise ValueError(f"objective {cfg.objective!r}: choose images or spectrum")
        if cfg.objective == "images":
            if crops is None or crops.shape[-1] * 2 != cfg.frequencies:
                raise ValueError(f"the images objective needs crops of side {cfg.frequencies // 2}")
            mirrored = torch.cat([crops, crops.flip(-1)], dim=-1)
            self.register_buffer("mirrored", torch.cat([mirrored, mirrored.flip(-2)], dim=-2).to(dtype))
            self.register_buffer("input_hat", torch.fft.fft2(self.mirrored))
        self.cfg, self.calib = cfg, calib
        pupils = [p * 1e-3 for p in cfg.pupils_mm] or [None]
        self.optics = RadialPsfModel(calib, calib.doe_design_pitch_m, cfg.window, dtype=dtype,
                                     pupil_diameter_m=pupils[0])
        # Every pupil sees the one DOE (its parameters shared).
        self.other_pupils = torch.nn.ModuleList()
        for pupil in pupils[1:]:
            m = RadialPsfModel(calib, calib.doe_design_pitch_m, cfg.window, dtype=dtype, pupil_diameter_m=pupil)
            m.doe = self.optics.doe
            self.other_pupils.append(m)
        self.log_k = torch.nn.Parameter(torch.tensor(math.log(cfg.initial_k), dtype=dtype))
        md = cfg.frequencies
        m = 2 * md
        if cfg.window > m:
            raise ValueError(f"window {cfg.window} exceeds the {m}-cell frequency grid")
        nu = torch.fft.fftfreq(m, dtype=dtype)                     # cycles per retinal cell
        f = torch.fft.fftfreq(md, dtype=dtype)                      # cycles per display pixel
        fr = torch.hypot(f[:, None], f[None, :])
        spectrum = torch.where(fr > 0, fr.clamp_min(1e-12) ** -alpha, torch.zeros_like(fr))
        self.register_buffer("spectrum_ret", spectrum.repeat(2, 2))   # S(2ν), periodic in f
        box = 4 * torch.cos(math.pi * nu) ** 2                      # |1 + e^{−j2πν}|²: up2's pixel box
        self.register_buffer("up2_gain", box[:, None] * box[None, :])
        tri = 2 * torch.cos(math.pi * nu) ** 2                      # T(ν), indexed a·Md + k
        self.register_buffer("tri", tri.reshape(2, md))
        self.signal = float((self.spectrum_ret * self.up2_gain).sum())
        lo, hi = calib.range_d
        step = calib.wiener_average_step_d
        n = round((hi - lo) / step)
        self.sweep_d = [lo + i * (hi - lo) / n for i in range(n + 1)]
        dlo, dhi = cfg.design_range_d
        if cfg.target == "multifocal":
            self.design_d = [d for d in calib.depths_d if dlo - 1e-9 <= d <= dhi + 1e-9]
        else:
            k = round((dhi - dlo) / cfg.design_step_d)
            self.design_d = [dlo + i * (dhi - dlo) / k for i in range(k + 1)]
        self.all_d = sorted(set(round(d, 9) for d in self.sweep_d + self.design_d))
        with torch.no_grad():
            # The target's blur through each pupil (as nedrt computes it).
            blur = [torch.stack([self._spectrum(*o.psf(ch, calib.target_blur_psi_rad, with_doe=False))
                                 for ch in range(len(calib.channels))]) for o in self.pupil_optics()]
        # The first pupil's under the name it always had (checkpoints resume).
        for i, b in enumerate(blur):
            self.register_buffer("blur_otf" if i == 0 else f"blur_otf_{i}", b)

    def pupil_optics(self) -> list:
        """The optics of every design pupil (one without a pupil range)."""
        return [self.optics, *self.other_pupils]

    def pupil_blur(self, i: int) -> torch.Tensor:
        """The target blur's transfer (per channel) through pupil `i`."""
        return getattr(self, "blur_otf" if i == 0 else f"blur_otf_{i}")

    def _spectrum(self, cells: torch.Tensor, veil) -> torch.Tensor:
        """Retinal-grid transfer H(ν) (real: the PSFs are symmetric) of
        cells (…×W×W, on-axis centre) with the veil at zero frequency."""
        m = 2 * self.cfg.frequencies
        w = cells.shape[-1]
        grid = torch.zeros(cells.shape[:-2] + (m, m), dtype=cells.dtype, device=cells.device)
        grid[..., :w, :w] = cells
        grid = torch.roll(grid, shifts=(-(w // 2), -(w // 2)), dims=(-2, -1))
        h = torch.fft.fft2(grid).real
        h[..., 0, 0] = h[..., 0, 0] + veil
        return h

    def display_transfer(self, h: torch.Tensor) -> torch.Tensor:
        """K(f) = ¼ Σ_a T(ν_x) T(ν_y) H(ν), ν = (f + a)/2 (display grid)."""
        md = self.cfg.frequencies
        h4 = h.reshape(h.shape[:-2] + (2, md, 2, md))
        t = self.tri
        return (h4 * t[:, :, None, None] * t[None, None, :, :]).sum(dim=(-4, -2)) / 4

    def depth_errors(self, height_m: torch.Tensor | None = None):
        """Per channel, per design depth: error power E_D / signal power, and
        the Wiener gain G; `height_m` overrides the DOE (design-pitch heights)."""
        per_pupil = [self._depth_errors(o, self.pupil_blur(i), height_m) for i, o in enumerate(self.pupil_optics())]
        return torch.stack(per_pupil).mean(0)

    def _depth_errors(self, optics, blur_otf, height_m):
        errors, kappa = [], self.log_k.exp()
        index = {round(d, 9): i for i, d in enumerate(self.all_d)}
        sweep_rows = [index[round(d, 9)] for d in self.sweep_d]
        design_rows = [index[round(d, 9)] for d in self.design_d]
        for ch in range(len(self.calib.channels)):
            psi = [self.calib.psi_rad(ch, d) for d in self.all_d]
            cells, veil = optics.psfs(ch, psi, height_m=height_m)
            h = self._spectrum(cells, veil)
            k = self.display_transfer(h[sweep_rows]).mean(0)
            gain = k / (k * k + kappa) * ((k[0, 0] ** 2 + kappa) / k[0, 0])
            g_ret = gain.repeat(2, 2)
            rows = []
            for i, d in zip(design_rows, self.design_d):
                goal = 1.0
                if self.cfg.target == "multifocal" and not self.calib.is_main_depth(d):
                    goal = blur_otf[ch]
                err = (g_ret * h[i] - goal) ** 2
                rows.append((self.spectrum_ret * self.up2_gain * err).sum() / self.signal)
            errors.append(torch.stack(rows))
        return torch.stack(errors)                                  # channels × depths

    def clamped_errors(self, height_m: torch.Tensor | None = None):
        """Per design depth: the mean squared error on the retinal grid of the
        crops' perceived images, display = clamp(Wiener(crop), 0, 1), against
        the target, over crops and channels, computed exactly in the
        frequency domain of the mirrored frames (Parseval): with D, I the
        display's and the input's spectra, E_D = Σ_ν |B(ν)|² |D(2ν) H_D(ν) −
        I(2ν) T_D(ν)|² / (4c)⁴ for crops of side c."""
        per_pupil = [self._clamped_errors(o, self.pupil_blur(i), height_m) for i, o in enumerate(self.pupil_optics())]
        return torch.stack(per_pupil).mean(0)

    def _clamped_errors(self, optics, blur_otf, height_m):
        kappa = self.log_k.exp()
        index = {round(d, 9): i for i, d in enumerate(self.all_d)}
        sweep_rows = [index[round(d, 9)] for d in self.sweep_d]
        design_rows = [index[round(d, 9)] for d in self.design_d]
        side = self.mirrored.shape[-1] * 2                           # retinal side of a mirrored crop
        total = 0
        for ch in range(len(self.calib.channels)):
            psi = [self.calib.psi_rad(ch, d) for d in self.all_d]
            cells, veil = optics.psfs(ch, psi, height_m=height_m)
            h = self._spectrum(cells, veil)
            k = self.display_transfer(h[sweep_rows]).mean(0)
            gain = k / (k * k + kappa) * ((k[0, 0] ** 2 + kappa) / k[0, 0])
            x = self.input_hat[:, ch]
            display = torch.fft.ifft2(x * gain).real.clamp(0, 1)
            d_hat = torch.fft.fft2(display)
            # Crop sums of |D|², Re(D I*), |I|² on the display grid, tiled to 2ν.
            a = (d_hat.real ** 2 + d_hat.imag ** 2).sum(0).repeat(2, 2) * self.up2_gain
            b = (d_hat * x.conj()).real.sum(0).repeat(2, 2) * self.up2_gain
            c = (x.real ** 2 + x.imag ** 2).sum(0).repeat(2, 2) * self.up2_gain
            rows = []
            for i, d in zip(design_rows, self.design_d):
                goal = blur_otf[ch] if self.cfg.target == "multifocal" and not self.calib.is_main_depth(d) else 1.0
                hd = h[i]
                rows.append((a * hd * hd - 2 * b * hd * goal + c * goal * goal).sum())
            total = total + torch.stack(rows)
        crops = self.mirrored.shape[0]
        return total / (len(self.calib.channels) * crops * side ** 4)

    def objective(self, height_m: torch.Tensor | None = None):
        """(loss, dB per design depth): PSNR of the clamped display on the
        crops ("images") or signal-to-error ratio of the linear model
        ("spectrum"); the loss trades their mean against a soft minimum."""
        if self.cfg.objective == "images":
            rel = self.clamped_errors(height_m)
        else:
            rel = self.depth_errors(height_m).mean(0)                # mean over channels
        db = -10 * torch.log10(rel)
        tau = self.cfg.softmin_db
        soft_worst = -tau * torch.logsumexp(-db / tau, 0) + tau * math.log(len(db))
        w = self.cfg.worst_weight
        return -((1 - w) * db.mean() + w * soft_worst), db
