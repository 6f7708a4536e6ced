"""The DOE stage of the recipe: optimise a rotationally symmetric height
profile h(ρ) for the display with a linear (Wiener) prefilter, for a chosen
target, by the expected error over natural-image spectra.

    nedrt-train design --target multifocal --out models/runs/design-multifocal
    nedrt-train design --target allsharp --out models/runs/design-allsharp
    python -m nedrt_train.design --target allsharp --out models/runs/design-allsharp --resume

(from the repository root, or with `--calib FILE` and `--images DIR`).

Model (docs/training.md, "The DOE stage"). Per colour channel, the PSFs h_D
of the lens + DOE over the accommodation sweep (radial model, cells
integrated exactly, the rest of the light a uniform veil) give the display-
grid transfer K_D(f) = ¼ Σ_a T(ν_x) T(ν_y) H_D(ν), ν = (f + a)/2,
T(ν) = 2cos²(πν), the frequency form of nedrt's exact relation
down2(up2(x) ∗ h) = x ∗ k. The prefilter is nedrt's: G = K̄/(K̄² + κ) scaled
to unit gain at zero frequency, K̄ the mean of K_D over the sweep. The error
of the perceived image at depth D against its target T_D (the sharp image,
or the h_b-blurred one at the multifocal target's intermediate depths) is,
on the retinal grid where nedrt scores,

    E_D = Σ_ν S(2ν) · 4cos²(πν_x)cos²(πν_y) · |G(2ν) H_D(ν) − T_D(ν)|²,

S the power spectrum of natural images, S ∝ |f|^−α with α fitted to the
training photographs. The objective is the mean over the design depths of
the error in dB plus a soft minimum (the worst depth), both against the
signal's power. κ (the Wiener constant) is optimised with the profile; the
clamp to the panel's [0, 1] is not in this linear model, so the exported
design's K is re-tuned with the clamp by `nedrt tune-wiener`.

Checkpointed (atomic) and resumable; a resume with another calibration,
target or model is refused. Writes metrics.csv, checkpoint.pt, and at the
end the DOE at the design and fabrication pitches (radial profiles, docs/doe-format.md)
and design.json (the recipe, wall time, final figures).
"""
import argparse
import csv
import dataclasses
import hashlib
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from . import calib as calib_mod
from .data import photo_folder, resolve_root
from .keys import keys_profile
from .radial import RadialPsfModel, radial_nodes

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


