"""The DOE stage of the recipe: optimise a rotationally symmetric height
profile h(ρ) for the display with a linear (Wiener) prefilter, for a chosen
target, by the expected error over natural-image spectra.

    nedrt-train design --target multifocal --out models/runs/design-multifocal
    nedrt-train design --target allsharp --out models/runs/design-allsharp
    python -m nedrt_train.design --target allsharp --out models/runs/design-allsharp --resume

(from the repository root, or with `--calib FILE` and `--images DIR`).

Model (docs/training.md, "The DOE stage"). Per colour channel, the PSFs h_D
of the lens + DOE over the accommodation sweep (radial model, cells
integrated exactly, the rest of the light a uniform veil) give the display-
grid transfer K_D(f) = ¼ Σ_a T(ν_x) T(ν_y) H_D(ν), ν = (f + a)/2,
T(ν) = 2cos²(πν), the frequency form of nedrt's exact relation
down2(up2(x) ∗ h) = x ∗ k. The prefilter is nedrt's: G = K̄/(K̄² + κ) scaled
to unit gain at zero frequency, K̄ the mean of K_D over the sweep. The error
of the perceived image at depth D against its target T_D (the sharp image,
or the h_b-blurred one at the multifocal target's intermediate depths) is,
on the retinal grid where nedrt scores,

    E_D = Σ_ν S(2ν) · 4cos²(πν_x)cos²(πν_y) · |G(2ν) H_D(ν) − T_D(ν)|²,

S the power spectrum of natural images, S ∝ |f|^−α with α fitted to the
training photographs. The objective is the mean over the design depths of
the error in dB plus a soft minimum (the worst depth), both against the
signal's power. κ (the Wiener constant) is optimised with the profile; the
clamp to the panel's [0, 1] is not in this linear model, so the exported
design's K is re-tuned with the clamp by `nedrt tune-wiener`.

Checkpointed (atomic) and resumable; a resume with another calibration,
target or model is refused. Writes metrics.csv, checkpoint.pt, and at the
end the DOE at the design and fabrication pitches (radial profiles, docs/doe-format.md)
and design.json (the recipe, wall time, final figures).

This module runs the stage (`design`), exports its DOE (`export_design`)
and reads the command line; the model and the objective are in
design_model.py, the clamped Wiener on photographs and the K search in
design_eval.py.
"""
import argparse
import csv
import dataclasses
import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from . import calib as calib_mod
from .data import photo_folder, resolve_root
from .design_eval import load_images, training_crops, tune_k
from .design_model import TARGETS, DesignConfig, DesignModel, fit_spectrum_alpha
from .keys import keys_profile
from .radial import RadialPsfModel, radial_nodes

# The model and its evaluation live in the modules above; the names a caller
# used from here before the split stay importable from here
# (tests/test_design.py imports display_kernel, wiener_gain, … from here).
from .design_eval import display_kernel, evaluate, wiener_display, wiener_gain  # noqa: F401


def file_hash(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def _rng_state():
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state()}


def design_calib(cfg: DesignConfig):
    """The calibration of a design: the file, with the config's eye LCA."""
    calib = calib_mod.load(cfg.calib)
    if cfg.eye_lca is not None:
        calib = dataclasses.replace(calib, eye_lca=cfg.eye_lca)
    return calib


def identity(cfg: DesignConfig) -> dict:
    """What a checkpoint must share with the run that resumes it."""
    return {"target": cfg.target, "calib_sha": file_hash(cfg.calib), "window": cfg.window,
            "objective": cfg.objective, "crops": cfg.crops,
            "frequencies": cfg.frequencies, "design_range_d": list(cfg.design_range_d),
            "design_step_d": cfg.design_step_d,
            # Only a pupil range enters, so earlier checkpoints still resume.
            **({"pupils_mm": list(cfg.pupils_mm)} if cfg.pupils_mm else {}),
            **({"eye_lca": cfg.eye_lca} if cfg.eye_lca is not None else {})}


#: Training photographs the clamped K search uses (every n-th, sorted by name):
#: 17 K values × 8 photos × 6 depths is about two minutes on one core.
TUNE_IMAGES = 8


