"""The D-CNN stage with the DOE frozen (issue 16, docs/training.md):

    nedrt prefilter --design multifocal --images data/images/train \\
        --out-dir out/teacher/train --operator 128x128,256x256
    nedrt prefilter --design multifocal --images data/images/val --out-dir out/teacher/val
    nedrt-train dcnn --teacher out/teacher --width 16 --steps 6000 --out models/runs/dcnn-half
    nedrt-train dcnn export --run models/runs/dcnn-half --name dcnn-half \
        --doe designs/multifocal/doe-fabrication.safetensors

The loss is the exact objective nedrt's `optimal` prefilter minimises: the
squared error of the perceived images against the targets summed over the
headline depths (all of them every step), computed from the kernels
`nedrt prefilter --operator` writes (one FFT pair per channel on the
mirrored patch, however wide the PSFs), on the clamped display image; plus
the distance to the teacher (the optimal display image of the whole
photograph, cropped and turned like the patch) and a penalty on output
outside [0, 1]. The network is the residual U-Net of unet.py, exported as
the runtime's ONNX. Checkpoints every `--checkpoint-every` steps; `--resume`
continues a run exactly (optimiser, schedule, random state).
"""
import argparse
import contextlib
import dataclasses
import json
import math
import os
import random
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from .data import load_photos, photo_folder, resolve_root
from .unet import UNet


@dataclass
class DistillConfig:
    width: int = 16
    levels: int = 4
    patch: int = 128
    batch: int = 8
    steps: int = 6000
    lr: float = 1e-3
    # Weight of the distance to the teacher (mean squared, display units)
    # against the objective's mean squared error (retinal, per depth).
    distill: float = 1.0
    # Weight of the squared excursion outside [0, 1] of the raw output.
    range_penalty: float = 1.0
    # "mse": the summed squared error over the depths (what `optimal`
    # minimises); "psnr": the mean over the depths of the per-depth PSNR,
    # per frame (what the evaluation's headline averages).
    loss: str = "mse"
    # With --loss psnr: weight of the mean per-depth PSNR against the sharp
    # image (kernels from DIR/train-sharp, nedrt prefilter
    # --prefilter optimal@sharp --operator …) beside the one against the target.
    sharp_weight: float = 0.0
    seed: int = 0
    teacher: str | None = None
    images: str | None = None
    validate_every: int = 500
    checkpoint_every: int = 250
    threads: int = 0
    # Start from the network of another run's checkpoint (a fresh optimiser
    # and schedule): distil first, then fine-tune on the metric.
    init: str | None = None
    # The residual's base: the input ("input", the runtime's network
    # I + UNet(I)) or the Wiener prefilter's output of the design ("wiener",
    # DIR/train-wiener and DIR/val-wiener; display = W(I) + UNet(I) − I,
    # the last layer started at zero so that training starts at the Wiener).
    base: str = "input"
    # The network's input: the photograph ("image") or the design's Wiener
    # output before the clamp ("wiener-raw", DIR/train-wiener-raw and
    # DIR/val-wiener-raw from nedrt prefilter --prefilter native --unclamped;
    # display = x + UNet(x) for x = W(I), the last layer started at zero,
    # so that training starts at the clamped Wiener and the network sees
    # where and by how much the clamp cuts).
    input: str = "image"
    # Gradient of the panel's clamp: "zero" outside [0, 1] (the clamp's
    # own) or "straight" (straight-through: the loss at the clamped image,
    # passed to the raw output as if unclamped, so that a value the clamp
    # cuts still learns which way it should move).
    clamp_grad: str = "zero"
    # The folder under --teacher whose display images are distilled
    # ("train": nedrt's optimum; "train-ceiling": nedrt-train ceiling
    # --split train --write, the optimum of the evaluation's mean PSNR).
    teacher_set: str = "train"
    # How the distance to the teacher is measured: in display values
    # ("display"), or as the eye sees it ("perceived": the mean squared
    # difference of the perceived images summed over the depths, through the
    # objective's normal kernel). The ceiling's display image carries
    # content the optics do not pass (its start's, unconstrained by the
    # objective); "perceived" does not ask the network to learn that.
    distill_metric: str = "display"
    # Where the step runs ("cpu", "cuda", "cuda:1", "meta" in tests): the
    # network, the objective's spectra, the photographs and their teachers
    # all live there; a checkpoint resumes on any device.
    device: str = "cpu"
    # Mixed precision of the network ("off", or "bf16": its convolutions
    # under autocast, float32 accumulation; the residual sum, the clamp and
    # the objective's FFTs stay float32, so the loss is computed in full
    # precision from a display image whose residual is good to bf16's 3
    # significant digits).
    amp: str = "off"
    # A wall-clock budget of the run, seconds (0: none): the schedule's
    # cosine follows the time spent instead of the steps, and the run stops
    # (checkpointed, validated) when the budget is spent or at `steps`.
    time_budget: float = 0.0
    # --batch 0: the largest batch of patches (a power of two, at most this)
    # whose step fits in the device's memory, probed before the first step.
    max_batch: int = 64


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

    def to(self, device) -> "Objective":
        """The same objective with its spectra on `device`."""
        self.spectra = {k: v.to(device) for k, v in self.spectra.items()}
        if self.depth_spectra is not None:
            self.depth_spectra = {k: v.to(device) for k, v in self.depth_spectra.items()}
        return self

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


