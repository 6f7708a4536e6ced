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

This module prepares a run (`prepare`), runs its loop (`train`) and reads
the command line; the stage's parts are beside it: its configuration
(distill_config.py), nedrt's objective (objective.py), the teacher and the
patches (distill_data.py), the loss and the step (distill_step.py), and
`dcnn export` (distill_export.py).
"""
import argparse
import dataclasses
import json
import os
import random
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
from tqdm import tqdm

from .data import load_photos, resolve_root
from .distill_config import DistillConfig, is_finished
from .distill_data import Patches, load_teacher, photo_names
from .distill_export import export
from .distill_step import largest_batch, lr_at, step_once, validate
from .objective import Objective, db
from .unet import UNet

# The stage's parts live in the modules above; the names a caller used
# from here before the split stay importable from here (distill.clamp,
# distill.forward, …; tests/test_distill.py uses them).
from .distill_step import autocast, clamp, forward, losses  # noqa: F401
from .distill_export import teacher_manifest  # noqa: F401


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
