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
continues a run exactly (optimiser, schedule, random state), and refuses
another configuration naming the fields. `--save-checkpoint DIR` also
writes each checkpoint as a carried one, which `--from-checkpoint DIR`
continues on another machine if made under this run's identity
(distill_checkpoint.py; the device check carries models/checkpoints/dcnn-full).

This module prepares a run (`prepare`), runs its loop (`train`) and reads
the command line; the stage's parts are beside it: its configuration
(distill_config.py), nedrt's objective (objective.py), the teacher and the
patches (distill_data.py), the loss and the step (distill_step.py), the
carried checkpoint (distill_checkpoint.py), and `dcnn export`
(distill_export.py).
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

from . import distill_checkpoint as carried
from .data import load_photos, resolve_root
from .distill_checkpoint import Carry, identity
from .distill_config import DistillConfig, is_finished
from .distill_data import Patches, load_teacher, photo_names
from .distill_export import export, teacher_manifest, wiener_k_of
from .distill_step import largest_batch, lr_at, step_once, validate
from .objective import Objective, db
from .unet import UNet

# The stage's parts live in the modules above; the names a caller used
# from here before the split stay importable from here (distill.clamp,
# distill.forward, …; tests/test_distill.py uses them).
from .distill_step import autocast, clamp, forward, losses  # noqa: F401


