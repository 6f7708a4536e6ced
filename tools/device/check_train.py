"""The device check's training steps (tools/device/check.py runs them after
the benchmarks): the D-CNN's teacher folders, the full-width network
trained on the GPU, and its export as the runtime's model."""
import json
import os
import shutil
from pathlib import Path

from check_runner import AFTER_TRAIN_S, REPO, TRAIN_BUDGET_S, Failed, Runner, Step, deadline_after


def step_teacher(r: Runner, s: Step, z: dict, device: str):
    """The teacher folders of docs/training.md (the v10 recipe) under the
    work folder; in smoke, of a tiny image set cut from the training photos."""
    images = REPO / "data" / "images"
    if r.smoke:
        images = tiny_images(r.work / "images", z)
    t = r.work / "teacher"
    # The kernels at the patch size (the loss), the training photographs'
    # size (their ceiling) and the validation photographs' (validation).
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
    r.parallel([
        [*design, "--images", images / "train", "--out-dir", t / "train", "--operator", ops],
        [*design, "--images", images / "val", "--out-dir", t / "val"],
        [*design, "--images", images / "train", "--out-dir", t / "train-wiener", "--prefilter", "native"],
        [*design, "--images", images / "train", "--out-dir", t / "train-sharp", "--prefilter", "optimal@sharp",
         "--operator", ops],
        *[[*design, "--images", images / split, "--out-dir", t / f"{split}-wiener-raw", "--prefilter", "native",
           "--unclamped"] for split in ("train", "val")],
    ], deadline, mem_gib=4.5)
    # The ceiling of the training photographs, in shares side by side (the
    # solver is scipy's, on the CPU; its objective on the device).
    n = z["ceiling_shards"]
    cmd = [r.python, "-m", "nedrt_train", "ceiling", "--teacher", t, "--images", images, "--split", "train",
           "--sharp-weight", "1", "--iterations", z["ceiling_iterations"], "--write", t / "train-ceiling",
           "--device", device]
    r.teacher, r.images = t, images
    try:
        r.parallel([cmd + ["--shard", f"{k}/{n}"] for k in range(1, n + 1)], deadline)
    except Failed as e:
        # Better a network distilled from the summed optimum than none.
        r.teacher_set = "train"
        s.note = f"the training ceiling failed ({e}); the training distils optimal@target (teacher set train)"
        r.say(f"   {s.note}")


def step_train(r: Runner, s: Step, z: dict, device: str):
    budget = z["budget_s"] if r.smoke else max(min(TRAIN_BUDGET_S, r.left() - AFTER_TRAIN_S - 30), 10)
    s.cap_s = round(budget)
    run = r.work / "run"
    r.sh([r.python, "-m", "nedrt_train", "dcnn", "--teacher", r.teacher, "--images", r.images, "--out", run,
          "--width", z["width"], "--levels", z["levels"], "--patch", z["patch"], "--input", "wiener-raw",
          "--clamp-grad", "straight", "--teacher-set", r.teacher_set, "--distill", "1000",
          "--distill-metric", "perceived", "--loss", "psnr", "--sharp-weight", "1", "--lr", "1e-3",
          "--steps", z["steps"], "--time-budget", f"{budget:.0f}", "--validate-every", z["validate_every"],
          "--checkpoint-every", 1000, "--device", device, "--amp", "bf16" if device == "cuda" else "off",
          "--batch", 0, "--max-batch", z["max_batch"]], budget + 120, parse_json=False)
    result = json.loads((run / "result.json").read_text())
    s.records.append({"kind": "train", "steps": result["steps"], "seconds": result["seconds"],
                      "batch": result["config"]["batch"], "device": result.get("device"),
                      "validation": result["validation"][-1:] if result["validation"] else []})
    shutil.copyfile(run / "metrics.csv", r.out / "metrics.csv")
    r.run_dir = run


def step_export(r: Runner, s: Step, z: dict):
    r.sh([r.python, "-m", "nedrt_train", "dcnn", "export", "--run", r.run_dir, "--out", r.out, "--name",
          "dcnn-full", "--doe", REPO / "designs" / "multifocal" / "doe-fabrication.safetensors"], s.cap_s,
         parse_json=False)
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

