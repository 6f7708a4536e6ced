"""Joint training of the DOE and the D-CNN (paper §2, docs/model.md §14–§15).

    python -m nedrt_train.train --preset half --steps 2000 --out models/runs/half
    torchrun --nproc_per_node=4 -m nedrt_train.train --preset full --device cuda ...

Each step samples an accommodation from the seven depths, a batch of
patches, runs the residual U-Net, renders the perceived image through the
lens + DOE (differentiable), and steps Adam on both the network and the DOE's
height map. Checkpoints (`--resume`), a CSV metrics log, a progress bar, and
determinism given `--seed` (per rank). Under torchrun the model is wrapped in
DistributedDataParallel (gloo on CPU, NCCL on GPU).
"""
import argparse
import csv
import dataclasses
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import torch.nn as nn
from tqdm import tqdm

from . import calib as calib_mod
from .data import TrainingImages, validation_images
from .loss import loss_terms, total
from .optics import PsfModel, perceive, target, up2
from .radial import RadialPsfModel
from .unet import UNet


@dataclass
class Config:
    width: int = 32
    levels: int = 4
    patch: int = 256
    batch: int = 2
    steps: int = 20000
    lr_net: float = 1e-4
    lr_doe: float = 1e-2
    # Training-time PSF model: a window of retinal cells (light outside it is
    # the uniform veil), every cell integrated over its square. The DOE is a
    # radial profile h(ρ) (Hankel transform, radial.py) or, for GPU runs, a
    # free-form 2-D map ("map", optics.PsfModel). The final figures come from
    # the Rust simulator (3 µm fabrication file, window up to the period).
    window: int = 121
    doe_profile: str = "radial"
    seed: int = 0
    calib: str = str(calib_mod.DEFAULT)
    validate_every: int = 500
    checkpoint_every: int = 500
    extra: dict = field(default_factory=dict)


def config_from_saved(saved: dict) -> Config:
    """A checkpoint's Config; runs from before the radial model (with a
    midpoint `sub`) were 2-D maps."""
    saved = dict(saved)
    if "sub" in saved:
        saved.pop("sub")
        saved.setdefault("doe_profile", "map")
    return Config(**saved)


PRESETS = {
    "full": Config(),
    "half": Config(width=16),
    # What two CPU cores can train in about an hour: the half-width network
    # on 128² patches, a 61-cell PSF window (the rest is veil), 2×2 cells.
    "cpu": Config(width=16, patch=128, batch=4, window=61, steps=3000, lr_net=3e-4,
                  validate_every=500, checkpoint_every=250),
    "smoke": Config(width=4, levels=2, patch=32, batch=1, steps=2, window=9,
                    calib=str(calib_mod.REPO / "tests" / "data" / "small-aperture.toml"),
                    validate_every=1000, checkpoint_every=1),
}


class System(nn.Module):
    """Network and optics together, so DDP averages the gradients of both."""

    def __init__(self, cfg: Config, calib):
        super().__init__()
        self.calib = calib
        self.net = UNet(cfg.width, cfg.levels)
        if cfg.doe_profile == "radial":
            self.optics = RadialPsfModel(calib, calib.doe_design_pitch_m, cfg.window, dtype=torch.float32)
        elif cfg.doe_profile == "map":
            self.optics = PsfModel(calib, calib.doe_design_pitch_m, cfg.window, dtype=torch.float32)
        else:
            raise ValueError(f"doe_profile = {cfg.doe_profile!r}: choose radial or map")

    def forward(self, image: torch.Tensor, accommodation_d: float, blur):
        display = self.net(image)
        perceived = perceive(display, self.optics.system(accommodation_d))
        goal = target(image, self.calib, accommodation_d, blur)
        terms = loss_terms(goal, perceived, display)
        return total(terms), terms


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(10 * torch.log10(1 / ((a - b) ** 2).mean()))


@torch.no_grad()
def validate(system: System, images: torch.Tensor, blur) -> list:
    """Per depth: PSNR vs sharp and vs target with the display clamped to [0, 1]."""
    rows = []
    for d in system.calib.depths_d:
        display = system.net.forward_padded(images).clamp(0, 1)
        perceived = perceive(display, system.optics.system(d))
        rows.append({"accommodation_d": d,
                     "psnr_vs_sharp": psnr(perceived, up2(images)),
                     "psnr_vs_target": psnr(perceived, target(images, system.calib, d, blur))})
    return rows


