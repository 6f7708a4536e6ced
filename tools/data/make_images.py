"""Derive the project's shipped test and training images from the photographs
bundled in the scikit-image wheel (PyPI), so the set is reproducible:

    .venv/bin/pip install scikit-image==0.26.0
    .venv/bin/python tools/data/make_images.py

Licences (from scikit-image's docstrings): astronaut, rocket and
hubble_deep_field are NASA/SpaceX public domain; coffee and chelsea are CC0.
Crops are multiples of 8 display pixels (docs/model.md §17). Training images
(used only to tune the Wiener constant K, and later by the trainer) and test
images come from different photographs.

The rest of data/images/train and the validation set data/images/val come from
tools/data/make_photos.py, which also writes data/images/manifest.json and
SOURCES.md for every image, these included (and checks that the committed
files are exactly these crops).
"""
from pathlib import Path

import numpy as np
from skimage import data, io

ROOT = Path(__file__).resolve().parents[2] / "data" / "images"


def crop(img, top, left, h, w):
    assert h % 8 == 0 and w % 8 == 0
    out = img[top:top + h, left:left + w, :3]
    assert out.shape == (h, w, 3), out.shape
    return np.ascontiguousarray(out)


def main():
    sets = {
        "test": {
            "astronaut": crop(data.astronaut(), 0, 0, 512, 512),
            "hubble": crop(data.hubble_deep_field(), 180, 240, 512, 512),
        },
        "train": {
            "coffee": crop(data.coffee(), 72, 120, 256, 256),
            "chelsea": crop(data.chelsea(), 20, 100, 256, 256),
            "rocket": crop(data.rocket(), 60, 190, 256, 256),
        },
    }
    for split, images in sets.items():
        (ROOT / split).mkdir(parents=True, exist_ok=True)
        for name, img in images.items():
            path = ROOT / split / f"{name}.png"
            io.imsave(path, img, check_contrast=False)
            print(path.relative_to(ROOT.parents[1]), img.shape)


if __name__ == "__main__":
    main()
