"""What the eye sees through nedrt's display, from Python: one photograph
through the multifocal design at three accommodations, with the design's
Wiener and with the split solver (admm:3), scored against the sharp image.

    python examples/python/perceived.py [IMAGE]      # from the repository root

Needs the package (README, "Python"): maturin develop --release -m runtime/python/Cargo.toml
"""
import sys

import numpy as np

import nedrt


def load(path):
    from PIL import Image  # any loader that gives H×W×3 in [0, 1] will do

    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0


def psnr(a, b):
    return 10 * np.log10(1.0 / np.mean((a - b) ** 2))


def main():
    image = load(sys.argv[1]) if len(sys.argv) > 1 else load("data/images/val/airport.png")[:128, :128]
    display = nedrt.Display(design="multifocal")
    sharp = image.repeat(2, axis=0).repeat(2, axis=1)  # the retinal grid is twice the panel's
    print("accommodation  prefilter  PSNR vs sharp (dB)")
    for d in (0.5, 1.0, 1.5):
        for prefilter in ("native", "admm:3"):
            seen = display.perceived(image, d, method="doe+wiener", prefilter=prefilter)
            print(f"{d:>11.1f} D  {prefilter:>9}  {psnr(seen, sharp):6.2f}")
    psfs = display.psfs(1.5, method="doe+wiener")
    print(f"PSFs at 1.5 D: {psfs.shape}, light in the window per channel {psfs.sum(axis=(1, 2)).round(4)}")


if __name__ == "__main__":
    main()
