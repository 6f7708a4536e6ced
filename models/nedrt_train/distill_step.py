"""The D-CNN stage's step (distill.py runs the loop): the network's raw
display image and the panel's clamp, the loss (the objective, the distance
to the teacher, the range penalty), one Adam step, the learning-rate
schedule, the validation figures, and the largest batch that fits in a
GPU's memory (`--batch 0`)."""
import contextlib
import math

import torch
import torch.nn.functional as F

from .distill_config import DistillConfig
from .distill_data import Patches
from .objective import Objective, db

#: What a step computes, declared: the network (unet.py), the loss and the
#: clamp, the optimiser, the schedule and the batches' draws
#: (distill_data.py). A carried checkpoint (distill_checkpoint.py) records
#: it in its identity and a run of another version refuses it, so bump it
#: when a change makes a continued run train another thing than the run
#: it continues (a new term, another draw order); refactors leave it.
STEP_VERSION = 1


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


def lr_at(cfg: DistillConfig, step: int, elapsed: float = 0.0, warm_start: int = 0) -> float:
    """Linear warm-up over 200 steps from `warm_start` (the step Adam's
    moments started at: 0, or where a carried checkpoint without them was
    continued), then cosine decay to 1 % of the peak over the steps, or
    over the time budget where there is one."""
    warm = min(1.0, (step - warm_start + 1) / 200)
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