def file_hash(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


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


def display_kernel(cells: torch.Tensor) -> torch.Tensor:
    """Display-grid kernel of a retinal PSF (W×W, W odd, centred), nedrt's
    `display_kernel`: k[n, m] = ¼ Σ_{a,b ∈ {−1,0,1}} w_a w_b h[2n + a, 2m + b],
    w = (1, 2, 1). Returns (2·half + 1)² with half = ⌈(W//2)/2⌉."""
    w = cells.shape[-1]
    c = w // 2
    half = (c + 1) // 2
    side = 2 * half + 1
    pad = 2 * half + 1 - c
    padded = torch.nn.functional.pad(cells, (pad, pad, pad, pad))
    tri = torch.tensor([1.0, 2.0, 1.0], dtype=cells.dtype)
    smooth = torch.nn.functional.conv2d(padded[None, None], (tri[:, None] * tri[None, :] / 4)[None, None], padding=1)[0, 0]
    centre = c + pad
    rows = centre + 2 * (torch.arange(side) - half)
    return smooth[rows][:, rows]


def wiener_gain(kernel: torch.Tensor, veil: float, k_reg: float, height: int, width: int) -> torch.Tensor:
    """G over the rfft2 spectrum of a mirrored 2h×2w frame: K̄/(K̄² + κ)
    scaled to unit gain at zero frequency, K̄ the kernel's transfer (the veil
    at zero frequency), as nedrt's WienerFilter."""
    side = kernel.shape[-1]
    grid = torch.zeros(2 * height, 2 * width, dtype=kernel.dtype)
    grid[:side, :side] = kernel
    grid = torch.roll(grid, shifts=(-(side // 2), -(side // 2)), dims=(0, 1))
    transfer = torch.fft.rfft2(grid)
    transfer[0, 0] += veil
    dc = transfer[0, 0].real
    return transfer.conj() / (transfer.real ** 2 + transfer.imag ** 2 + k_reg) * ((dc ** 2 + k_reg) / dc)


def wiener_display(image: torch.Tensor, gains) -> torch.Tensor:
    """clamp(F⁻¹{G·F{I}}, 0, 1) per channel on the mirrored frame (image C×H×W)."""
    _, h, w = image.shape
    mirrored = torch.cat([image, image.flip(-1)], dim=-1)
    mirrored = torch.cat([mirrored, mirrored.flip(-2)], dim=-2)
    out = [torch.fft.irfft2(torch.fft.rfft2(mirrored[c]) * gains[c], s=(2 * h, 2 * w))[:h, :w] for c in range(image.shape[0])]
    return torch.stack(out).clamp(0, 1)


@torch.no_grad()
def evaluate(model: DesignModel, images: list, k_reg: float, depths_d=None) -> list:
    """PSNR (dB) vs sharp and vs target per depth with the display clamped
    to [0, 1], averaged over `images` (C×H×W tensors, sides multiples of 8)
    and, for a pupil range, over its pupils (as the objective is)."""
    per_pupil = [_evaluate(model, optics, images, k_reg, depths_d) for optics in model.pupil_optics()]
    return [{"accommodation_d": rows[0]["accommodation_d"],
             "psnr_vs_sharp": float(np.mean([r["psnr_vs_sharp"] for r in rows])),
             "psnr_vs_target": float(np.mean([r["psnr_vs_target"] for r in rows]))}
            for rows in zip(*per_pupil)]


def _evaluate(model: DesignModel, optics, images: list, k_reg: float, depths_d=None) -> list:
    from .optics import perceive, target, up2
    calib = model.calib
    depths_d = depths_d or [d for d in calib.depths_d if d <= 2.5 + 1e-9]
    sweep = [optics.psfs(ch, [calib.psi_rad(ch, d) for d in model.sweep_d]) for ch in range(len(calib.channels))]
    mean_psfs = [(c.mean(0), float(v.mean())) for c, v in sweep]
    blur = optics.target_blur()
    rows = {d: {"sharp": [], "target": []} for d in depths_d}
    for image in images:
        _, h, w = image.shape
        gains = [wiener_gain(display_kernel(c), v, k_reg, h, w) for c, v in mean_psfs]
        display = wiener_display(image, gains)
        for d in depths_d:
            perceived = perceive(display, optics.system(d))
            for key, ref in [("sharp", up2(image)), ("target", target(image, calib, d, blur))]:
                rows[d][key].append(float(10 * torch.log10(1 / ((perceived - ref) ** 2).mean())))
    return [{"accommodation_d": d, "psnr_vs_sharp": float(np.mean(r["sharp"])),
             "psnr_vs_target": float(np.mean(r["target"]))} for d, r in rows.items()]


def load_images(folder: Path, limit: int | None = None) -> list:
    """The PNGs of `folder` as C×H×W float64 tensors in [0, 1] (linear),
    cropped to multiples of 8 like nedrt eval; with `limit`, every n-th of
    the sorted names so that at most `limit` are read."""
    from PIL import Image
    out = []
    paths = sorted(Path(folder).glob("*.png"))
    if limit and len(paths) > limit:
        paths = paths[::math.ceil(len(paths) / limit)]
    for p in paths:
        img = np.asarray(Image.open(p).convert("RGB"), dtype=np.float64) / 255
        h, w = img.shape[0] // 8 * 8, img.shape[1] // 8 * 8
        out.append(torch.from_numpy(np.ascontiguousarray(img[:h, :w])).permute(2, 0, 1))
    if not out:
        raise ValueError(f"{folder}: no PNG images")
    return out


def tune_k(model: DesignModel, images: list, target: str) -> tuple:
    """K on quarter decades 10^-4 … 10^0 maximising the mean PSNR over
    0–2.5 D with the clamp (vs sharp for allsharp, vs target for multifocal),
    as `nedrt tune-wiener` searches."""
    key = "psnr_vs_target" if target == "multifocal" else "psnr_vs_sharp"
    best = None
    for e in range(-16, 1):
        k = 10 ** (e / 4)
        rows = evaluate(model, images, k)
        score = float(np.mean([r[key] for r in rows]))
        if best is None or score > best[1]:
            best = (k, score, rows)
    return best


def training_crops(folder: Path, count: int, side: int, seed: int) -> torch.Tensor:
    """`count` fixed crops (side×side display pixels, C×H×W in [0, 1]) of the
    training photographs, cycling through them in name order, each at a
    position drawn from `seed`."""
    images = load_images(folder)
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        img = images[i % len(images)]
        _, h, w = img.shape
        if h < side or w < side:
            raise ValueError(f"{folder}: photograph {i % len(images)} is {w}×{h}, smaller than a {side}² crop")
        y, x = int(rng.integers(0, h - side + 1)), int(rng.integers(0, w - side + 1))
        out.append(img[:, y:y + side, x:x + side])
    return torch.stack(out)


def _rng_state():
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state()}


def design_calib(cfg: DesignConfig):
    """The calibration of a design: the file, with the config's eye LCA."""
    calib = calib_mod.load(cfg.calib)
    if cfg.eye_lca is not None:
        calib = dataclasses.replace(calib, eye_lca=cfg.eye_lca)
    return calib


def identity(cfg: DesignConfig) -> dict:
    """What a checkpoint must share with the run that resumes it."""
    return {"target": cfg.target, "calib_sha": file_hash(cfg.calib), "window": cfg.window,
            "objective": cfg.objective, "crops": cfg.crops,
            "frequencies": cfg.frequencies, "design_range_d": list(cfg.design_range_d),
            "design_step_d": cfg.design_step_d,
            # Only a pupil range enters, so earlier checkpoints still resume.
            **({"pupils_mm": list(cfg.pupils_mm)} if cfg.pupils_mm else {}),
            **({"eye_lca": cfg.eye_lca} if cfg.eye_lca is not None else {})}


#: Training photographs the clamped K search uses (every n-th, sorted by name):
#: 17 K values × 8 photos × 6 depths is about two minutes on one core.
TUNE_IMAGES = 8


def design(cfg: DesignConfig, out: Path, resume: bool = False, images_dir: Path | None = None,
           tune: bool = True) -> dict:
    """The DOE stage in `out`. `images_dir` is the training photographs'
    folder (data/images/train): the spectrum fit, the crops of the images
    objective and the clamped K search read it; the command line passes
    `--images`'s train/."""
    if cfg.target not in TARGETS:
        raise ValueError(f"target {cfg.target!r}: choose one of {', '.join(TARGETS)}")
    calib = design_calib(cfg)
    out.mkdir(parents=True, exist_ok=True)
    ckpt = out / "checkpoint.pt"
    state = None
    if resume:
        if not ckpt.exists():
            raise ValueError(f"{ckpt}: nothing to resume (no checkpoint)")
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        theirs, mine = state["identity"], identity(cfg)
        diff = [k for k in mine if theirs.get(k) != mine[k]]
        if diff:
            raise ValueError(
                f"{ckpt}: cannot resume: the checkpoint was made with "
                + ", ".join(f"{k} = {theirs.get(k)!r}" for k in diff)
                + "; this run has " + ", ".join(f"{k} = {mine[k]!r}" for k in diff)
                + ". Start a new run in another --out folder.")
        alpha = state["alpha"]
    else:
        if ckpt.exists():
            raise ValueError(f"{ckpt} exists: pass --resume to continue it, or choose another --out")
        alpha = cfg.spectrum_alpha if cfg.spectrum_alpha is not None else fit_spectrum_alpha(photo_folder(images_dir))
    torch.manual_seed(cfg.seed)
    crops = None
    if cfg.objective == "images":
        crops = training_crops(photo_folder(images_dir), cfg.crops,
                               cfg.frequencies // 2, cfg.seed)
    crops_sha = hashlib.sha256(crops.numpy().tobytes()).hexdigest()[:16] if crops is not None else None
    if state and state.get("crops_sha") != crops_sha:
        raise ValueError(f"{ckpt}: cannot resume: the training crops differ from the checkpoint's "
                         "(data/images/train changed); start a new run in another --out folder")
    model = DesignModel(cfg, calib, alpha, crops=crops)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    step, elapsed = 0, 0.0
    if state:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        step, elapsed = state["step"], state["elapsed_s"]
        torch.set_rng_state(state["rng"]["torch"])
    log_path = out / "metrics.csv"
    new_log = not log_path.exists() or step == 0
    log = open(log_path, "w" if new_log else "a", newline="")
    writer = csv.writer(log)
    if new_log:
        writer.writerow(["step", "objective", "mean_db", "worst_db", "k", "seconds"])
    start = time.time() - elapsed

    def save():
        tmp = Path(str(ckpt) + ".tmp")
        torch.save({"model": model.state_dict(), "optimizer": opt.state_dict(), "step": step,
                    "elapsed_s": time.time() - start, "alpha": alpha, "identity": identity(cfg),
                    "crops_sha": crops_sha,
                    "config": dataclasses.asdict(cfg), "rng": _rng_state()}, tmp)
        os.replace(tmp, ckpt)

    bar = tqdm(range(step, cfg.steps), initial=step, total=cfg.steps, desc=f"design {cfg.target}")
    for step in bar:
        loss, db = model.objective()
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        writer.writerow([step, f"{loss.item():.6f}", f"{db.mean().item():.4f}", f"{db.min().item():.4f}",
                         f"{model.log_k.exp().item():.6g}", f"{time.time() - start:.2f}"])
        bar.set_postfix(mean=f"{db.mean().item():.2f}", worst=f"{db.min().item():.2f}", K=f"{model.log_k.exp().item():.3g}")
        if step % cfg.checkpoint_every == 0 or step == cfg.steps:
            log.flush()
            save()
    log.close()
    if step < cfg.steps or not ckpt.exists():
        save()
    with torch.no_grad():
        _, db = model.objective()
    k_clamped, train_rows = None, None
    if tune:
        tune_images = load_images(photo_folder(images_dir), limit=TUNE_IMAGES)
        k_clamped, _, train_rows = tune_k(model, tune_images, cfg.target)
    result = {
        "target": cfg.target, "steps": step, "wall_time_s": round(time.time() - start, 1),
        "threads": torch.get_num_threads(), "spectrum_alpha": alpha,
        "wiener_k_linear": model.log_k.exp().item(),
        "wiener_k": k_clamped,
        "train_psnr_clamped": train_rows,
        "design_depths_d": model.design_d,
        "expected_db": [round(v, 3) for v in db.tolist()],
        # The calibration relative to the working directory when inside it,
        # so that a shipped design.json names no machine's folders.
        "config": {**dataclasses.asdict(cfg), "calib": portable_path(cfg.calib)},
        "calib_sha": file_hash(cfg.calib),
    }
    return result


def portable_path(path) -> str:
    """`path` relative to the working directory if it lies inside it."""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(p)


def export_design(run: Path, name: str, out: Path) -> dict:
    """The run's DOE as radial files at the design and fabrication pitches."""
    from .export import save_doe, sha256
    state = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=False)
    cfg = DesignConfig(**{**state["config"], "design_range_d": tuple(state["config"]["design_range_d"])})
    calib = design_calib(cfg)
    optics = RadialPsfModel(calib, calib.doe_design_pitch_m, cfg.window)
    optics.doe.load_state_dict({"logit": state["model"]["optics.doe.logit"]})
    height = optics.doe().detach().double().numpy()
    out.mkdir(parents=True, exist_ok=True)
    lam0 = calib.channels[calib.design_channel].wavelength_m
    desc = f"nedrt_train.design {cfg.target}, {state['step']} steps"
    design_path = out / f"doe-{name}-design.safetensors"
    fab_path = out / f"doe-{name}-fabrication.safetensors"
    save_doe(design_path, height, calib.doe_design_pitch_m, calib.doe_max_height_m, calib.material_name, lam0, desc)
    fab_rho, _ = radial_nodes(calib.aperture_radius_m, calib.doe_fabrication_pitch_m)
    fine = keys_profile(height, calib.doe_design_pitch_m, fab_rho, calib.doe_max_height_m)
    save_doe(fab_path, fine, calib.doe_fabrication_pitch_m, calib.doe_max_height_m, calib.material_name, lam0,
             desc + " (Keys cubic to the fabrication pitch)")
    return {"files": {p.name: sha256(p) for p in [design_path, fab_path]}}


def main(argv=None, prog=None):
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", choices=TARGETS, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--steps", type=int)
    ap.add_argument("--lr", type=float)
    ap.add_argument("--window", type=int)
    ap.add_argument("--calib", metavar="FILE",
                    help="calibration TOML (default: calib/default.toml under the current directory)")
    ap.add_argument("--images", metavar="DIR",
                    help="image root whose train/ the design reads (default: data/images under the current directory)")
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--no-tune", dest="tune", action="store_false", help="skip the clamped K search on training photographs")
    ap.add_argument("--name", help="also write the DOE files doe-NAME-{design,fabrication}.safetensors into --out")
    ap.add_argument("--pupils-mm", type=lambda v: tuple(float(x) for x in v.split(",")), metavar="MM,MM,…",
                    help="design for these eye pupils (mm), their objectives averaged "
                         "(default: the calibration's eye; docs/model.md §4a)")
    ap.add_argument("--eye-lca", choices=["on", "off"],
                    help="the eye's chromatic aberration, Thibos 1992 (default: the calibration's eye.lca)")
    args = ap.parse_args(argv)
    overrides = {k: getattr(args, k) for k in ["steps", "lr", "window", "pupils_mm"] if getattr(args, k) is not None}
    if args.eye_lca is not None:
        overrides["eye_lca"] = args.eye_lca == "on"
    if any(not 0 < p <= 12 for p in overrides.get("pupils_mm", ())):
        raise SystemExit(f"error: --pupils-mm {args.pupils_mm}: each pupil must lie in (0, 12] mm")
    try:
        calib = calib_mod.resolve(args.calib)
        images = resolve_root(args.images)
    except FileNotFoundError as e:
        raise SystemExit(f"error: {e}")
    cfg = dataclasses.replace(DesignConfig(target=args.target), calib=str(calib), **overrides)
    try:
        result = design(cfg, args.out, resume=args.resume, images_dir=images / "train", tune=args.tune)
    except (ValueError, FileNotFoundError) as e:
        raise SystemExit(f"error: {e}")
    if args.name:
        result.update(export_design(args.out, args.name, args.out))
    tmp = args.out / "design.json.tmp"
    tmp.write_text(json.dumps(result, indent=1))
    os.replace(tmp, args.out / "design.json")
    print(json.dumps({k: result[k] for k in ["target", "steps", "wall_time_s", "expected_db", "wiener_k_linear"]}, indent=1))


if __name__ == "__main__":
    main()
