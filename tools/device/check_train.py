"""The device check's training steps (tools/device/check.py runs them after
the benchmarks): the D-CNN's teacher folders, the full-width network
trained on the GPU (continuing the committed checkpoint, which comes back
continued: docs/training.md, "Carrying the training across lent GPUs"),
and its export as the runtime's model."""
import hashlib
import json
import os
import shutil
import time
from pathlib import Path

from check_runner import AFTER_TRAIN_S, MIB, REPO, TRAIN_BUDGET_S, Failed, Runner, Step, deadline_after

#: The carried checkpoint the training continues, committed in the repository.
CHECKPOINT = REPO / "models" / "checkpoints" / "dcnn-full"
#: Where under $OUT the continued checkpoint comes back (card.json and its tensors file).
RETURNED = "checkpoint"


def step_teacher(r: Runner, s: Step, z: dict):
    """The teacher folders of docs/training.md (the v10 recipe) under the
    work folder; in smoke, of a tiny image set cut from the training photos.
    The training photographs' optimum, the set the training distils, is
    nedrt's own solver on the device (refine:K@target with the wgpu
    backend: its objective equals the CPU optimum's within 1e-4, a test
    holds it); the CPU computes it only if the device cannot."""
    images = REPO / "data" / "images"
    if r.smoke:
        images = tiny_images(r.work / "images", z)
    t = r.work / "teacher"
    # The kernels at the patch size (the loss), the training photographs'
    # size and the validation photographs' (validation).
    ops = ",".join(f"{n}x{n}" for n in sorted({z["patch"], square(images / "train"), square(images / "val")}))
    cores = os.cpu_count() or 2
    # Seven independent commands side by side, the cores shared among them:
    # each spends seconds on its PSFs before its parallel solves.
    design = [r.nedrt, "--threads", max(cores // 7, 1), "--design", "multifocal", "prefilter"]
    deadline = deadline_after(r, s)
    # The first command alone computes the design's PSFs and caches them
    # for the others. Each command peaks at 3.8 GB (the design's PSFs and
    # its plans, whatever the image size): seven at once overran a 24 GiB CI
    # machine and were killed, so they run as many at once as memory holds.
    r.parallel([[*design, "--images", images / "val", "--out-dir", t / "val-wiener", "--prefilter", "native"]],
               deadline)
    # The teacher on the device, while the CPU is free, with the training
    # kernels; into `train`, the folder the CPU writes when it must (the
    # same teacher set either way, so a carried checkpoint continues).
    train = ["--images", images / "train", "--out-dir", t / "train", "--operator", ops]
    teacher = [r.nedrt, "--threads", cores, "--backend", "wgpu", "--design", "multifocal", "prefilter", *train,
               "--prefilter", f"refine:{z['teacher_steps']}@target"]
    cpu = []
    try:
        r.sh(teacher, max(deadline - time.monotonic(), 1), parse_json=False)
        manifest = json.loads((t / "train" / "prefilter.json").read_text())
        s.records.append({"kind": "teacher", "engine": manifest["engine"], "seconds": manifest["seconds"],
                          "images": len(manifest["images"]), "prefilter": manifest["prefilter"]})
        s.note = f"the teacher on the device: {manifest['prefilter']}, {len(manifest['images'])} photographs " \
                 f"in {manifest['seconds']:.1f} s ({manifest['engine']})"
    except (Failed, OSError, ValueError, KeyError) as e:
        cpu = [[*design, *train]]
        s.note = f"the device teacher failed ({e}); the CPU computes optimal@target"
    r.say(f"   {s.note}")
    r.teacher, r.images, r.teacher_set = t, images, "train"
    r.parallel([
        *cpu,
        [*design, "--images", images / "val", "--out-dir", t / "val"],
        [*design, "--images", images / "train", "--out-dir", t / "train-wiener", "--prefilter", "native"],
        [*design, "--images", images / "train", "--out-dir", t / "train-sharp", "--prefilter", "optimal@sharp",
         "--operator", ops],
        *[[*design, "--images", images / split, "--out-dir", t / f"{split}-wiener-raw", "--prefilter", "native",
           "--unclamped"] for split in ("train", "val")],
    ], deadline, mem_gib=4.5)


def step_train(r: Runner, s: Step, z: dict, device: str):
    """The full-width D-CNN, continuing the committed checkpoint where it
    matches this run (otherwise fresh, and the note says why); the
    continued checkpoint is written under $OUT/checkpoint/ to come back.
    The smoke makes a tiny checkpoint first and continues that."""
    budget = z["budget_s"] if r.smoke else max(min(TRAIN_BUDGET_S, r.left() - AFTER_TRAIN_S - 30), 10)
    s.cap_s = round(budget)
    source = CHECKPOINT
    if r.smoke:
        source = r.work / "seed-checkpoint"
        r.sh([*train_command(r, z, device, r.work / "seed", budget), "--stop-after", z["seed_steps"],
              "--save-checkpoint", source], budget + 120, parse_json=False)
    run, back = r.work / "run", r.out / RETURNED
    cmd = [*train_command(r, z, device, run, budget), "--save-checkpoint", back, "--session-note",
           f"device check, commit {r.commit}"]
    if (source / "card.json").is_file():
        # Relative to the repository (the command's folder), as the card and report show it.
        cmd += ["--from-checkpoint", shown_path(source), "--fresh-if-refused"]
    r.sh(cmd, budget + 120, parse_json=False)
    result = json.loads((run / "result.json").read_text())
    started = result.get("started", {})
    if "checkpoint" in started:
        n = started["sessions"]
        s.note = f"continued {shown_path(source)} from step {started['step']} ({n} session{'s' if n != 1 else ''})"
    elif (source / "card.json").is_file():
        s.note = f"started fresh: {started.get('fresh')}"
    else:
        s.note = f"started fresh: no checkpoint at {shown_path(source)}"
    r.say(f"   {s.note}")
    if r.smoke and "checkpoint" not in started:
        raise Failed(f"the smoke's run did not continue its tiny checkpoint: {started}")
    returned = returned_checkpoint(back)
    s.records.append({"kind": "train", "steps": result["steps"], "seconds": result["seconds"],
                      "batch": result["config"]["batch"], "device": result.get("device"),
                      "validation": result["validation"][-1:] if result["validation"] else [],
                      "started": started, "checkpoint": returned})
    shutil.copyfile(run / "metrics.csv", r.out / "metrics.csv")
    r.run_dir = run


#: The loss's weight on the sharp image. 1 (v10's) for the carried
#: network's sessions 1 and 2, whose mean vs target plateaued 0.40 dB under
#: its Wiener while the other three numbers passed (docs/training.md, "What
#: session 2 taught"); 0.5 from 2026-11-27 on: a new identity, so the next
#: lent GPU starts a second carried network (the first is refused by name).
SHARP_WEIGHT = "0.5"


def train_command(r: Runner, z: dict, device: str, run: Path, budget: float) -> list:
    """v10's recipe at the full width (docs/training.md) with the sharp
    weight above, this session's seconds added to the time budget of the
    checkpoint it continues."""
    return [r.python, "-m", "nedrt_train", "dcnn", "--teacher", r.teacher, "--images", r.images, "--out", run,
            "--width", z["width"], "--levels", z["levels"], "--patch", z["patch"], "--input", "wiener-raw",
            "--clamp-grad", "straight", "--teacher-set", r.teacher_set, "--distill", "1000",
            "--distill-metric", "perceived", "--loss", "psnr", "--sharp-weight", SHARP_WEIGHT, "--lr", "1e-3",
            "--steps", z["steps"], "--session-seconds", f"{budget:.0f}", "--validate-every", z["validate_every"],
            "--checkpoint-every", 1000, "--device", device, "--amp", "bf16" if device == "cuda" else "off",
            "--batch", 0, "--max-batch", z["max_batch"]]


def returned_checkpoint(folder: Path) -> dict:
    """The continued checkpoint under $OUT, checked: its card names one
    tensors file, whose SHA-256 is the card's."""
    card_path = folder / "card.json"
    if not card_path.is_file():
        raise Failed(f"{card_path}: the continued checkpoint was not written")
    card = json.loads(card_path.read_text())
    tensors = folder / card["tensors"]["file"]
    digest = hashlib.sha256(tensors.read_bytes()).hexdigest() if tensors.is_file() else None
    if digest != card["tensors"]["sha256"]:
        raise Failed(f"{tensors}: SHA-256 {digest}, its card says {card['tensors']['sha256']}")
    extra = sorted(p.name for p in folder.iterdir() if p.name not in ("card.json", tensors.name))
    if extra:
        raise Failed(f"{folder}: files its card does not name: {', '.join(extra)}")
    return {"step": card["step"], "seconds": card["seconds"], "moments": card["moments"],
            "mib": round(card["tensors"]["bytes"] / MIB, 2), "file": f"{RETURNED}/{tensors.name}",
            "sessions": len(card.get("sessions", []))}


def shown_path(path: Path) -> str:
    return str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path)


def step_export(r: Runner, s: Step, z: dict):
    """The trained network as the runtime's model; the ONNX and its card
    come back (the DOE beside it is the repository's
    designs/multifocal/doe-fabrication.safetensors, its hash in the card)."""
    scratch = r.work / "export"
    r.sh([r.python, "-m", "nedrt_train", "dcnn", "export", "--run", r.run_dir, "--out", scratch, "--name",
          "dcnn-full", "--doe", REPO / "designs" / "multifocal" / "doe-fabrication.safetensors"], s.cap_s,
         parse_json=False)
    for name in ("dcnn-full.onnx", "dcnn-full.card.json"):
        shutil.copyfile(scratch / name, r.out / name)
    card = json.loads((r.out / "dcnn-full.card.json").read_text())
    s.records.append({"kind": "export", "files": card["files"], "steps": card["steps"],
                      "finished": card["finished"], "trained_on": card.get("trained_on")})


def square(folder: Path) -> int:
    """The side of the folder's (square, equal) photographs."""
    from PIL import Image
    found = {Image.open(p).size for p in sorted(folder.glob("*.png"))}
    if len(found) != 1 or len({*next(iter(found))}) != 1:
        raise Failed(f"{folder}: photographs of one square size expected, found {sorted(found)}")
    return next(iter(found))[0]


def tiny_images(root: Path, z: dict) -> Path:
    """Smoke: the first training and validation photographs, centre crops."""
    from PIL import Image
    for split, count, size in (("train", z["train_images"], z["crop"]), ("val", z["val_images"], z["val_crop"])):
        (root / split).mkdir(parents=True, exist_ok=True)
        for path in sorted((REPO / "data" / "images" / split).glob("*.png"))[:count]:
            im = Image.open(path).convert("RGB")
            x, y = (im.width - size) // 2, (im.height - size) // 2
            im.crop((x, y, x + size, y + size)).save(root / split / path.name)
    return root