def load_teacher(folder: Path, names: list) -> dict:
    """The teacher's display images (`displays.safetensors` of nedrt
    prefilter, or the shares `displays-K-of-N.safetensors` of a sharded
    `nedrt-train ceiling`), by photograph name."""
    from safetensors.torch import load_file
    path = folder / "displays.safetensors"
    files = [path] if path.is_file() else sorted(folder.glob("displays-*-of-*.safetensors"))
    if not files:
        raise FileNotFoundError(f"{path}: no teacher display images (run nedrt prefilter --out-dir {folder})")
    t = {}
    for f in files:
        for name, display in load_file(str(f)).items():
            if name in t:
                raise ValueError(f"{f}: {name} is also in another share of {folder}")
            t[name] = display
    missing = [n for n in names if n not in t]
    if missing:
        where = path if files == [path] else f"{folder}'s {len(files)} shares"
        raise ValueError(f"{where}: no display image for {', '.join(missing[:5])}")
    return {n: t[n].float() for n in names}


def photo_names(folder: Path) -> list:
    return [p.stem for p in sorted(photo_folder(folder).glob("*.png"))]


class Patches:
    """Random P×P crops of the training photographs under one of the eight
    symmetries of the square (the PSFs are rotationally symmetric, so the
    teacher turns with its photograph), with the teacher cropped alike.
    The draws come from one numpy generator in a fixed order (photograph,
    row, column, turn, flip per patch), so a batch is the same on any
    device; the crops are cut on the photographs' device, in a few
    operations per batch when the photographs are of one size."""

    def __init__(self, photos: list, teachers: list, patch: int, seed: int, bases: list | None = None,
                 device="cpu"):
        self.photos = [torch.from_numpy(p).permute(2, 0, 1).contiguous() for p in photos]
        stacks = (self.photos, teachers, bases)
        sizes = {tuple(t.shape) for stack in stacks if stack is not None for t in stack}
        # One tensor per stack where every photograph has the same size:
        # a batch is then one gather per stack.
        self.dense = len(sizes) == 1
        self.stacks = [None if stack is None else
                       (torch.stack(stack).to(device) if self.dense else [t.to(device) for t in stack])
                       for stack in stacks]
        self.patch = patch
        self.device = torch.device(device)
        self.rng = np.random.default_rng(seed)

    def draw(self, size: int) -> np.ndarray:
        """B × (photograph, row, column, turn, flip), in the generator's order."""
        out = np.empty((size, 5), dtype=np.int64)
        n = self.patch
        for b in range(size):
            k = self.rng.integers(len(self.photos))
            p = self.photos[k]
            y = self.rng.integers(p.shape[1] - n + 1)
            x = self.rng.integers(p.shape[2] - n + 1)
            out[b] = (k, y, x, int(self.rng.integers(4)), int(self.rng.integers(2)))
        return out

    def batch(self, size: int):
        """(images, teachers, bases or None), each B × 3 × P × P, on the device."""
        draws = self.draw(size)
        n = self.patch
        if not self.dense:
            out = [[], [], []]
            for k, y, x, turn, flip in draws:
                for i, stack in enumerate(self.stacks):
                    if stack is not None:
                        t = torch.rot90(stack[k][:, y:y + n, x:x + n], int(turn), (1, 2))
                        out[i].append(t.flip(-1) if flip else t)
            return tuple(torch.stack(o).contiguous() if o else None for o in out)
        # One upload a batch: the draws, and the patches ordered by symmetry.
        group = draws[:, 3] * 2 + draws[:, 4]
        order = np.argsort(group, kind="stable")
        d = torch.from_numpy(np.concatenate([draws, order[:, None]], axis=1)).to(self.device)
        ar = torch.arange(n, device=self.device)
        rows = (d[:, 1, None] + ar)[:, None, :, None]
        cols = (d[:, 2, None] + ar)[:, None, None, :]
        chan = torch.arange(3, device=self.device)[None, :, None, None]
        k = d[:, 0, None, None, None]
        crops = [None if stack is None else stack[k, chan, rows, cols] for stack in self.stacks]
        # The symmetries, one group of patches at a time (at most eight).
        counts = np.bincount(group, minlength=8)
        start = 0
        for g, count in enumerate(counts):
            idx = d[start:start + count, 5]
            start += count
            turn, flip = divmod(g, 2)
            if count == 0 or g == 0:
                continue
            for c in crops:
                if c is not None:
                    t = torch.rot90(c[idx], int(turn), (2, 3))
                    c[idx] = t.flip(-1) if flip else t
        return tuple(None if c is None else c.contiguous() for c in crops)