def design(cfg: DesignConfig, out: Path, resume: bool = False, images_dir: Path | None = None,
           tune: bool = True) -> dict:
    """The DOE stage in `out`. `images_dir` is the training photographs'
    folder (data/images/train): the spectrum fit, the crops of the images
    objective and the clamped K search read it; the command line passes
    `--images`'s train/."""
    if cfg.target not in TARGETS:
        raise ValueError(f"target {cfg.target!r}: choose one of {', '.join(TARGETS)}")
    calib = design_calib(cfg)
    out.mkdir(parents=True, exist_ok=True)
    ckpt = out / "checkpoint.pt"
    state = None
    if resume:
        if not ckpt.exists():
            raise ValueError(f"{ckpt}: nothing to resume (no checkpoint)")
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        theirs, mine = state["identity"], identity(cfg)
        diff = [k for k in mine if theirs.get(k) != mine[k]]
        if diff:
            raise ValueError(
                f"{ckpt}: cannot resume: the checkpoint was made with "
                + ", ".join(f"{k} = {theirs.get(k)!r}" for k in diff)
                + "; this run has " + ", ".join(f"{k} = {mine[k]!r}" for k in diff)
                + ". Start a new run in another --out folder.")
        alpha = state["alpha"]
    else:
        if ckpt.exists():
            raise ValueError(f"{ckpt} exists: pass --resume to continue it, or choose another --out")
        alpha = cfg.spectrum_alpha if cfg.spectrum_alpha is not None else fit_spectrum_alpha(photo_folder(images_dir))
    torch.manual_seed(cfg.seed)
    crops = None
    if cfg.objective == "images":
        crops = training_crops(photo_folder(images_dir), cfg.crops,
                               cfg.frequencies // 2, cfg.seed)
    crops_sha = hashlib.sha256(crops.numpy().tobytes()).hexdigest()[:16] if crops is not None else None
    if state and state.get("crops_sha") != crops_sha:
        raise ValueError(f"{ckpt}: cannot resume: the training crops differ from the checkpoint's "
                         "(data/images/train changed); start a new run in another --out folder")
    model = DesignModel(cfg, calib, alpha, crops=crops)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    step, elapsed = 0, 0.0
    if state:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        step, elapsed = state["step"], state["elapsed_s"]
        torch.set_rng_state(state["rng"]["torch"])
    log_path = out / "metrics.csv"
    new_log = not log_path.exists() or step == 0
    log = open(log_path, "w" if new_log else "a", newline="")
    writer = csv.writer(log)
    if new_log:
        writer.writerow(["step", "objective", "mean_db", "worst_db", "k", "seconds"])
    start = time.time() - elapsed

    def save():
        tmp = Path(str(ckpt) + ".tmp")
        torch.save({"model": model.state_dict(), "optimizer": opt.state_dict(), "step": step,
                    "elapsed_s": time.time() - start, "alpha": alpha, "identity": identity(cfg),
                    "crops_sha": crops_sha,
                    "config": dataclasses.asdict(cfg), "rng": _rng_state()}, tmp)
        os.replace(tmp, ckpt)

    bar = tqdm(range(step, cfg.steps), initial=step, total=cfg.steps, desc=f"design {cfg.target}")
    for step in bar:
        loss, db = model.objective()
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        writer.writerow([step, f"{loss.item():.6f}", f"{db.mean().item():.4f}", f"{db.min().item():.4f}",
                         f"{model.log_k.exp().item():.6g}", f"{time.time() - start:.2f}"])
        bar.set_postfix(mean=f"{db.mean().item():.2f}", worst=f"{db.min().item():.2f}", K=f"{model.log_k.exp().item():.3g}")
        if step % cfg.checkpoint_every == 0 or step == cfg.steps:
            log.flush()
            save()
    log.close()
    if step < cfg.steps or not ckpt.exists():
        save()
    with torch.no_grad():
        _, db = model.objective()
    k_clamped, train_rows = None, None
    if tune:
        tune_images = load_images(photo_folder(images_dir), limit=TUNE_IMAGES)
        k_clamped, _, train_rows = tune_k(model, tune_images, cfg.target)
    result = {
        "target": cfg.target, "steps": step, "wall_time_s": round(time.time() - start, 1),
        "threads": torch.get_num_threads(), "spectrum_alpha": alpha,
        "wiener_k_linear": model.log_k.exp().item(),
        "wiener_k": k_clamped,
        "train_psnr_clamped": train_rows,
        "design_depths_d": model.design_d,
        "expected_db": [round(v, 3) for v in db.tolist()],
        # The calibration relative to the working directory when inside it,
        # so that a shipped design.json names no machine's folders.
        "config": {**dataclasses.asdict(cfg), "calib": portable_path(cfg.calib)},
        "calib_sha": file_hash(cfg.calib),
    }
    return result


def portable_path(path) -> str:
    """`path` relative to the working directory if it lies inside it."""
    p = Path(path).resolve()
    try:
        return str(p.relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(p)


def export_design(run: Path, name: str, out: Path) -> dict:
    """The run's DOE as radial files at the design and fabrication pitches."""
    from .export import save_doe, sha256
    state = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=False)
    cfg = DesignConfig(**{**state["config"], "design_range_d": tuple(state["config"]["design_range_d"])})
    calib = design_calib(cfg)
    optics = RadialPsfModel(calib, calib.doe_design_pitch_m, cfg.window)
    optics.doe.load_state_dict({"logit": state["model"]["optics.doe.logit"]})
    height = optics.doe().detach().double().numpy()
    out.mkdir(parents=True, exist_ok=True)
    lam0 = calib.channels[calib.design_channel].wavelength_m
    desc = f"nedrt_train.design {cfg.target}, {state['step']} steps"
    design_path = out / f"doe-{name}-design.safetensors"
    fab_path = out / f"doe-{name}-fabrication.safetensors"
    save_doe(design_path, height, calib.doe_design_pitch_m, calib.doe_max_height_m, calib.material_name, lam0, desc)
    fab_rho, _ = radial_nodes(calib.aperture_radius_m, calib.doe_fabrication_pitch_m)
    fine = keys_profile(height, calib.doe_design_pitch_m, fab_rho, calib.doe_max_height_m)
    save_doe(fab_path, fine, calib.doe_fabrication_pitch_m, calib.doe_max_height_m, calib.material_name, lam0,
             desc + " (Keys cubic to the fabrication pitch)")
    return {"files": {p.name: sha256(p) for p in [design_path, fab_path]}}


def main(argv=None, prog=None):
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", choices=TARGETS, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--steps", type=int)
    ap.add_argument("--lr", type=float)
    ap.add_argument("--window", type=int)
    ap.add_argument("--calib", metavar="FILE",
                    help="calibration TOML (default: calib/default.toml under the current directory)")
    ap.add_argument("--images", metavar="DIR",
                    help="image root whose train/ the design reads (default: data/images under the current directory)")
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--no-tune", dest="tune", action="store_false", help="skip the clamped K search on training photographs")
    ap.add_argument("--name", help="also write the DOE files doe-NAME-{design,fabrication}.safetensors into --out")
    ap.add_argument("--pupils-mm", type=lambda v: tuple(float(x) for x in v.split(",")), metavar="MM,MM,…",
                    help="design for these eye pupils (mm), their objectives averaged "
                         "(default: the calibration's eye; docs/model.md §4a)")
    ap.add_argument("--eye-lca", choices=["on", "off"],
                    help="the eye's chromatic aberration, Thibos 1992 (default: the calibration's eye.lca)")
    args = ap.parse_args(argv)
    overrides = {k: getattr(args, k) for k in ["steps", "lr", "window", "pupils_mm"] if getattr(args, k) is not None}
    if args.eye_lca is not None:
        overrides["eye_lca"] = args.eye_lca == "on"
    if any(not 0 < p <= 12 for p in overrides.get("pupils_mm", ())):
        raise SystemExit(f"error: --pupils-mm {args.pupils_mm}: each pupil must lie in (0, 12] mm")
    try:
        calib = calib_mod.resolve(args.calib)
        images = resolve_root(args.images)
    except FileNotFoundError as e:
        raise SystemExit(f"error: {e}")
    cfg = dataclasses.replace(DesignConfig(target=args.target), calib=str(calib), **overrides)
    try:
        result = design(cfg, args.out, resume=args.resume, images_dir=images / "train", tune=args.tune)
    except (ValueError, FileNotFoundError) as e:
        raise SystemExit(f"error: {e}")
    if args.name:
        result.update(export_design(args.out, args.name, args.out))
    tmp = args.out / "design.json.tmp"
    tmp.write_text(json.dumps(result, indent=1))
    os.replace(tmp, args.out / "design.json")
    print(json.dumps({k: result[k] for k in ["target", "steps", "wall_time_s", "expected_db", "wiener_k_linear"]}, indent=1))


if __name__ == "__main__":
    main()
