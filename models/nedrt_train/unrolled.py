"""The unrolled preprocessor (issue 55, item 3), first on the CPU at small
crops to choose the design: K steps of the split solver (nedrt-optics'
`admm:K`, docs/optimal.md) through nedrt's exact objective (objective.py,
the kernels of `nedrt prefilter --operator`), each followed by a small
residual CNN whose last layer starts at zero, so that the untrained model
is the classical solver. Per step: a learned penalty ρ_k (a share of L)
and relaxation α_k; the CNN sees the relaxed point, the dual, and the
objective's gradient at the relaxed point (which carries the PSF's reach
into its receptive field), and corrects the point before the clamp:

    x   = (N + ρ_k)⁻¹ (Σ_D A_Dᵀ t_D + ρ_k (z − u))
    r   = α_k x + (1 − α_k) z
    z⁺  = clamp(r + u + CNN_k(r + u, u, ∇f(r)), 0, 1),   u⁺ = u + r − z⁺

from z = the clamped `lsq` image (the kernels' `linear` filter, as
nedrt's `admm:K` starts; the clamped frame for older kernel files) and
u = 0, trained with a loss at every step or at the last (`--loss`; the
objective's mean squared error per depth, channel and retinal value, the
evaluation's PSNR scale). The CNN's convolutions pad with zeros, as the
runtime's do, and the objective works on the mirrored frame, as the
runtime's split solver does, so the exported model (`--export`,
unrolled_export.py) computes on the runtime what it computed here. It
prints, per step, the classical solver's and the learned one's PSNR on
held-out crops of data/images/val.

    python -m nedrt_train.unrolled --kernels out/op/operator-128x128.safetensors \\
        --steps 3 --iterations 300 --out out/unrolled --export models/unrolled
"""
import argparse
import json
import math
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .data import load_photos, photo_folder, validation_photos
from .objective import Objective, db


class StepCorrection(nn.Module):
    """A few 3×3 layers; the last one zero so the step starts classical."""

    def __init__(self, width: int = 16, layers: int = 3):
        super().__init__()
        chans = [9] + [width] * (layers - 1)
        body = []
        for cin, cout in zip(chans[:-1], chans[1:]):
            body += [nn.Conv2d(cin, cout, 3, padding=1), nn.ReLU()]
        self.body = nn.Sequential(*body)
        self.last = nn.Conv2d(chans[-1], 3, 3, padding=1)
        nn.init.zeros_(self.last.weight)
        nn.init.zeros_(self.last.bias)

    def forward(self, point, dual, gradient):
        return self.planes(torch.cat([point, dual, gradient], dim=1))

    def planes(self, seen):
        """On the 9 planes as the runtime stacks them: point, dual, gradient."""
        return self.last(self.body(seen))


class Unrolled(nn.Module):
    """K split-solver steps with learned ρ_k, α_k and corrections."""

    def __init__(self, objective: Objective, steps: int, rho: float = 0.05, relaxation: float = 1.8,
                 width: int = 16, learned: bool = True):
        super().__init__()
        self.objective = objective
        normal = objective.spectra["normal"].real  # channels × 2h × (w + 1)
        self.normal = normal
        self.lipschitz = normal.amax(dim=(-2, -1)).view(1, -1, 1, 1)
        self.log_rho = nn.Parameter(torch.full((steps,), math.log(rho)))
        # α in (0, 2): 2·sigmoid.
        self.relax = nn.Parameter(torch.full((steps,), math.log(relaxation / (2 - relaxation))))
        self.corrections = nn.ModuleList(StepCorrection(width) for _ in range(steps)) if learned else None
        self.steps = steps

    def quadrant(self, x):
        h, w = self.objective.size
        return x[..., :h, :w]

    def start(self, image):
        """The clamped `lsq` image, as nedrt's split solver starts (the
        clamped frame where the kernels have no lsq filter)."""
        if self.objective.linear is None:
            return image.clamp(0, 1)
        return self.objective.lsq(image).clamp(0, 1)

    def forward(self, image, start=None):
        """Every step's display image (a list of B×3×h×w)."""
        o = self.objective
        spectrum = lambda x: torch.fft.rfft2(o.mirror(x))
        s = o.mirror(image).shape[-2:]
        b = spectrum(image) * o.spectra["adjoint_target"]
        z = (self.start(image) if start is None else start).clamp(0, 1)
        u = torch.zeros_like(z)
        out = []
        for k in range(self.steps):
            rho = torch.exp(self.log_rho[k]) * self.lipschitz
            alpha = 2 * torch.sigmoid(self.relax[k])
            x = self.quadrant(torch.fft.irfft2((b + rho * spectrum(z - u)) / (self.normal + rho), s=s))
            r = alpha * x + (1 - alpha) * z
            point = r + u
            if self.corrections is not None:
                gradient = self.quadrant(torch.fft.irfft2(spectrum(r) * o.spectra["normal"], s=s)
                                         - torch.fft.irfft2(b, s=s))
                point = point + self.corrections[k](point, u, gradient / self.lipschitz)
            z_next = point.clamp(0, 1)
            u = u + r - z_next
            z = z_next
            out.append(z)
        return out