def forward(net, image, base=None, cfg=None):
    """The raw display image: I + UNet(I), base + UNet(I) − I (`--base
    wiener`), or x + UNet(x) of the raw Wiener x = base (`--input wiener-raw`);
    float32 whatever the network's precision (`--amp`)."""
    x = base if cfg is not None and cfg.input == "wiener-raw" else image
    with autocast(cfg, x.device):
        out = net(x)
    out = out.float()
    if cfg is not None and cfg.input == "wiener-raw":
        return out
    return out if base is None else base + (out - image)


def autocast(cfg, device):
    """The network's precision: bf16 autocast under `--amp bf16`, else none."""
    if cfg is None or cfg.amp == "off":
        return contextlib.nullcontext()
    if cfg.amp != "bf16":
        raise ValueError(f"amp {cfg.amp!r}: choose off or bf16")
    return torch.autocast(device_type=torch.device(device).type, dtype=torch.bfloat16)


def clamp(raw, cfg=None):
    """The panel's clamp, with the gradient `--clamp-grad` asks for."""
    display = raw.clamp(0, 1)
    if cfg is not None and cfg.clamp_grad == "straight":
        return raw + (display - raw).detach()
    return display


def losses(net, objective: Objective, image, teacher, cfg: DistillConfig, sharp: Objective | None = None,
           base=None):
    raw = forward(net, image, base, cfg)
    display = clamp(raw, cfg)
    if cfg.distill_metric == "perceived":
        distill = objective.seen_distance(display, teacher).mean()
    else:
        distill = F.mse_loss(display, teacher)
    excursion = (F.relu(raw - 1) ** 2 + F.relu(-raw) ** 2).mean()
    if cfg.loss == "psnr":
        per_depth = objective.depth_mse(display, image).clamp_min(1e-10)
        mse = per_depth.mean()
        # −mean PSNR, in units of 10 dB so that its size is that of the others.
        fit = torch.log10(per_depth).mean()
        if cfg.sharp_weight:
            fit = fit + cfg.sharp_weight * torch.log10(sharp.depth_mse(display, image).clamp_min(1e-10)).mean()
    elif cfg.loss == "mse":
        mse = fit = objective.mse(display, image).mean()
    else:
        raise ValueError(f"loss {cfg.loss!r}: choose mse or psnr")
    total = fit + cfg.distill * distill + cfg.range_penalty * excursion
    return total, {"mse": mse, "distill": distill, "range": excursion}


