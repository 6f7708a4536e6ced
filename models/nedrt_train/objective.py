"""nedrt's exact objective in torch, from the kernels `nedrt prefilter
--operator` writes (runtime/app/src/prefilter_batch.rs): the squared error
of the perceived images against the targets summed over the headline
depths, its per-depth errors, and the perceived distance of two display
images, each by one FFT pair per channel on the mirrored frame. The D-CNN
stage (distill.py) trains on it; the ceiling (ceiling.py) solves it per
frame."""
import json
import math
from pathlib import Path

import torch


class Objective:
    """½ Σ_D ‖A_D d − t_D‖² of P×P frames from nedrt's kernels
    (`operator-PxP.safetensors`, runtime/app/src/prefilter_batch.rs): on the
    mirrored 2P×2P grid, ¼ (½ d̃·(κ_M ⊛ d̃) − d̃·(κ_C ⊛ Ĩ) + ½ Ĩ·(κ_T ⊛ Ĩ))."""

    NAMES = ("normal", "adjoint_target", "target_gram")

    def __init__(self, kernels: dict, depths: int):
        """`kernels`: the three kernels, each channels × 2h × 2w, and where
        given the same per depth (`NAME_per_depth`, depths × channels × 2h × 2w)."""
        shape = kernels["normal"].shape
        self.size = (shape[-2] // 2, shape[-1] // 2)
        self.depths = depths
        spectrum = lambda k: torch.fft.rfft2(torch.as_tensor(k).double()).to(torch.complex64)
        self.spectra = {k: spectrum(kernels[k]) for k in self.NAMES}
        self.depth_spectra = ({k: spectrum(kernels[k + "_per_depth"]) for k in self.NAMES}
                              if all(k + "_per_depth" in kernels for k in self.NAMES) else None)
        # The lsq prefilter (the split solver's start), where the file has it.
        self.linear = spectrum(kernels["linear"]) if "linear" in kernels else None

    def to(self, device) -> "Objective":
        """The same objective with its spectra on `device`."""
        self.spectra = {k: v.to(device) for k, v in self.spectra.items()}
        if self.depth_spectra is not None:
            self.depth_spectra = {k: v.to(device) for k, v in self.depth_spectra.items()}
        if self.linear is not None:
            self.linear = self.linear.to(device)
        return self

    def lsq(self, image: torch.Tensor) -> torch.Tensor:
        """nedrt's `lsq` prefilter of `image` before the clamp (B×C×h×w)."""
        if self.linear is None:
            raise ValueError("these kernels have no lsq filter (an older nedrt prefilter --operator)")
        h, w = self.size
        m = self.mirror(image)
        return torch.fft.irfft2(torch.fft.rfft2(m) * self.linear, s=m.shape[-2:])[..., :h, :w]

    @classmethod
    def load(cls, path: Path) -> "Objective":
        from safetensors import safe_open
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no kernel file (nedrt prefilter --operator WxH writes it)")
        with safe_open(str(path), framework="pt") as f:
            meta = f.metadata() or {}
            if meta.get("format") != "nedrt objective kernels 1":
                raise ValueError(f"{path}: not a kernel file of nedrt prefilter --operator")
            kernels = {k: f.get_tensor(k) for k in f.keys()}
        objective = cls(kernels, len(json.loads(meta["depths_d"])))
        objective.meta = meta
        return objective

    @staticmethod
    def mirror(x: torch.Tensor) -> torch.Tensor:
        x = torch.cat([x, x.flip(-1)], dim=-1)
        return torch.cat([x, x.flip(-2)], dim=-2)

    def _conv(self, x: torch.Tensor, name: str) -> torch.Tensor:
        s = x.shape[-2:]
        return torch.fft.irfft2(torch.fft.rfft2(x) * self.spectra[name], s=s)

    def __call__(self, display: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
        """Per frame (B,): the objective."""
        if tuple(display.shape[-2:]) != self.size:
            raise ValueError(f"frames of {tuple(display.shape[-2:])}, kernels for {self.size}")
        d, i = self.mirror(display), self.mirror(image)
        value = (0.5 * (d * self._conv(d, "normal")) - d * self._conv(i, "adjoint_target")
                 + 0.5 * (i * self._conv(i, "target_gram"))).sum(dim=(1, 2, 3))
        return 0.25 * value

    def depth_mse(self, display: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
        """Per frame and depth (B × D): the mean squared error of the
        perceived image against the target over channels and retinal
        values, from which the evaluation's PSNR is −10 log10."""
        if self.depth_spectra is None:
            raise ValueError("these kernels have no per-depth terms (an older nedrt prefilter --operator)")
        h, w = self.size
        d, i = self.mirror(display)[:, None], self.mirror(image)[:, None]
        s = d.shape[-2:]
        conv = lambda x, k: torch.fft.irfft2(torch.fft.rfft2(x) * self.depth_spectra[k], s=s)
        value = (0.5 * (d * conv(d, "normal")) - d * conv(i, "adjoint_target")
                 + 0.5 * (i * conv(i, "target_gram"))).sum(dim=(2, 3, 4))
        return 0.5 * value / (display.shape[1] * 4 * h * w)

    def seen_distance(self, display: torch.Tensor, other: torch.Tensor) -> torch.Tensor:
        """Per frame: the mean squared difference of the two display
        images' perceived images, per depth, channel and retinal value (the
        objective's scale: `mse` of `display` against a target that `other`
        meets exactly)."""
        h, w = self.size
        e = self.mirror(display - other)
        value = 0.125 * (e * self._conv(e, "normal")).sum(dim=(1, 2, 3))
        return 2 * value / (self.depths * display.shape[1] * 4 * h * w)

    def mse(self, display: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
        """Per frame: the mean squared error per depth, channel and retinal value."""
        h, w = self.size
        return 2 * self(display, image) / (self.depths * display.shape[1] * 4 * h * w)


def db(mse) -> float:
    return float(-10 * math.log10(max(float(mse), 1e-30)))