def train(cfg: Config, out: Path, device: str = "cpu", resume: bool = False) -> dict:
    distributed = int(os.environ.get("WORLD_SIZE", "1")) > 1
    rank = 0
    if distributed:
        dist.init_process_group("nccl" if device == "cuda" else "gloo")
        rank = dist.get_rank()
        if device == "cuda":
            torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
    torch.manual_seed(cfg.seed + rank)
    rng = np.random.default_rng(cfg.seed + 7919 * rank)
    calib = calib_mod.load(cfg.calib)
    system = System(cfg, calib).to(device)
    model = nn.parallel.DistributedDataParallel(system) if distributed else system
    opt = torch.optim.Adam([
        {"params": system.net.parameters(), "lr": cfg.lr_net},
        {"params": system.optics.doe.parameters(), "lr": cfg.lr_doe},
    ])
    data = TrainingImages(cfg.patch, cfg.seed + 1000 * (rank + 1))
    out.mkdir(parents=True, exist_ok=True)
    ckpt = out / "checkpoint.pt"
    step = 0
    if resume and ckpt.exists():
        state = torch.load(ckpt, map_location=device, weights_only=False)
        system.load_state_dict(state["system"])
        opt.load_state_dict(state["optimizer"])
        step = state["step"]
        rng = state["rng"][rank] if rank < len(state["rng"]) else rng
        data.rng = state["data_rng"][rank] if rank < len(state["data_rng"]) else data.rng
        torch.set_rng_state(state["torch_rng"])
    with torch.no_grad():
        blur = [(c.to(device), v.to(device)) for c, v in system.optics.target_blur()]
    depths = calib.depths_d
    log_path = out / "metrics.csv"
    log = open(log_path, "a", newline="") if rank == 0 else None
    writer = csv.writer(log) if log else None
    if writer and step == 0:
        writer.writerow(["step", "accommodation_d", "loss", "l1", "ssim_loss", "dark", "range", "seconds"])
    start = time.time()
    loss = None
    bar = tqdm(range(step, cfg.steps), initial=step, total=cfg.steps, disable=rank != 0, desc="train")
    for step in bar:
        d = float(depths[rng.integers(len(depths))])
        image = data.batch(cfg.batch).to(device)
        loss, terms = model(image, d, blur)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if writer:
            writer.writerow([step + 1, d, loss.item()] + [terms[k].item() for k in ["l1", "ssim", "dark", "range"]]
                            + [round(time.time() - start, 3)])
            bar.set_postfix(loss=f"{loss.item():.4f}", D=d)
        if rank == 0 and ((step + 1) % cfg.checkpoint_every == 0 or step + 1 == cfg.steps):
            ranks = dist.get_world_size() if distributed else 1
            torch.save({"system": system.state_dict(), "optimizer": opt.state_dict(), "step": step + 1,
                        "rng": [rng] * ranks, "data_rng": [data.rng] * ranks,
                        "torch_rng": torch.get_rng_state(), "config": dataclasses.asdict(cfg)},
                       str(ckpt) + ".tmp")
            os.replace(str(ckpt) + ".tmp", ckpt)
    if log:
        log.close()
    result = {"steps": cfg.steps, "seconds": time.time() - start, "final_loss": None if loss is None else loss.item()}
    if rank == 0:
        result["validation"] = validate(system, validation_images(cfg.patch).to(device), blur)
    if distributed:
        dist.destroy_process_group()
    return result


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", choices=sorted(PRESETS), default="half")
    ap.add_argument("--steps", type=int)
    ap.add_argument("--seed", type=int)
    ap.add_argument("--batch", type=int)
    ap.add_argument("--patch", type=int)
    ap.add_argument("--calib")
    ap.add_argument("--doe-profile", dest="doe_profile", choices=["radial", "map"])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--resume", action="store_true")
    args = ap.parse_args(argv)
    cfg = PRESETS[args.preset]
    overrides = {k: getattr(args, k) for k in ["steps", "seed", "batch", "patch", "calib", "doe_profile"] if getattr(args, k) is not None}
    cfg = dataclasses.replace(cfg, **overrides)
    result = train(cfg, args.out, args.device, args.resume)
    if int(os.environ.get("RANK", "0")) == 0:
        (args.out / "result.json").write_text(json.dumps({"config": dataclasses.asdict(cfg), **result}, indent=1))
        print(json.dumps(result["validation"], indent=1))


if __name__ == "__main__":
    main()
