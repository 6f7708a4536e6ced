#!/usr/bin/env python3
"""What share of the ceiling's gain over the Wiener lies beyond a network's
receptive field (issue 55, item 1; docs/training.md, "Where the gain lies").

    python3 tools/diagnose/receptive_field.py [--nedrt target/release/nedrt]
        [--images data/images/val] [--doe models/dcnn.doe.safetensors]
        [--fields 30,100,300] [--out out/diagnose]

The optimum's display image (``optimal@target``) and the clamped Wiener's
(``doe+wiener``) come from ``nedrt prefilter``; the optimum's correction
c = optimum - Wiener is split at each receptive field R by a Gaussian
low-pass of sigma = R / (2 pi) pixels (its transfer falls to 1/e^0.5 at a
period of R pixels): c_far = G * c (periods longer than R: what a
network seeing R pixels cannot place from what it sees) and
c_near = c - c_far. Wiener + c_near and Wiener + c_far, clamped to the
panel's [0, 1], are scored by ``nedrt eval --display-dir`` beside the Wiener
and the optimum (each through the same path), mean PSNR vs sharp and vs
target over 0-2.5 D. Display images go to the evaluation as 16-bit PNGs.
"""

import argparse
import json
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np

HEADLINE_D = [0.0, 0.5, 1.0, 1.5, 2.0, 2.5]


def read_safetensors(path: Path) -> dict:
    raw = path.read_bytes()
    (n,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8:8 + n])
    body = raw[8 + n:]
    out = {}
    for name, meta in header.items():
        if name == "__metadata__":
            continue
        if meta["dtype"] != "F32":
            raise SystemExit(f"{path}: {name} is {meta['dtype']}, not F32")
        a, b = meta["data_offsets"]
        out[name] = np.frombuffer(body[a:b], dtype="<f4").reshape(meta["shape"])
    return out


def write_png16(path: Path, image: np.ndarray) -> None:
    """HxWx3 values in [0, 1] as a 16-bit RGB PNG."""
    h, w, _ = image.shape
    codes = np.round(np.clip(image, 0.0, 1.0) * 65535).astype(">u2")
    rows = b"".join(b"\x00" + codes[y].tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(rows, 6)) + chunk(b"IEND", b"")
    path.write_bytes(png)


def gaussian_lowpass(plane: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian with mirror (half-sample symmetric) borders, as
    the simulator extends a frame."""
    radius = max(1, int(np.ceil(4 * sigma)))
    x = np.arange(-radius, radius + 1)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    k /= k.sum()
    out = plane
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (radius, radius)
        padded = np.pad(out, pad, mode="symmetric")
        out = np.apply_along_axis(lambda v: np.convolve(v, k, mode="valid"), axis, padded)
    return out


def displays(nedrt: str, images: str, doe: str, prefilter: str, out: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    subprocess.run([nedrt, "prefilter", "--images", images, "--doe", doe, "--method", "doe+wiener",
                    "--prefilter", prefilter, "--out-dir", str(out)], check=True)
    return read_safetensors(out / "displays.safetensors")


def headline_means(eval_json: Path) -> dict:
    methods = json.loads(eval_json.read_text())["methods"]
    means = {}
    for m in methods:
        rows = [r for r in m["rows"] if any(abs(r["accommodation_d"] - d) < 1e-9 for d in HEADLINE_D)]
        name = m["method"]
        means[name] = tuple(float(np.mean([r[k]["psnr_db"] for r in rows])) for k in ("vs_sharp", "vs_target"))
    return means


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nedrt", default="target/release/nedrt")
    ap.add_argument("--images", default="data/images/val")
    ap.add_argument("--doe", default="models/dcnn.doe.safetensors")
    ap.add_argument("--fields", default="30,100,300")
    ap.add_argument("--out", default="out/diagnose", type=Path)
    a = ap.parse_args()
    fields = [int(f) for f in a.fields.split(",")]
    optimum = displays(a.nedrt, a.images, a.doe, "optimal@target", a.out / "optimal")
    wiener = displays(a.nedrt, a.images, a.doe, "native", a.out / "wiener")
    names = sorted(optimum)
    if sorted(wiener) != names:
        raise SystemExit("the two prefilter runs wrote different images")
    dirs = {"wiener": {}, "optimum": {}}
    for field in fields:
        dirs[f"r{field}-near"] = {}
        dirs[f"r{field}-far"] = {}
    for name in names:
        w = wiener[name].astype(np.float64)
        c = optimum[name].astype(np.float64) - w
        dirs["wiener"][name] = w
        dirs["optimum"][name] = w + c
        for field in fields:
            sigma = field / (2 * np.pi)
            # Channel-major planes (channels, height, width).
            far = np.stack([gaussian_lowpass(c[ch], sigma) for ch in range(c.shape[0])])
            dirs[f"r{field}-far"][name] = w + far
            dirs[f"r{field}-near"][name] = w + (c - far)
    report = {}
    for row, images in dirs.items():
        folder = a.out / "displays" / row
        folder.mkdir(parents=True, exist_ok=True)
        for name, image in images.items():
            write_png16(folder / f"{name}.png", np.moveaxis(image, 0, -1))
        ev = a.out / "eval" / row
        subprocess.run([a.nedrt, "eval", "--images", a.images, "--doe", a.doe, "--methods", "doe+wiener",
                        "--display-dir", str(folder), "--display-name", row, "--out-dir", str(ev)],
                       check=True)
        report[row] = headline_means(ev / "eval.json")[row]
        report.setdefault("doe+wiener (its own row)", headline_means(ev / "eval.json")["doe+wiener"])
    print(json.dumps(report, indent=1))
    (a.out / "report.json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    sys.exit(main())