def device_name(device: torch.device) -> str:
    """What the run ran on, for the card."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    if device.type == "cpu":
        return f"CPU ({torch.get_num_threads()} threads)"
    return str(device)


def save_checkpoint(path: Path, net, opt, step: int, cfg: DistillConfig, rng: np.random.Generator, seconds: float,
                    history: list, sessions: list = (), session: dict | None = None, warm_start: int = 0):
    """The run folder's own checkpoint (`--resume`): everything, Adam's
    moments in full; plain containers and tensors, so that it loads with
    torch.load(weights_only=True)."""
    tmp = Path(str(path) + ".tmp")
    torch.save({"net": net.state_dict(), "optimizer": opt.state_dict(), "step": step,
                "config": dataclasses.asdict(cfg), "data_rng": rng.bit_generator.state,
                "torch_rng": torch.get_rng_state(), "python_rng": random.getstate(),
                "seconds": seconds, "history": history, "sessions": list(sessions), "session": session,
                "warm_start": warm_start}, tmp)
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
        if (init / "card.json").is_file():
            # A carried checkpoint (its hash checked): its network only.
            start = carried.read(init)
            size, weights = start.card["identity"]["network"], carried.network_of(start)
        else:
            init = init / "checkpoint.pt" if init.is_dir() else init
            if not init.is_file():
                raise FileNotFoundError(f"{init}: no checkpoint to start from (--init)")
            saved = torch.load(init, map_location="cpu", weights_only=True)
            size, weights = saved["config"], saved["net"]
        if (size["width"], size["levels"]) != (cfg.width, cfg.levels):
            raise ValueError(f"{init}: a network of width {size['width']} and "
                             f"{size['levels']} levels, this run's is {cfg.width} and {cfg.levels}")
        net.load_state_dict(weights)
    net.to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    return SimpleNamespace(device=device, teacher_root=teacher_root, objective=objective, sharp=sharp, data=data, net=net, opt=opt, val_objective=val_objective, val_images=val_images, val_teacher=val_teacher, val_wiener=val_wiener, val_sharp=val_sharp, val_input=val_input)


def train(cfg: DistillConfig, out: Path, resume: bool = False, stop_after: int | None = None,
          carry: Carry | None = None) -> dict:
    """A run, or its continuation (`resume`: the run folder's own
    checkpoint; `carry.source`: a carried checkpoint, distill_checkpoint.py);
    with `stop_after`, only up to that step (checkpointed), as a session
    that ends would: `--resume` then goes on exactly as an uninterrupted
    run (the schedule depends on `steps`, so a resumed run must keep it).
    With `carry.target`, each checkpoint is also written there, carried."""
    carry = carry or Carry()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    random.seed(cfg.seed)
    out.mkdir(parents=True, exist_ok=True)
    checkpoint = out / "checkpoint.pt"
    resuming = resume and checkpoint.exists()
    ident = identity(cfg, carry.calib) if carry.source or carry.target else None
    calib = carried.calibration_path(cfg, carry.calib) if ident else None
    start, started = None, {"fresh": "no checkpoint given (--from-checkpoint)"}
    if resuming:
        started = {"resumed": str(checkpoint)}
    elif carry.source:
        try:
            start = carried.load(carry.source, ident)
            started = {"checkpoint": str(carry.source), "step": start.step,
                       "sessions": len(start.card.get("sessions", []))}
        except (carried.Refused, FileNotFoundError) as e:
            if not carry.fresh_if_refused:
                raise SystemExit(f"error: {e}")
            started = {"fresh": str(e)}
            print(f"dcnn: {e}; starting fresh (--fresh-if-refused)", flush=True)
    if carry.session_seconds is not None and not resuming:
        cfg = dataclasses.replace(cfg, time_budget=(start.seconds if start else 0.0) + carry.session_seconds)
    r = prepare(cfg)
    device, teacher_root, net, opt, data = r.device, r.teacher_root, r.net, r.opt, r.data
    objective, sharp = r.objective, r.sharp
    step, seconds_before, history, sessions, warm_start, session = 0, 0.0, [], [], 0, None
    moments_in = "fresh"
    if resuming:
        state = torch.load(checkpoint, map_location="cpu", weights_only=True)
        saved = DistillConfig(**{**dataclasses.asdict(DistillConfig()), **state["config"]})
        if cfg.batch == 0:
            # --batch 0 was resolved when the run started: keep that batch.
            cfg = dataclasses.replace(cfg, batch=saved.batch)
        if carry.session_seconds is not None:
            # The session's budget was added to its source's seconds when it began.
            cfg = dataclasses.replace(cfg, time_budget=saved.time_budget)
        # Where the data lie and the device may change between machines;
        # what is trained may not.
        movable = {"threads": cfg.threads, "teacher": cfg.teacher, "images": cfg.images, "init": cfg.init,
                   "device": cfg.device}
        diffs = carried.differences(dataclasses.asdict(dataclasses.replace(saved, **movable)),
                                    dataclasses.asdict(cfg))
        if diffs:
            raise SystemExit(f"error: {checkpoint} was made with another configuration: {carried.explain(diffs)}")
        net.load_state_dict(state["net"])
        opt.load_state_dict(state["optimizer"])
        step = state["step"]
        data.rng.bit_generator.state = state["data_rng"]
        torch.set_rng_state(state["torch_rng"])
        random.setstate(state["python_rng"])
        seconds_before = state["seconds"]
        history = state.get("history", [])
        sessions, session = state.get("sessions", []), state.get("session")
        warm_start = state.get("warm_start", 0)
    elif start is not None:
        moments_in = carried.restore(start, net, opt, data)
        step, seconds_before = start.step, start.seconds
        history, sessions = list(start.card.get("validation", [])), list(start.card.get("sessions", []))
        # Without its moments, Adam starts afresh: the learning rate warms up again.
        warm_start = step if moments_in == "reset" else start.card.get("warm_start", 0)
        print(f"dcnn: from {carry.source} at step {step} ({len(sessions)} sessions, "
              f"{seconds_before:.0f} s; Adam's moments: {moments_in})", flush=True)
        for note in carried.recipe_notes(start.card, cfg):
            print(f"dcnn: this run's {note}", flush=True)
    if cfg.batch == 0:
        cfg = dataclasses.replace(cfg, batch=largest_batch(net, objective, cfg, sharp))
        print(f"dcnn: batch {cfg.batch} (the largest of at most {cfg.max_batch} that fits on {device})", flush=True)
    if session is None:
        session = {"machine": device_name(device), "note": carry.session_note,
                   "started": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "from_step": step,
                   "from_seconds": round(seconds_before, 1), "moments_in": moments_in,
                   "code_sha256": carried.code_sha256()}
        known = [s["code_sha256"] for s in sessions if s.get("code_sha256")]
        if known and known[-1] != session["code_sha256"]:
            print(f"dcnn: the step's code changed since the checkpoint's last session (syntax tree "
                  f"{known[-1][:12]} → {session['code_sha256'][:12]}); its declared version is this one's, "
                  "so the run goes on", flush=True)
    moments = carried.choose_moments(sum(p.numel() for p in net.parameters()), carry.moments, carry.budget_mib)
    log_path = out / "metrics.csv"
    new_log = step == 0 or not log_path.exists()
    log = open(log_path, "w" if new_log else "a")
    if new_log:
        log.write("step,lr,loss,mse_db,distill,range,val_dcnn_db,val_optimal_db,val_wiener_db,"
                  "val_dcnn_mean_db,val_dcnn_worst_db,val_wiener_mean_db,val_wiener_worst_db,"
                  "val_dcnn_sharp_mean_db,val_dcnn_sharp_worst_db,val_wiener_sharp_mean_db,val_wiener_sharp_worst_db,"
                  "seconds\n")
    start_time = time.time()
    last = cfg.steps if stop_after is None else min(cfg.steps, stop_after)
    done = max(step, last)
    written = None
    bar = tqdm(range(step, last), initial=step, total=cfg.steps, desc="dcnn")
    for step in bar:
        lr = lr_at(cfg, step, seconds_before + time.time() - start_time, warm_start)
        for g in opt.param_groups:
            g["lr"] = lr
        loss, terms = step_once(net, opt, objective, data, cfg, sharp)
        # One read-back a step (a device synchronisation), not four.
        loss_v, mse_v, distill_v, range_v = torch.stack(
            [loss.detach(), terms["mse"].detach(), terms["distill"].detach(), terms["range"].detach()]).tolist()
        elapsed = seconds_before + time.time() - start_time
        spent = cfg.time_budget > 0 and elapsed >= cfg.time_budget
        if spent:
            # The budget is spent: this step is the run's last.
            last = done = step + 1
        val = {}
        if (step + 1) % cfg.validate_every == 0 or step + 1 == cfg.steps or spent:
            val = validate(net, r.val_objective, r.val_images, r.val_teacher, r.val_wiener, r.val_sharp,
                           r.val_wiener if cfg.base == "wiener" else None, r.val_input, cfg)
            history.append({"step": step + 1, **val})
            session["validation"] = history[-1]
            bar.write(json.dumps(history[-1]))
            elapsed = seconds_before + time.time() - start_time
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
            session.update(to_step=step + 1, seconds=round(elapsed - session["from_seconds"], 1), batch=cfg.batch)
            save_checkpoint(checkpoint, net, opt, step + 1, cfg, data.rng, elapsed, history,
                            sessions=sessions, session=session, warm_start=warm_start)
            if carry.target:
                written = carried.write(carry.target, net, opt, moments, {
                    "identity": ident, "step": step + 1, "seconds": elapsed, "warm_start": warm_start,
                    "parameters": sum(p.numel() for p in net.parameters()), "config": dataclasses.asdict(cfg),
                    "rng": {"data": data.rng.bit_generator.state, "python": random.getstate()},
                    "validation": history, "sessions": sessions + [session],
                    "teacher": teacher_manifest(cfg), "wiener_k": wiener_k_of(cfg, required=False),
                    "calibration": str(calib)})
        if step + 1 >= last:
            break
    log.close()
    finished = is_finished(cfg, done, seconds_before + time.time() - start_time)
    result = {"config": dataclasses.asdict(cfg), "steps": done, "finished": finished,
              "seconds": seconds_before + time.time() - start_time, "validation": history,
              "device": device_name(device), "started": started, "sessions": sessions + [session],
              "teacher": {"train": json.loads((teacher_root / cfg.teacher_set / "prefilter.json").read_text())}}
    if written is not None:
        result["checkpoint"] = {"folder": str(carry.target), "step": written["step"], "moments": written["moments"],
                                **written["tensors"]}
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
    if argv and argv[0] == "checkpoint":
        ap = argparse.ArgumentParser(prog=f"{prog} checkpoint" if prog else None,
                                     description="A carried checkpoint checked against its card's hash, "
                                                 "and what it holds (step, sessions, identity, last validation).")
        ap.add_argument("folder", type=Path)
        args = ap.parse_args(argv[1:])
        try:
            print(json.dumps(carried.summary(carried.read(args.folder)), indent=1))
        except (ValueError, FileNotFoundError, KeyError) as e:
            raise SystemExit(f"error: {e}")
        return
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    defaults = DistillConfig()
    for f in dataclasses.fields(DistillConfig):
        if f.name in ("teacher", "images"):
            continue
        if f.name == "init":
            ap.add_argument("--init", metavar="RUN",
                            help="start from this run's (checkpoint file's, carried checkpoint's) network")
            continue
        ap.add_argument("--" + f.name.replace("_", "-"), type=type(getattr(defaults, f.name)),
                        default=getattr(defaults, f.name))
    ap.add_argument("--teacher", metavar="DIR", required=True, type=Path,
                    help="nedrt prefilter's folders: DIR/train (with the kernels), DIR/val, optionally DIR/val-wiener")
    ap.add_argument("--images", metavar="DIR",
                    help="image root with train/ and val/ (default: data/images under the current directory)")
    ap.add_argument("--out", required=True, type=Path)
    start = ap.add_mutually_exclusive_group()
    start.add_argument("--resume", action="store_true", help="continue OUT/checkpoint.pt")
    start.add_argument("--from-checkpoint", metavar="DIR", type=Path,
                       help="continue a carried checkpoint (docs/training.md): refused, naming the field, unless "
                            "made under this run's identity (calibration, design, objective, network, step version)")
    ap.add_argument("--fresh-if-refused", action="store_true",
                    help="with --from-checkpoint: a refused or missing checkpoint starts a fresh run (and says why)")
    ap.add_argument("--save-checkpoint", metavar="DIR", type=Path,
                    help="also write each checkpoint here as a carried checkpoint (atomically)")
    ap.add_argument("--session-seconds", type=float, metavar="S",
                    help="this session's time: --time-budget becomes the checkpoint's seconds plus S")
    ap.add_argument("--session-note", default="", metavar="TEXT", help="recorded with this session in the card")
    ap.add_argument("--moments", choices=carried.MOMENTS, default="auto",
                    help="Adam's moments in a carried checkpoint: auto takes the first of f32, bf16, none whose "
                         f"file fits {carried.CARRY_BUDGET_MIB:g} MiB")
    ap.add_argument("--calib", metavar="FILE", type=Path,
                    help="the calibration the teacher's kernels were made with, hashed into a carried checkpoint's "
                         "identity (default: the file their metadata names, under the current directory)")
    ap.add_argument("--stop-after", type=int, metavar="STEP",
                    help="stop at this step (checkpointed), to go on later with --resume")
    args = ap.parse_args(argv)
    if args.fresh_if_refused and not args.from_checkpoint:
        ap.error("--fresh-if-refused goes with --from-checkpoint")
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
        carry = Carry(source=args.from_checkpoint, target=args.save_checkpoint,
                      fresh_if_refused=args.fresh_if_refused, session_seconds=args.session_seconds,
                      session_note=args.session_note, calib=args.calib, moments=args.moments)
        result = train(cfg, args.out, args.resume, args.stop_after, carry)
    except (ValueError, FileNotFoundError) as e:
        raise SystemExit(f"error: {e}")
    print(json.dumps(result["validation"][-1:], indent=1))


if __name__ == "__main__":
    main()