@torch.no_grad()
def validate(net, objective: Objective, images: torch.Tensor, teacher: torch.Tensor, wiener: torch.Tensor | None,
             sharp: Objective | None = None, base: torch.Tensor | None = None, net_input: torch.Tensor | None = None,
             cfg: DistillConfig | None = None):
    """Objective dB (−10 log10 of the mean squared error over depths) on the
    validation photographs: the network, the teacher (the optimum), and the
    Wiener prefilter where given. The network sees `net_input` where given
    (the raw Wiener), else the photographs."""
    net.eval()
    x = images if net_input is None else net_input
    with autocast(cfg, x.device):
        display = torch.cat([net.forward_padded(x[i:i + 1]).float() for i in range(len(x))])
    if base is not None:
        display = base + (display - images)
    display = display.clamp(0, 1)
    net.train()
    out = {}
    for name, d in [("dcnn", display), ("optimal", teacher), ("wiener", wiener)]:
        if d is None:
            continue
        out[f"{name}_db"] = db(objective.mse(d, images).mean())
        if objective.depth_spectra is not None:
            # The evaluation's headline vs target: per-depth PSNR averaged
            # over the photographs, then its mean and worst over the depths.
            psnr = (-10 * torch.log10(objective.depth_mse(d, images))).mean(dim=0)
            out[f"{name}_mean_db"] = float(psnr.mean())
            out[f"{name}_worst_db"] = float(psnr.min())
        if sharp is not None and name != "optimal":
            psnr = (-10 * torch.log10(sharp.depth_mse(d, images))).mean(dim=0)
            out[f"{name}_sharp_mean_db"] = float(psnr.mean())
            out[f"{name}_sharp_worst_db"] = float(psnr.min())
    return out


def lr_at(cfg: DistillConfig, step: int, elapsed: float = 0.0) -> float:
    """Linear warm-up over 200 steps, then cosine decay to 1 % of the peak
    over the steps, or over the time budget where there is one."""
    warm = min(1.0, (step + 1) / 200)
    progress = min(1.0, elapsed / cfg.time_budget) if cfg.time_budget > 0 else step / max(cfg.steps, 1)
    return cfg.lr * warm * (0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * progress)))


def step_once(net, opt, objective: Objective, data: "Patches", cfg: DistillConfig, sharp: Objective | None):
    """One Adam step on a fresh batch; the loss and its terms."""
    image, teacher, base = data.batch(cfg.batch)
    loss, terms = losses(net, objective, image, teacher, cfg, sharp, base)
    opt.zero_grad()
    loss.backward()
    opt.step()
    return loss, terms


def largest_batch(net, objective: Objective, cfg: DistillConfig, sharp: Objective | None) -> int:
    """`--batch 0`: the largest power of two up to `max_batch` whose step
    (forward and backward, no update) fits in the device's memory with a
    quarter to spare, probed on random patches; 8 on a device without a
    memory count (the CPU). Touches no random state of the run."""
    device = torch.device(cfg.device)
    if device.type != "cuda":
        return min(8, cfg.max_batch)
    total = torch.cuda.get_device_properties(device).total_memory
    gen = torch.Generator(device=device).manual_seed(0)
    best, b = 0, 1
    while b <= cfg.max_batch:
        try:
            torch.cuda.empty_cache()
            torch.cuda.reset_peak_memory_stats(device)
            shape = (b, 3, cfg.patch, cfg.patch)
            image, teacher, base = (torch.rand(shape, generator=gen, device=device) for _ in range(3))
            loss, _ = losses(net, objective, image, teacher, cfg, sharp, base)
            loss.backward()
            net.zero_grad(set_to_none=True)
            peak = torch.cuda.max_memory_allocated(device)
        except torch.OutOfMemoryError:
            break
        best = b
        # The next size doubles the activations; stop where that would not fit.
        if 2 * peak > 0.75 * total:
            break
        b *= 2
    net.zero_grad(set_to_none=True)
    torch.cuda.empty_cache()
    if best == 0:
        raise ValueError(f"not even one {cfg.patch}² patch fits in {device}'s memory")
    return best


def is_finished(cfg: DistillConfig, step: int, seconds: float) -> bool:
    """At its last step, or its time budget spent (its schedule has run out)."""
    return step >= cfg.steps or (cfg.time_budget > 0 and seconds >= cfg.time_budget)


