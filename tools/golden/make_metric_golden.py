"""Golden PSNR/SSIM values from scikit-image, the reference implementation
that docs/model.md §16 names, for the Rust metrics test.

    .venv/bin/pip install scikit-image==0.26.0 numpy
    .venv/bin/python tools/golden/make_metric_golden.py

Writes tests/golden/metrics.json. Inputs are float32-representable so both
sides see the same numbers.
"""
import json
from pathlib import Path

import numpy as np
import skimage
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

OUT = Path(__file__).resolve().parents[2] / "tests" / "golden" / "metrics.json"


def case(rng, h, w, kind):
    a = rng.random((h, w, 3)).astype(np.float32)
    if kind == "noise":
        b = np.clip(a + 0.1 * rng.standard_normal(a.shape), 0, 1)
    elif kind == "blur":
        b = (a + np.roll(a, 1, 0) + np.roll(a, 1, 1) + np.roll(a, (1, 1), (0, 1))) / 4
    else:  # contrast and offset change
        b = 0.6 * a + 0.3
    b = b.astype(np.float32)
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    ssim = structural_similarity(a64, b64, gaussian_weights=True, sigma=1.5,
                                 use_sample_covariance=False, data_range=1.0,
                                 channel_axis=2)
    psnr = peak_signal_noise_ratio(a64, b64, data_range=1.0)
    return {
        "kind": kind, "width": w, "height": h,
        "a": [a[:, :, c].ravel().tolist() for c in range(3)],
        "b": [b[:, :, c].ravel().tolist() for c in range(3)],
        "ssim": float(ssim), "psnr": float(psnr),
    }


def main():
    rng = np.random.default_rng(2026)
    cases = [case(rng, 24, 31, "noise"), case(rng, 17, 20, "blur"), case(rng, 16, 16, "affine")]
    OUT.write_text(json.dumps({"generator": f"scikit-image {skimage.__version__}",
                               "script": "tools/golden/make_metric_golden.py",
                               "cases": cases}))
    for c in cases:
        print(c["kind"], c["ssim"], c["psnr"])


if __name__ == "__main__":
    main()
