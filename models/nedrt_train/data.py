"""Training and validation images, nothing downloaded: procedural images with
natural-image statistics (dead leaves with a 1/r³ size distribution, which
gives the 1/f spectrum of natural scenes, plus edges, colour gradients and
bar patterns) and the photographs shipped in data/images: training crops in
data/images/train, a validation set in data/images/val, both cut from
photographs that PyPI and Debian packages ship (tools/data/make_photos.py;
provenance and licences in data/images/SOURCES.md). The validation
photographs are never trained on, and the test photographs (data/images/test)
are neither trained nor validated on.

The folders are arguments: the commands take the image root (`--images DIR`,
by default `data/images` under the current directory, see `resolve_root`)
and pass its `train`, `val` or `test` folder on."""
import math
from pathlib import Path

import numpy as np
import torch

from .paths import resolve_cli_path

#: Where a command looks for the image folders when `--images` is not given,
#: relative to the current directory (the repository root, usually).
DEFAULT_ROOT = Path("data") / "images"


def resolve_root(arg=None, cwd=None) -> Path:
    """The image root a command line names (the folder holding train/, val/
    and test/): `arg`, or `data/images` under `cwd` (the current directory)
    when `arg` is None; absolute. Raises FileNotFoundError naming the path
    when it is not a folder."""
    return resolve_cli_path(arg, DEFAULT_ROOT, cwd, folder=True, what="image folder", flag="--images DIR")


def photo_folder(folder) -> Path:
    """`folder` as a Path, refused (naming it) when it is not a folder: a
    mistyped path must not train on no photographs without a word."""
    if folder is None:
        raise ValueError("no photograph folder given (pass --images DIR)")
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: photograph folder not found")
    return folder


def dead_leaves(rng: np.random.Generator, size: int, r_min: float = 3.0, r_max: float = None) -> np.ndarray:
    """A dead-leaves image (H×W×3 in [0, 1]): opaque discs dropped front to
    back, radii with density ∝ r⁻³, until 99.5 % of the frame is covered
    (the rest, a few pixels, takes a background colour)."""
    r_max = r_max or size / 3
    img = np.zeros((size, size, 3))
    covered = np.zeros((size, size), bool)
    uncovered = size * size
    for _ in range(20000):
        if uncovered <= size * size // 200:
            img[~covered] = rng.random(3) ** 1.5
            break
        # Inverse CDF of p(r) ∝ r⁻³ on [r_min, r_max].
        u = rng.random()
        r = 1 / math.sqrt(1 / r_min ** 2 - u * (1 / r_min ** 2 - 1 / r_max ** 2))
        cx, cy = rng.uniform(-r, size + r, 2)
        shaded, shade = rng.random() < 0.3, rng.uniform(-0.5, 0.5)
        color = rng.random(3) ** 1.5
        # Work inside the disc's bounding box only.
        x0, x1 = max(int(cx - r), 0), min(int(cx + r) + 1, size)
        y0, y1 = max(int(cy - r), 0), min(int(cy + r) + 1, size)
        if x0 >= x1 or y0 >= y1:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1]
        disc = (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r
        box = covered[y0:y1, x0:x1]
        new = disc & ~box
        if new.any():
            if shaded:  # a shaded leaf: linear colour gradient
                g = (xx - cx) / (2 * r) * shade
                img[y0:y1, x0:x1][new] = np.clip(color[None, :] + g[new][:, None], 0, 1)
            else:
                img[y0:y1, x0:x1][new] = color
            uncovered -= int(new.sum())
            box |= disc
    return img


def bars(rng: np.random.Generator, size: int) -> np.ndarray:
    """Sharp bar patterns of random period and orientation on a colour gradient."""
    yy, xx = np.mgrid[0:size, 0:size] / size
    angle = rng.uniform(0, math.pi)
    period = rng.uniform(0.02, 0.2)
    phase = (xx * math.cos(angle) + yy * math.sin(angle)) / period
    stripes = (np.floor(phase) % 2)[..., None]
    a, b = rng.random(3), rng.random(3)
    background = a[None, None, :] * (1 - xx[..., None]) + b[None, None, :] * xx[..., None]
    return np.clip(0.7 * background + 0.3 * stripes * rng.random(3), 0, 1)


def load_photos(folder: Path) -> list:
    """Every PNG of `folder`, sorted by name, as H×W×3 float32 in [0, 1]
    (8-bit code values, taken as linear intensity)."""
    from PIL import Image
    return [np.asarray(Image.open(p).convert("RGB"), dtype=np.float32) / 255 for p in sorted(folder.glob("*.png"))]


class TrainingImages:
    """Random patches: procedural images and random crops/flips of the
    training photographs (every PNG of `photo_dir`, data/images/train, at
    least `patch` on a side), in proportion `photo_share`."""

    def __init__(self, patch: int, seed: int, photo_dir, photo_share: float = 0.3):
        self.patch = patch
        self.rng = np.random.default_rng(seed)
        self.photos = [p for p in load_photos(photo_folder(photo_dir)) if min(p.shape[:2]) >= patch]
        self.photo_share = photo_share if self.photos else 0.0

    def sample(self) -> np.ndarray:
        rng, n = self.rng, self.patch
        if rng.random() < self.photo_share:
            p = self.photos[rng.integers(len(self.photos))]
            y = rng.integers(p.shape[0] - n + 1)
            x = rng.integers(p.shape[1] - n + 1)
            img = p[y:y + n, x:x + n]
            if rng.random() < 0.5:
                img = img[:, ::-1]
            return np.ascontiguousarray(img)
        return (dead_leaves if rng.random() < 0.8 else bars)(rng, n).astype(np.float32)

    def batch(self, size: int) -> torch.Tensor:
        return torch.from_numpy(np.stack([self.sample() for _ in range(size)])).permute(0, 3, 1, 2).contiguous()


def validation_photos(val_dir, patch: int = None) -> torch.Tensor:
    """The validation photographs of `val_dir`, data/images/val (N×3×H×W, float32 in
    [0, 1]), disjoint from the training photographs by source photograph;
    with `patch`, their centre patch×patch crops (photographs smaller than
    that are left out), else their centre squares of the smallest side (all
    are 384×384 now, so the whole photographs)."""
    photos, imgs = load_photos(photo_folder(val_dir)), []
    side = patch or min((min(p.shape[:2]) for p in photos), default=0)
    for p in photos:
        n = side
        y, x = (p.shape[0] - n) // 2, (p.shape[1] - n) // 2
        if y >= 0 and x >= 0:
            imgs.append(p[y:y + n, x:x + n])
    if not imgs:
        return torch.zeros(0, 3, patch or 0, patch or 0)
    return torch.from_numpy(np.stack(imgs)).permute(0, 3, 1, 2).contiguous()


def validation_images(patch: int, val_dir, count: int = 4, seed: int = 10_000) -> torch.Tensor:
    """A fixed validation set, disjoint from training: procedural images from
    their own seed plus centre crops of the validation photographs in
    `val_dir` (data/images/val; until issue 14 these were the test
    photographs, which are now kept for the final evaluation only)."""
    rng = np.random.default_rng(seed)
    imgs = [dead_leaves(rng, patch).astype(np.float32) for _ in range(count)]
    for p in load_photos(photo_folder(val_dir)):
        y, x = (p.shape[0] - patch) // 2, (p.shape[1] - patch) // 2
        if y >= 0 and x >= 0:
            imgs.append(p[y:y + patch, x:x + patch])
    return torch.from_numpy(np.stack(imgs)).permute(0, 3, 1, 2).contiguous()