def crops(photos: list, patch: int, rng: np.random.Generator, count: int) -> torch.Tensor:
    picked = []
    for _ in range(count):
        p = photos[rng.integers(len(photos))]
        y = rng.integers(p.shape[0] - patch + 1)
        x = rng.integers(p.shape[1] - patch + 1)
        c = p[y:y + patch, x:x + patch]
        if rng.random() < 0.5:
            c = c[:, ::-1]
        picked.append(np.ascontiguousarray(c))
    return torch.from_numpy(np.stack(picked)).permute(0, 3, 1, 2).contiguous()


def step_db(objective: Objective, displays: list, image) -> list:
    return [db(objective.mse(d, image).mean()) for d in displays]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description="the unrolled preprocessor on the CPU at small crops")
    ap.add_argument("--kernels", type=Path, required=True, help="operator-PxP.safetensors (nedrt prefilter --operator)")
    ap.add_argument("--photos", type=Path, default=Path("data/images/train"))
    ap.add_argument("--val", type=Path, default=Path("data/images/val"))
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--iterations", type=int, default=300)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--width", type=int, default=16)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--loss", choices=("every", "last"), default="every",
                    help="the squared error of every step's display image, averaged, or of the last alone")
    ap.add_argument("--out", type=Path, default=Path("out/unrolled"))
    ap.add_argument("--export", type=Path, default=None,
                    help="write the trained model here for the runtime (a manifest and one ONNX per step)")
    ap.add_argument("--name", default=None, help="the exported model's name (default unrolled-kK)")
    ap.add_argument("--doe", type=Path, default=None,
                    help="the DOE file the kernels were made through, copied beside the export "
                         "(NAME.unrolled.doe.safetensors, where nedrt's --dcnn looks for a model's DOE)")
    a = ap.parse_args(argv)
    if a.doe is not None and not a.doe.is_file():
        raise SystemExit(f"{a.doe}: no DOE file")
    torch.manual_seed(a.seed)
    objective = Objective.load(a.kernels)
    patch = objective.size[0]
    if objective.size[0] != objective.size[1]:
        raise SystemExit(f"{a.kernels}: square kernels only, these are {objective.size}")
    photos = [p for p in load_photos(photo_folder(a.photos)) if min(p.shape[:2]) >= patch]
    val = validation_photos(a.val, patch)
    if not photos or len(val) == 0:
        raise SystemExit(f"no photographs of at least {patch}² in {a.photos} or {a.val}")
    rng = np.random.default_rng(a.seed)
    classical = Unrolled(objective, a.steps, learned=False)
    model = Unrolled(objective, a.steps, width=a.width)
    with torch.no_grad():
        base = step_db(objective, classical(val), val)
        start_db = db(objective.mse(classical.start(val), val).mean())
        # The ceiling at this crop: the classical solver run to convergence.
        ceiling_db = step_db(objective, Unrolled(objective, 300, learned=False)(val)[-1:], val)[0]
    print(f"val dB: start {start_db:.3f}, classical admm steps 1..{a.steps} {[round(v, 3) for v in base]}, "
          f"ceiling (300 steps) {ceiling_db:.3f}")
    opt = torch.optim.Adam(model.parameters(), lr=a.lr)
    log = []
    for it in range(1, a.iterations + 1):
        batch = crops(photos, patch, rng, a.batch)
        displays = model(batch)
        scored = displays if a.loss == "every" else displays[-1:]
        loss = sum(objective.mse(d, batch).mean() for d in scored) / len(scored)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if it % 50 == 0 or it == a.iterations:
            with torch.no_grad():
                learned = step_db(objective, model(val), val)
            row = {"iteration": it, "train_loss_db": db(loss.item()), "val_db": learned,
                   "classical_val_db": base, "start_val_db": start_db, "ceiling_val_db": ceiling_db,
                   "rho": torch.exp(model.log_rho).tolist(),
                   "relaxation": (2 * torch.sigmoid(model.relax)).tolist()}
            log.append(row)
            print(json.dumps(row))
    a.out.mkdir(parents=True, exist_ok=True)
    suffix = "" if a.loss == "every" else f"-{a.loss}"
    (a.out / f"log-k{a.steps}{suffix}.json").write_text(json.dumps(log, indent=1))
    if a.export is not None:
        from .unrolled_export import export
        manifest = export(model, a.kernels, a.export, a.name or f"unrolled-k{a.steps}",
                          note=f"{a.iterations} iterations at {patch}², loss on {a.loss} step(s), seed {a.seed}",
                          doe=a.doe)
        print(f"wrote {manifest}")


if __name__ == "__main__":
    main()
