"""The ceiling of the evaluation's own headline (issue 16, docs/training.md):
per validation photograph, the display image in [0, 1] that maximises the
mean over the headline depths of the PSNR vs target, plus `w` times the
mean PSNR vs sharp, solved with scipy's L-BFGS-B from nedrt's optimum.

    nedrt-train ceiling --teacher out/teacher --sharp-weight 0,0.5,1 --out ceiling.json
    nedrt-train ceiling --teacher out/teacher --split train --sharp-weight 1 \
        --write out/teacher/train-ceiling     # a teacher for nedrt-train dcnn --teacher-set
    # the same on two cores: two processes, each a share of the photographs
    nedrt-train ceiling ... --shard 1/2 & nedrt-train ceiling ... --shard 2/2

`nedrt`'s `optimal` prefilter minimises the summed squared error over the
depths, a convex problem; the headline averages PSNRs, i.e. logarithms of
the per-depth errors, which weighs the well-focused blurred depths far
more. No preprocessor of any kind (a D-CNN included) can beat this per-frame
optimum on the quantity it maximises, so its numbers bound what the
acceptance of issue 16 can ask of a network.

The per-depth errors are quadratic forms of the display image with nedrt's
kernels (`nedrt prefilter --operator`), evaluated by Parseval on one FFT of
the mirrored frame: one forward and one inverse FFT per evaluation however
many depths and objectives.
"""
import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

from .data import load_photos, resolve_root
from .distill_data import load_teacher, photo_names
from .objective import Objective


class DepthErrors:
    """Per-depth mean squared errors of one photograph's perceived images
    against one objective's targets, as functions of the display image."""

    def __init__(self, objective: Objective, image: torch.Tensor, device="cpu"):
        if objective.depth_spectra is None:
            raise ValueError("these kernels have no per-depth terms (an older nedrt prefilter --operator)")
        c, h, w = image.shape
        self.frame = (c, h, w)
        self.device = torch.device(device)
        image = image.to(self.device)
        spectra = {k: v.to(self.device, torch.complex128) for k, v in objective.depth_spectra.items()}
        i_hat = torch.fft.rfft2(Objective.mirror(image.double()))
        # rfft keeps half the last axis: every bin but the first (and the
        # Nyquist one) stands for itself and its conjugate.
        # The mirrored frame is 2w wide: bins 0 and w (Nyquist) are their own.
        weight = torch.full((w + 1,), 2.0, dtype=torch.float64, device=self.device)
        weight[0] = weight[-1] = 1.0
        self.n = 4 * h * w
        self.weight = weight / self.n
        self.normal = spectra["normal"].real * self.weight  # D × C × 2h × (w+1)
        self.cross = (spectra["adjoint_target"] * i_hat).conj() * self.weight
        self.constant = 0.5 * ((spectra["target_gram"] * i_hat.abs() ** 2).real * self.weight).sum(dim=(1, 2, 3))
        self.scale = 0.5 / (c * self.n)

    def __call__(self, display_hat: torch.Tensor) -> torch.Tensor:
        """D: the errors, from the rfft of the mirrored display image."""
        power = display_hat.real ** 2 + display_hat.imag ** 2
        quadratic = 0.5 * (self.normal * power).sum(dim=(1, 2, 3))
        linear = (self.cross * display_hat).real.sum(dim=(1, 2, 3))
        return self.scale * (quadratic - linear + self.constant)


def psnr(errors: torch.Tensor) -> torch.Tensor:
    return -10 * torch.log10(errors.clamp_min(1e-30))


def solve(start: torch.Tensor, target: DepthErrors, sharp: DepthErrors, sharp_weight: float,
          iterations: int) -> tuple:
    """The display image maximising mean PSNR vs target + w · mean PSNR vs
    sharp over [0, 1], and (iterations used, final objective)."""
    from scipy.optimize import minimize
    shape = start.shape
    device = target.device

    def value_and_gradient(x):
        # The solver's iterate stays on the CPU (scipy); the objective and
        # its gradient are computed on the errors' device (float64).
        d = torch.from_numpy(x).view(shape).to(device).requires_grad_(True)
        d_hat = torch.fft.rfft2(Objective.mirror(d))
        loss = -psnr(target(d_hat)).mean()
        if sharp_weight:
            loss = loss - sharp_weight * psnr(sharp(d_hat)).mean()
        loss.backward()
        return float(loss.detach()), d.grad.cpu().numpy().ravel().copy()

    x0 = start.double().clamp(0, 1).numpy().ravel().copy()
    result = minimize(value_and_gradient, x0, jac=True, method="L-BFGS-B", bounds=[(0.0, 1.0)] * x0.size,
                      options={"maxiter": iterations, "maxcor": 10, "ftol": 1e-12, "gtol": 1e-10})
    return torch.from_numpy(result.x).view(shape).float(), result.nit, float(result.fun)


