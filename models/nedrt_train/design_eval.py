"""The DOE stage on photographs (design.py uses it after the optimisation,
tests/test_design.py against the model): nedrt's clamped Wiener prefilter
in torch (the display kernel of a PSF, the gain, the display image), the
PSNR per depth it gives through a design, the clamped K search as `nedrt
tune-wiener` makes it, and the photographs and fixed crops it reads."""
import math
from pathlib import Path

import numpy as np
import torch

from .design_model import DesignModel


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