def device_name(device: torch.device) -> str:
    """What the run ran on, for the card."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    if device.type == "cpu":
        return f"CPU ({torch.get_num_threads()} threads)"
    return str(device)


def save_checkpoint(path: Path, net, opt, step: int, cfg: DistillConfig, rng: np.random.Generator, seconds: float,
                    history: list):
    tmp = Path(str(path) + ".tmp")
    torch.save({"net": net.state_dict(), "optimizer": opt.state_dict(), "step": step,
                "config": dataclasses.asdict(cfg), "data_rng": rng.bit_generator.state,
                "torch_rng": torch.get_rng_state(), "python_rng": random.getstate(),
                "seconds": seconds, "history": history}, tmp)
    os.replace(tmp, path)


def prepare(cfg: DistillConfig) -> SimpleNamespace:
    """What a run's steps use, each on `cfg.device`: the network (and its
    optimiser), the objectives, the patches and the validation set. The
    step on a GPU is the step on the CPU with this one argument changed."""
    if cfg.amp not in ("off", "bf16"):
        raise ValueError(f"amp {cfg.amp!r}: choose off or bf16")
    try:
        device = torch.device(cfg.device)
    except RuntimeError as e:
        raise ValueError(f"device {cfg.device!r}: {e}") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {cfg.device!r}: this torch sees no CUDA device")
    if cfg.batch < 0 or cfg.max_batch < 1:
        raise ValueError(f"batch {cfg.batch}, max-batch {cfg.max_batch}: a batch is ≥ 1 (or 0: the largest that fits)")
    teacher_root, images_root = Path(cfg.teacher), Path(cfg.images)
    objective = Objective.load(teacher_root / "train" / f"operator-{cfg.patch}x{cfg.patch}.safetensors").to(device)
    names = photo_names(images_root / "train")
    photos = load_photos(images_root / "train")
    teachers = load_teacher(teacher_root / cfg.teacher_set, names)
    if cfg.base not in ("input", "wiener"):
        raise ValueError(f"base {cfg.base!r}: choose input or wiener")
    if cfg.input not in ("image", "wiener-raw"):
        raise ValueError(f"input {cfg.input!r}: choose image or wiener-raw")
    if cfg.input == "wiener-raw" and cfg.base != "input":
        raise ValueError("--input wiener-raw is its own residual base: leave --base at input")
    if cfg.distill_metric not in ("display", "perceived"):
        raise ValueError(f"distill-metric {cfg.distill_metric!r}: choose display or perceived")
    if cfg.clamp_grad not in ("zero", "straight"):
        raise ValueError(f"clamp-grad {cfg.clamp_grad!r}: choose zero or straight")
    bases = None
    if cfg.base == "wiener" or cfg.input == "wiener-raw":
        folder = "train-wiener" if cfg.base == "wiener" else "train-wiener-raw"
        wiener_train = load_teacher(teacher_root / folder, names)
        bases = [wiener_train[n] for n in names]
    data = Patches(photos, [teachers[n] for n in names], cfg.patch, cfg.seed, bases, device)
    val_names = photo_names(images_root / "val")
    val_images = torch.from_numpy(np.stack(load_photos(images_root / "val"))).permute(0, 3, 1, 2).contiguous()
    val_images = val_images.to(device)
    val_teacher = torch.stack([t for t in load_teacher(teacher_root / "val", val_names).values()]).to(device)
    vh, vw = val_images.shape[-2:]
    val_objective = Objective.load(teacher_root / "train" / f"operator-{vw}x{vh}.safetensors").to(device)
    sharp_root = teacher_root / "train-sharp"
    has_sharp = (sharp_root / f"operator-{vw}x{vh}.safetensors").is_file()
    if cfg.sharp_weight and not has_sharp:
        raise FileNotFoundError(f"{sharp_root}: no kernels for the sharp objective (--sharp-weight needs "
                                "nedrt prefilter --prefilter optimal@sharp --operator …)")
    sharp = (Objective.load(sharp_root / f"operator-{cfg.patch}x{cfg.patch}.safetensors").to(device)
             if cfg.sharp_weight else None)
    val_sharp = Objective.load(sharp_root / f"operator-{vw}x{vh}.safetensors").to(device) if has_sharp else None
    wiener_dir = teacher_root / "val-wiener"
    val_wiener = (torch.stack(list(load_teacher(wiener_dir, val_names).values())).to(device)
                  if (wiener_dir / "displays.safetensors").is_file() else None)
    if cfg.base == "wiener" and val_wiener is None:
        raise FileNotFoundError(f"{wiener_dir}: --base wiener needs the Wiener's validation images "
                                "(nedrt prefilter --prefilter native)")
    val_input = (torch.stack(list(load_teacher(teacher_root / "val-wiener-raw", val_names).values())).to(device)
                 if cfg.input == "wiener-raw" else None)

    net = UNet(cfg.width, cfg.levels)
    if cfg.base == "wiener" or cfg.input == "wiener-raw":
        # Start exactly at the Wiener prefilter: the residual is zero.
        with torch.no_grad():
            net.out.weight.zero_()
            net.out.bias.zero_()
    if cfg.init:
        init = Path(cfg.init)
        init = init / "checkpoint.pt" if init.is_dir() else init
        if not init.is_file():
            raise FileNotFoundError(f"{init}: no checkpoint to start from (--init)")
        saved = torch.load(init, map_location="cpu", weights_only=False)
        if (saved["config"]["width"], saved["config"]["levels"]) != (cfg.width, cfg.levels):
            raise ValueError(f"{init}: a network of width {saved['config']['width']} and "
                             f"{saved['config']['levels']} levels, this run's is {cfg.width} and {cfg.levels}")
        net.load_state_dict(saved["net"])
    net.to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    return SimpleNamespace(device=device, teacher_root=teacher_root, objective=objective, sharp=sharp, data=data, net=net, opt=opt, val_objective=val_objective, val_images=val_images, val_teacher=val_teacher, val_wiener=val_wiener, val_sharp=val_sharp, val_input=val_input)


def train(cfg: DistillConfig, out: Path, resume: bool = False, stop_after: int | None = None) -> dict:
    """A run, or its continuation (`resume`); with `stop_after`, only up to
    that step (checkpointed), as a session that ends would: `--resume`
    then goes on exactly as an uninterrupted run (the schedule depends on
    `steps`, so a resumed run must keep it)."""
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    random.seed(cfg.seed)
    r = prepare(cfg)
    device, teacher_root, net, opt, data = r.device, r.teacher_root, r.net, r.opt, r.data
    objective, sharp = r.objective, r.sharp
    out.mkdir(parents=True, exist_ok=True)
    checkpoint = out / "checkpoint.pt"
    step, seconds_before, history = 0, 0.0, []
    state = None
    if resume and checkpoint.exists():
        state = torch.load(checkpoint, map_location="cpu", weights_only=False)
        saved = DistillConfig(**{**dataclasses.asdict(DistillConfig()), **state["config"]})
        if cfg.batch == 0:
            # --batch 0 was resolved when the run started: keep that batch.
            cfg = dataclasses.replace(cfg, batch=saved.batch)
        # Where the data lie and the device may change between machines;
        # what is trained may not.
        movable = {"threads": cfg.threads, "teacher": cfg.teacher, "images": cfg.images, "init": cfg.init,
                   "device": cfg.device}
        if dataclasses.replace(saved, **movable) != cfg:
            raise SystemExit(f"error: {checkpoint} was made with another configuration: {saved}")
        net.load_state_dict(state["net"])
        opt.load_state_dict(state["optimizer"])
        step = state["step"]
        data.rng.bit_generator.state = state["data_rng"]
        torch.set_rng_state(state["torch_rng"])
        random.setstate(state["python_rng"])
        seconds_before = state["seconds"]
        history = state.get("history", [])
    if cfg.batch == 0:
        cfg = dataclasses.replace(cfg, batch=largest_batch(net, objective, cfg, sharp))
        print(f"dcnn: batch {cfg.batch} (the largest of at most {cfg.max_batch} that fits on {device})", flush=True)
    log_path = out / "metrics.csv"
    new_log = step == 0 or not log_path.exists()
    log = open(log_path, "w" if step == 0 else "a")
    if new_log:
        log.write("step,lr,loss,mse_db,distill,range,val_dcnn_db,val_optimal_db,val_wiener_db,"
                  "val_dcnn_mean_db,val_dcnn_worst_db,val_wiener_mean_db,val_wiener_worst_db,"
                  "val_dcnn_sharp_mean_db,val_dcnn_sharp_worst_db,val_wiener_sharp_mean_db,val_wiener_sharp_worst_db,"
                  "seconds\n")
    start = time.time()
    last = cfg.steps if stop_after is None else min(cfg.steps, stop_after)
    done = max(step, last)
    bar = tqdm(range(step, last), initial=step, total=cfg.steps, desc="dcnn")
    for step in bar:
        lr = lr_at(cfg, step, seconds_before + time.time() - start)
        for g in opt.param_groups:
            g["lr"] = lr
        loss, terms = step_once(net, opt, objective, data, cfg, sharp)
        # One read-back a step (a device synchronisation), not four.
        loss_v, mse_v, distill_v, range_v = torch.stack(
            [loss.detach(), terms["mse"].detach(), terms["distill"].detach(), terms["range"].detach()]).tolist()
        elapsed = seconds_before + time.time() - start
        spent = cfg.time_budget > 0 and elapsed >= cfg.time_budget
        if spent:
            # The budget is spent: this step is the run's last.
            last = done = step + 1
        val = {}
        if (step + 1) % cfg.validate_every == 0 or step + 1 == cfg.steps or spent:
            val = validate(net, r.val_objective, r.val_images, r.val_teacher, r.val_wiener, r.val_sharp,
                           r.val_wiener if cfg.base == "wiener" else None, r.val_input, cfg)
            history.append({"step": step + 1, **val})
            bar.write(json.dumps(history[-1]))
            elapsed = seconds_before + time.time() - start
        log.write(f"{step + 1},{lr:.3g},{loss_v:.6g},{db(mse_v):.4f},"
                  f"{distill_v:.4g},{range_v:.3g},{val.get('dcnn_db', '')},"
                  f"{val.get('optimal_db', '')},{val.get('wiener_db', '')},{val.get('dcnn_mean_db', '')},"
                  f"{val.get('dcnn_worst_db', '')},{val.get('wiener_mean_db', '')},{val.get('wiener_worst_db', '')},"
                  f"{val.get('dcnn_sharp_mean_db', '')},{val.get('dcnn_sharp_worst_db', '')},"
                  f"{val.get('wiener_sharp_mean_db', '')},{val.get('wiener_sharp_worst_db', '')},"
                  f"{elapsed:.1f}\n")
        log.flush()
        bar.set_postfix(mse_db=f"{db(mse_v):.2f}", distill=f"{distill_v:.2e}")
        if (step + 1) % cfg.checkpoint_every == 0 or step + 1 in (cfg.steps, last):
            save_checkpoint(checkpoint, net, opt, step + 1, cfg, data.rng, elapsed, history)
        if step + 1 >= last:
            break
    log.close()
    finished = is_finished(cfg, done, seconds_before + time.time() - start)
    result = {"config": dataclasses.asdict(cfg), "steps": done, "finished": finished,
              "seconds": seconds_before + time.time() - start, "validation": history,
              "device": device_name(device),
              "teacher": {"train": json.loads((teacher_root / cfg.teacher_set / "prefilter.json").read_text())}}
    (out / "result.json").write_text(json.dumps(result, indent=1))
    return result


def export(run: Path, out: Path, name: str, doe: Path) -> dict:
    """A run's network as the runtime's model: `out/NAME.onnx`, the frozen
    DOE it was trained for beside it (`out/NAME.doe.safetensors`, what
    nedrt loads with a model), and `out/NAME.card.json`."""
    import platform
    import shutil

    from .export import export_onnx, sha256
    state = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=False)
    cfg = DistillConfig(**state["config"])
    if not doe.is_file():
        raise FileNotFoundError(f"{doe}: DOE file not found")
    wiener_k = None
    if cfg.input == "wiener-raw":
        manifest = Path(cfg.teacher) / "train-wiener-raw" / "prefilter.json"
        k = json.loads(manifest.read_text()).get("wiener_k") if manifest.is_file() else None
        if not (isinstance(k, (int, float)) and k > 0):
            raise ValueError(f"{manifest}: no Wiener K (wiener_k); run nedrt prefilter --prefilter native "
                             "--unclamped again")
        wiener_k = float(k)
    net = UNet(cfg.width, cfg.levels)
    net.load_state_dict(state["net"])
    out.mkdir(parents=True, exist_ok=True)
    onnx_path, doe_path = out / f"{name}.onnx", out / f"{name}.doe.safetensors"
    export_onnx(net, onnx_path)
    shutil.copyfile(doe, doe_path)
    result = json.loads((run / "result.json").read_text()) if (run / "result.json").exists() else {}
    if result.get("steps") != state["step"]:
        # Written by an earlier stop of a run resumed since: the checkpoint is newer.
        result = {}
    card = {
        "name": name, "recipe": "nedrt-train dcnn (docs/training.md, the D-CNN stage)",
        "config": dataclasses.asdict(cfg), "steps": state["step"],
        "wall_time_s": state.get("seconds"),
        "hardware": {"platform": platform.platform(), "processor": platform.processor(),
                     "cpu_count": os.cpu_count(), "torch_threads": cfg.threads or torch.get_num_threads(),
                     "torch": torch.__version__,
                     "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None},
        # The device the run trained on (its result.json), beside the exporting machine.
        "trained_on": result.get("device"),
        "doe": {"source": str(doe), "sha256": sha256(doe)},
        "teacher": result.get("teacher") or teacher_manifest(cfg),
        # A run stopped before its last step has no result.json: its
        # checkpoint's history holds the validations it did make.
        "validation": result.get("validation", state.get("history")),
        "finished": is_finished(cfg, state["step"], state.get("seconds") or 0.0),
        "parameters": sum(p.numel() for p in net.parameters()),
        "macs_per_pixel": net.macs_per_pixel(),
        "files": {p.name: sha256(p) for p in [onnx_path, doe_path]},
    }
    if wiener_k is not None:
        # The runtime runs the same Wiener in front of the network
        # (nedrt-app's preprocess::dcnn_system reads these two fields).
        card["input"], card["wiener_k"] = "wiener-raw", wiener_k
    (out / f"{name}.card.json").write_text(json.dumps(card, indent=1))
    return card


def teacher_manifest(cfg: DistillConfig) -> dict | None:
    """The teacher's prefilter.json, as a run records it in result.json."""
    path = Path(cfg.teacher) / cfg.teacher_set / "prefilter.json"
    return {"train": json.loads(path.read_text())} if path.is_file() else None