def summary(per_image: list) -> dict:
    """Per-depth PSNR averaged over the photographs, then mean and worst
    over the depths, as `nedrt eval` reports them."""
    by_depth = torch.stack(per_image).mean(dim=0)
    return {"per_depth_db": [round(float(v), 3) for v in by_depth],
            "mean_db": round(float(by_depth.mean()), 3), "worst_db": round(float(by_depth.min()), 3)}


def ceiling(teacher_root: Path, images_root: Path, sharp_weights: list, iterations: int,
            limit: int | None = None, split: str = "val", write: Path | None = None,
            shard: tuple = (1, 1), device="cpu") -> dict:
    """The table on `split`'s photographs; with `write`, also the display
    images of the (one) sharp weight, as a teacher folder for
    `nedrt-train dcnn --teacher-set` (`displays.safetensors`, `prefilter.json`).
    `shard` (k, n) takes every n-th photograph from the k-th; its display
    images go to `displays-k-of-n.safetensors`, which `load_teacher` joins."""
    if write is not None and len(sharp_weights) != 1:
        raise ValueError("--write keeps the display images of one --sharp-weight; give exactly one")
    names = photo_names(images_root / split)
    photos = load_photos(images_root / split)
    if limit:
        names, photos = names[:limit], photos[:limit]
    k, n = shard
    names, photos = names[k - 1::n], photos[k - 1::n]
    if not names:
        raise ValueError(f"--shard {k}/{n}: no photographs in this share")
    images = [torch.from_numpy(p).permute(2, 0, 1).contiguous() for p in photos]
    h, w = images[0].shape[-2:]
    kernels = teacher_root / "train" / f"operator-{w}x{h}.safetensors"
    sharp_kernels = teacher_root / "train-sharp" / f"operator-{w}x{h}.safetensors"
    target_obj, sharp_obj = Objective.load(kernels), Objective.load(sharp_kernels)
    starts = load_teacher(teacher_root / split, names)
    wiener = load_teacher(teacher_root / f"{split}-wiener", names)
    written = {}
    rows = {"wiener": ([], []), "optimal@target": ([], [])}
    rows.update({f"ceiling w={s:g}": ([], []) for s in sharp_weights})
    seconds = {k: 0.0 for k in rows}
    iters = {k: [] for k in rows}
    for name, image in zip(names, images):
        if tuple(image.shape[-2:]) != (h, w):
            raise ValueError(f"{name}: the {split} photographs are of different sizes")
        target, sharp = DepthErrors(target_obj, image, device), DepthErrors(sharp_obj, image, device)

        def score(key, display):
            d_hat = torch.fft.rfft2(Objective.mirror(display.double().to(device)))
            rows[key][0].append(psnr(target(d_hat)).cpu())
            rows[key][1].append(psnr(sharp(d_hat)).cpu())

        score("wiener", wiener[name])
        score("optimal@target", starts[name])
        for s in sharp_weights:
            key = f"ceiling w={s:g}"
            t0 = time.perf_counter()
            display, nit, _ = solve(starts[name], target, sharp, s, iterations)
            seconds[key] += time.perf_counter() - t0
            iters[key].append(nit)
            # One line a photograph: a run stopped at a deadline shows how far it got.
            print(f"{name}: {key}, {nit} iterations in {time.perf_counter() - t0:.1f} s", file=sys.stderr,
                  flush=True)
            score(key, display)
            if write is not None:
                written[name] = display.contiguous()
    if write is not None:
        from safetensors.torch import save_file
        write.mkdir(parents=True, exist_ok=True)
        stem = "displays" if n == 1 else f"displays-{k}-of-{n}"
        tmp = write / f"{stem}.safetensors.tmp"
        save_file(written, str(tmp))
        tmp.replace(write / f"{stem}.safetensors")
        # Every share writes the same manifest; the photographs are in the files.
        manifest = {"prefilter": f"ceiling w={sharp_weights[0]:g}", "sharp_weight": sharp_weights[0],
                    "iterations": iterations, "split": split}
        if n == 1:
            manifest["images"] = names
        else:
            manifest["shards"] = n
        tmp = write / f"prefilter.json.{k}.tmp"
        tmp.write_text(json.dumps(manifest, indent=1))
        tmp.replace(write / "prefilter.json")
    out = {"split": split, "photographs": names, "size": [w, h], "iterations": iterations,
           "depths_d": json.loads(target_obj.meta["depths_d"]), "rows": {}}
    for key, (vs_target, vs_sharp) in rows.items():
        out["rows"][key] = {"vs_target": summary(vs_target), "vs_sharp": summary(vs_sharp)}
        if iters[key]:
            out["rows"][key]["solver"] = {"seconds": round(seconds[key], 1), "iterations": iters[key]}
    base = out["rows"]["wiener"]
    for row in out["rows"].values():
        row["gain_over_wiener_db"] = {
            f"{vs} {stat}": round(row[vs][f"{stat}_db"] - base[vs][f"{stat}_db"], 3)
            for vs in ("vs_target", "vs_sharp") for stat in ("mean", "worst")}
    return out


