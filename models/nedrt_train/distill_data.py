"""What the D-CNN stage (distill.py) trains on, besides the photographs
(data.py): the teacher's display images (nedrt prefilter's or the
ceiling's, by photograph name), and the random, turned patches of the
photographs with their teachers cut alike, drawn in an order that makes
a batch the same on any device."""
from pathlib import Path

import numpy as np
import torch

from .data import photo_folder


def load_teacher(folder: Path, names: list) -> dict:
    """The teacher's display images (`displays.safetensors` of nedrt
    prefilter, or the shares `displays-K-of-N.safetensors` of a sharded
    `nedrt-train ceiling`), by photograph name."""
    from safetensors.torch import load_file
    path = folder / "displays.safetensors"
    files = [path] if path.is_file() else sorted(folder.glob("displays-*-of-*.safetensors"))
    if not files:
        raise FileNotFoundError(f"{path}: no teacher display images (run nedrt prefilter --out-dir {folder})")
    t = {}
    for f in files:
        for name, display in load_file(str(f)).items():
            if name in t:
                raise ValueError(f"{f}: {name} is also in another share of {folder}")
            t[name] = display
    missing = [n for n in names if n not in t]
    if missing:
        where = path if files == [path] else f"{folder}'s {len(files)} shares"
        raise ValueError(f"{where}: no display image for {', '.join(missing[:5])}")
    return {n: t[n].float() for n in names}


def photo_names(folder: Path) -> list:
    return [p.stem for p in sorted(photo_folder(folder).glob("*.png"))]


class Patches:
    """Random P×P crops of the training photographs under one of the eight
    symmetries of the square (the PSFs are rotationally symmetric, so the
    teacher turns with its photograph), with the teacher cropped alike.
    The draws come from one numpy generator in a fixed order (photograph,
    row, column, turn, flip per patch), so a batch is the same on any
    device; the crops are cut on the photographs' device, in a few
    operations per batch when the photographs are of one size."""

    def __init__(self, photos: list, teachers: list, patch: int, seed: int, bases: list | None = None,
                 device="cpu"):
        self.photos = [torch.from_numpy(p).permute(2, 0, 1).contiguous() for p in photos]
        stacks = (self.photos, teachers, bases)
        sizes = {tuple(t.shape) for stack in stacks if stack is not None for t in stack}
        # One tensor per stack where every photograph has the same size:
        # a batch is then one gather per stack.
        self.dense = len(sizes) == 1
        self.stacks = [None if stack is None else
                       (torch.stack(stack).to(device) if self.dense else [t.to(device) for t in stack])
                       for stack in stacks]
        self.patch = patch
        self.device = torch.device(device)
        self.rng = np.random.default_rng(seed)

    def draw(self, size: int) -> np.ndarray:
        """B × (photograph, row, column, turn, flip), in the generator's order."""
        out = np.empty((size, 5), dtype=np.int64)
        n = self.patch
        for b in range(size):
            k = self.rng.integers(len(self.photos))
            p = self.photos[k]
            y = self.rng.integers(p.shape[1] - n + 1)
            x = self.rng.integers(p.shape[2] - n + 1)
            out[b] = (k, y, x, int(self.rng.integers(4)), int(self.rng.integers(2)))
        return out

    def batch(self, size: int):
        """(images, teachers, bases or None), each B × 3 × P × P, on the device."""
        draws = self.draw(size)
        n = self.patch
        if not self.dense:
            out = [[], [], []]
            for k, y, x, turn, flip in draws:
                for i, stack in enumerate(self.stacks):
                    if stack is not None:
                        t = torch.rot90(stack[k][:, y:y + n, x:x + n], int(turn), (1, 2))
                        out[i].append(t.flip(-1) if flip else t)
            return tuple(torch.stack(o).contiguous() if o else None for o in out)
        # One upload a batch: the draws, and the patches ordered by symmetry.
        group = draws[:, 3] * 2 + draws[:, 4]
        order = np.argsort(group, kind="stable")
        d = torch.from_numpy(np.concatenate([draws, order[:, None]], axis=1)).to(self.device)
        ar = torch.arange(n, device=self.device)
        rows = (d[:, 1, None] + ar)[:, None, :, None]
        cols = (d[:, 2, None] + ar)[:, None, None, :]
        chan = torch.arange(3, device=self.device)[None, :, None, None]
        k = d[:, 0, None, None, None]
        crops = [None if stack is None else stack[k, chan, rows, cols] for stack in self.stacks]
        # The symmetries, one group of patches at a time (at most eight).
        counts = np.bincount(group, minlength=8)
        start = 0
        for g, count in enumerate(counts):
            idx = d[start:start + count, 5]
            start += count
            turn, flip = divmod(g, 2)
            if count == 0 or g == 0:
                continue
            for c in crops:
                if c is not None:
                    t = torch.rot90(c[idx], int(turn), (2, 3))
                    c[idx] = t.flip(-1) if flip else t
        return tuple(None if c is None else c.contiguous() for c in crops)
