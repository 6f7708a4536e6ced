"""Joint training of the DOE and the D-CNN (paper §2, docs/model.md §14–§15).

    nedrt-train train --preset half --steps 2000 --out models/runs/half
    python -m nedrt_train.train --preset half --steps 2000 --out models/runs/half
    torchrun --nproc_per_node=4 -m nedrt_train train --preset full --device cuda ...

Run from the repository root, or name the calibration and the image root
(`--calib FILE`, `--images DIR`): nothing is looked up beside the package.

Each step samples an accommodation from the seven depths, a batch of
patches, runs the residual U-Net, renders the perceived image through the
lens + DOE (differentiable), and steps Adam on both the network and the DOE's
height map. Checkpoints (`--resume`), a CSV metrics log, a progress bar, and
determinism given `--seed` (per rank): each rank draws its own depths and
batches, and a checkpoint keeps every rank's random state, so a resumed run
draws what an uninterrupted one would. Under torchrun the model is wrapped
in DistributedDataParallel (gloo on CPU, NCCL on GPU). `train()` is
`setup` (seeds, system, optimiser, data, resume), `loop` (the steps) and
`finish` (validation), with `save_checkpoint`/`load_checkpoint` between.
"""
import argparse
import csv
import dataclasses
import json
import os
import random
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import torch.nn as nn
from tqdm import tqdm