def parse_shard(text: str) -> tuple:
    bad = ValueError(f"--shard {text!r}: K/N with 1 <= K <= N, e.g. 1/2")
    try:
        k, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise bad from None
    if not 1 <= k <= n:
        raise bad
    return k, n


def table(result: dict) -> str:
    lines = ["| display image | mean / worst vs target (dB) | mean / worst vs sharp (dB) | gain over Wiener, "
             "target mean / worst, sharp mean / worst |", "| --- | --- | --- | --- |"]
    for key, row in result["rows"].items():
        g = row["gain_over_wiener_db"]
        lines.append(f"| {key} | {row['vs_target']['mean_db']:.2f} / {row['vs_target']['worst_db']:.2f} | "
                     f"{row['vs_sharp']['mean_db']:.2f} / {row['vs_sharp']['worst_db']:.2f} | "
                     + " / ".join(f"{v:+.2f}" for v in g.values()) + " |")
    return "\n".join(lines)


def main(argv=None, prog=None):
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    ap.add_argument("--teacher", metavar="DIR", required=True, type=Path,
                    help="nedrt prefilter's folders: DIR/train and DIR/train-sharp (kernels at the validation "
                         "size), DIR/val (the optimum, the start), DIR/val-wiener")
    ap.add_argument("--images", metavar="DIR", help="image root with val/ (default: data/images)")
    ap.add_argument("--sharp-weight", default="0,1", help="comma-separated weights w of the PSNR vs sharp")
    ap.add_argument("--iterations", type=int, default=150, help="L-BFGS-B iterations per photograph")
    ap.add_argument("--limit", type=int, help="only the first N photographs")
    ap.add_argument("--split", choices=["val", "train"], default="val",
                    help="the photographs (their kernels, optimum and Wiener under --teacher)")
    ap.add_argument("--write", type=Path, metavar="DIR",
                    help="also write the display images (one --sharp-weight) as a teacher folder")
    ap.add_argument("--shard", default="1/1", metavar="K/N",
                    help="only every N-th photograph from the K-th (run N processes for N cores)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu",
                    help="where the objective and its gradient are computed (cpu, cuda); the solver runs on the CPU")
    ap.add_argument("--out", type=Path, help="write the result as JSON here")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    try:
        bad = ValueError(f"--sharp-weight {args.sharp_weight!r}: non-negative numbers, comma-separated")
        try:
            weights = [float(v) for v in args.sharp_weight.split(",") if v.strip()]
        except ValueError:
            raise bad from None
        if not weights or any(not math.isfinite(v) or v < 0 for v in weights):
            raise bad
        if args.iterations < 1:
            raise ValueError("--iterations: at least 1")
        shard = parse_shard(args.shard)
        if args.device.startswith("cuda") and not torch.cuda.is_available():
            raise ValueError(f"--device {args.device}: this torch sees no CUDA device")
        result = ceiling(args.teacher, resolve_root(args.images), weights, args.iterations, args.limit,
                         args.split, args.write, shard, args.device)
    except (ValueError, FileNotFoundError) as e:
        raise SystemExit(f"error: {e}")
    if args.out:
        tmp = args.out.with_suffix(args.out.suffix + ".tmp")
        tmp.write_text(json.dumps(result, indent=1))
        tmp.replace(args.out)
    print(table(result))


if __name__ == "__main__":
    main()