def main(argv=None, prog=None):
    if argv is None:
        import sys
        argv = sys.argv[1:]
    if argv and argv[0] == "export":
        ap = argparse.ArgumentParser(prog=f"{prog} export" if prog else None,
                                     description="A run as the runtime's model: ONNX, its DOE beside it, a card.")
        ap.add_argument("--run", type=Path, required=True)
        ap.add_argument("--out", type=Path, default=Path("models"))
        ap.add_argument("--name", required=True)
        ap.add_argument("--doe", type=Path, required=True,
                        help="the DOE file the network was trained for (the design's fabrication file)")
        args = ap.parse_args(argv[1:])
        try:
            card = export(args.run, args.out, args.name, args.doe)
        except (ValueError, FileNotFoundError) as e:
            raise SystemExit(f"error: {e}")
        print(json.dumps(card["files"], indent=1))
        return
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    defaults = DistillConfig()
    for f in dataclasses.fields(DistillConfig):
        if f.name in ("teacher", "images"):
            continue
        if f.name == "init":
            ap.add_argument("--init", metavar="RUN", help="start from this run's (or checkpoint file's) network")
            continue
        ap.add_argument("--" + f.name.replace("_", "-"), type=type(getattr(defaults, f.name)),
                        default=getattr(defaults, f.name))
    ap.add_argument("--teacher", metavar="DIR", required=True, type=Path,
                    help="nedrt prefilter's folders: DIR/train (with the kernels), DIR/val, optionally DIR/val-wiener")
    ap.add_argument("--images", metavar="DIR",
                    help="image root with train/ and val/ (default: data/images under the current directory)")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--stop-after", type=int, metavar="STEP",
                    help="stop at this step (checkpointed), to go on later with --resume")
    args = ap.parse_args(argv)
    try:
        images = resolve_root(args.images)
        if not args.teacher.is_dir():
            raise FileNotFoundError(f"{args.teacher}: teacher folder not found")
    except FileNotFoundError as e:
        raise SystemExit(f"error: {e}")
    values = {f.name: getattr(args, f.name) for f in dataclasses.fields(DistillConfig)
              if f.name not in ("teacher", "images")}
    if values["init"]:
        values["init"] = str(Path(values["init"]).resolve())
    cfg = DistillConfig(**values, teacher=str(args.teacher.resolve()), images=str(images))
    try:
        result = train(cfg, args.out, args.resume, args.stop_after)
    except (ValueError, FileNotFoundError) as e:
        raise SystemExit(f"error: {e}")
    print(json.dumps(result["validation"][-1:], indent=1))


if __name__ == "__main__":
    main()