from . import calib as calib_mod
from .data import TrainingImages, resolve_root, validation_images
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
    # The calibration TOML and the image root (train/, val/): absolute paths
    # the command line resolves (--calib, --images); no default here.
    calib: str | None = None
    images: str | None = None
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
    # For tests, with the small-aperture calibration
    # (--calib tests/data/small-aperture.toml): seconds a step on one core.
    "smoke": Config(width=4, levels=2, patch=32, batch=1, steps=2, window=9,
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


@dataclass
class Run:
    """A training run in progress: what `setup` builds, `loop` advances and
    `save_checkpoint` writes. One per process (rank)."""
    cfg: Config
    out: Path
    device: str
    rank: int
    world_size: int
    system: System
    model: nn.Module  # `system`, or DDP around it
    opt: torch.optim.Optimizer
    data: TrainingImages
    rng: np.random.Generator  # the depth draws
    blur: list
    depths: list
    step: int = 0
    log: object = None
    writer: object = None
    start: float = 0.0
    loss: torch.Tensor = None

    @property
    def checkpoint_path(self) -> Path:
        return self.out / "checkpoint.pt"


def init_distributed(device: str) -> bool:
    """Joins the process group when started by torchrun (WORLD_SIZE > 1):
    gloo on CPU, NCCL on GPU. Returns whether the run is distributed."""
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1:
        return False
    dist.init_process_group("nccl" if device == "cuda" else "gloo")
    if device == "cuda":
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
    return True


def setup(cfg: Config, out: Path, device: str = "cpu", resume: bool = False) -> Run:
    """Seeds this rank, builds the system, optimiser and data, and (with
    `resume`) restores the checkpoint in `out`, this rank's random state
    included; opens the metrics log on rank 0. Distributed when the process
    group is initialised (`init_distributed`)."""
    distributed = dist.is_available() and dist.is_initialized()
    rank = dist.get_rank() if distributed else 0
    world_size = dist.get_world_size() if distributed else 1
    torch.manual_seed(cfg.seed + rank)
    rng = np.random.default_rng(cfg.seed + 7919 * rank)
    calib = calib_mod.load(cfg.calib)
    system = System(cfg, calib).to(device)
    model = nn.parallel.DistributedDataParallel(system) if distributed else system
    opt = torch.optim.Adam([
        {"params": system.net.parameters(), "lr": cfg.lr_net},
        {"params": system.optics.doe.parameters(), "lr": cfg.lr_doe},
    ])
    data = TrainingImages(cfg.patch, cfg.seed + 1000 * (rank + 1), image_folder(cfg, "train"))
    out.mkdir(parents=True, exist_ok=True)
    run = Run(cfg=cfg, out=out, device=device, rank=rank, world_size=world_size, system=system, model=model,
              opt=opt, data=data, rng=rng, blur=[], depths=calib.depths_d)
    if resume and run.checkpoint_path.exists():
        load_checkpoint(run, torch.load(run.checkpoint_path, map_location=device, weights_only=False))
    with torch.no_grad():
        run.blur = [(c.to(device), v.to(device)) for c, v in system.optics.target_blur()]
    if rank == 0:
        run.log = open(out / "metrics.csv", "a", newline="")
        run.writer = csv.writer(run.log)
        if run.step == 0:
            run.writer.writerow(["step", "accommodation_d", "loss", "l1", "ssim_loss", "dark", "range", "seconds"])
    run.start = time.time()
    return run


def image_folder(cfg: Config, part: str) -> Path:
    """The `part` folder (train, val) of the run's image root."""
    if cfg.images is None:
        raise ValueError("no image folder given (Config.images; the command line's --images DIR)")
    return Path(cfg.images) / part


def loop(run: Run, on_step=None):
    """Trains from `run.step` to `cfg.steps`: per step one depth draw and
    one batch from this rank's generators, forward, backward, Adam; the
    metrics row and progress on rank 0, a checkpoint every
    `checkpoint_every` steps and at the last. `on_step(step, depth, batch)`,
    if given, sees each draw (the tests compare ranks' draws with it)."""
    cfg = run.cfg
    bar = tqdm(range(run.step, cfg.steps), initial=run.step, total=cfg.steps, disable=run.rank != 0, desc="train")
    for step in bar:
        d = float(run.depths[run.rng.integers(len(run.depths))])
        image = run.data.batch(cfg.batch).to(run.device)
        if on_step is not None:
            on_step(step, d, image)
        loss, terms = run.model(image, d, run.blur)
        run.opt.zero_grad()
        loss.backward()
        run.opt.step()
        run.loss = loss
        run.step = step + 1
        if run.writer:
            run.writer.writerow([step + 1, d, loss.item()] + [terms[k].item() for k in ["l1", "ssim", "dark", "range"]]
                                + [round(time.time() - run.start, 3)])
            bar.set_postfix(loss=f"{loss.item():.4f}", D=d)
        if (step + 1) % cfg.checkpoint_every == 0 or step + 1 == cfg.steps:
            save_checkpoint(run)


def rng_state(run: Run) -> dict:
    """This rank's random state: its depth and data generators, and the
    global torch (and CUDA), numpy and Python generators."""
    state = {"depth": run.rng.bit_generator.state, "data": run.data.rng.bit_generator.state,
             "torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}
    if run.device == "cuda":
        state["cuda"] = torch.cuda.get_rng_state()
    return state


def set_rng_state(run: Run, state: dict):
    """Restores what `rng_state` returned."""
    run.rng.bit_generator.state = state["depth"]
    run.data.rng.bit_generator.state = state["data"]
    torch.set_rng_state(state["torch"].cpu())
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    if run.device == "cuda" and "cuda" in state:
        torch.cuda.set_rng_state(state["cuda"].cpu())


def save_checkpoint(run: Run):
    """Writes `checkpoint.pt` (atomically) with the system, the optimiser,
    the step, the config and every rank's own random state (`rank_rng`, a
    list indexed by rank). Collective under DDP: every rank calls it, rank 0
    writes."""
    mine = rng_state(run)
    if run.world_size > 1:
        states = [None] * run.world_size
        dist.all_gather_object(states, mine)
    else:
        states = [mine]
    if run.rank != 0:
        return
    tmp = str(run.checkpoint_path) + ".tmp"
    torch.save({"system": run.system.state_dict(), "optimizer": run.opt.state_dict(), "step": run.step,
                "rank_rng": states, "config": dataclasses.asdict(run.cfg)}, tmp)
    os.replace(tmp, run.checkpoint_path)


def load_checkpoint(run: Run, state: dict):
    """Restores a checkpoint into `run`: system, optimiser, step, and this
    rank's own random state. A rank the checkpoint has no state for (a run
    resumed on more processes) keeps its fresh seeded state. Checkpoints
    from before per-rank state (`rng`, `data_rng`, `torch_rng`: rank 0's
    for every rank) still load."""
    run.system.load_state_dict(state["system"])
    run.opt.load_state_dict(state["optimizer"])
    run.step = state["step"]
    if "rank_rng" in state:
        if run.rank < len(state["rank_rng"]):
            set_rng_state(run, state["rank_rng"][run.rank])
        return
    if run.rank < len(state["rng"]):
        run.rng = state["rng"][run.rank]
    if run.rank < len(state["data_rng"]):
        run.data.rng = state["data_rng"][run.rank]
    torch.set_rng_state(state["torch_rng"].cpu())


def finish(run: Run) -> dict:
    """Closes the log; the result (steps, seconds, final loss) and, on rank
    0, the validation table."""
    if run.log:
        run.log.close()
        run.log = run.writer = None
    result = {"steps": run.cfg.steps, "seconds": time.time() - run.start,
              "final_loss": None if run.loss is None else run.loss.item()}
    if run.rank == 0:
        val = validation_images(run.cfg.patch, image_folder(run.cfg, "val")).to(run.device)
        result["validation"] = validate(run.system, val, run.blur)
    return result


def train(cfg: Config, out: Path, device: str = "cpu", resume: bool = False) -> dict:
    """A whole run: `setup`, `loop`, `finish`, in the process group when
    started by torchrun."""
    distributed = init_distributed(device)
    try:
        run = setup(cfg, out, device, resume)
        loop(run)
        result = finish(run)
        if distributed:
            # Rank 0 validates in `finish` while the others are done: a rank
            # that tears gloo down while its peer still holds the pair can
            # abort ("terminate called without an active exception").
            dist.barrier()
        return result
    finally:
        if distributed:
            dist.destroy_process_group()


def main(argv=None, prog=None):
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", choices=sorted(PRESETS), default="half")
    ap.add_argument("--steps", type=int)
    ap.add_argument("--seed", type=int)
    ap.add_argument("--batch", type=int)
    ap.add_argument("--patch", type=int)
    ap.add_argument("--calib", metavar="FILE",
                    help="calibration TOML (default: calib/default.toml under the current directory)")
    ap.add_argument("--images", metavar="DIR",
                    help="image root with train/ and val/ (default: data/images under the current directory)")
    ap.add_argument("--doe-profile", dest="doe_profile", choices=["radial", "map"])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--resume", action="store_true")
    args = ap.parse_args(argv)
    try:
        paths = {"calib": str(calib_mod.resolve(args.calib)), "images": str(resolve_root(args.images))}
    except FileNotFoundError as e:
        raise SystemExit(f"error: {e}")
    cfg = PRESETS[args.preset]
    overrides = {k: getattr(args, k) for k in ["steps", "seed", "batch", "patch", "doe_profile"] if getattr(args, k) is not None}
    cfg = dataclasses.replace(cfg, **overrides, **paths)
    result = train(cfg, args.out, args.device, args.resume)
    if int(os.environ.get("RANK", "0")) == 0:
        (args.out / "result.json").write_text(json.dumps({"config": dataclasses.asdict(cfg), **result}, indent=1))
        print(json.dumps(result["validation"], indent=1))


if __name__ == "__main__":
    main()
