"""The eye's pupil (docs/model.md §4a) against an independent numpy model:
`nedrt sim --method conventional --pupil-mm 4 --eye-relief-mm 0` at 0, 0.5,
1.5 and 2.5 D scores within 0.25 dB PSNR (vs sharp) of the same display
computed here from the physics alone.

Independent of the Rust code: the lens-alone PSF of a 4 mm pupil in the lens
plane by a zero-padded 2-D FFT of a super-sampled pupil (Rust takes the
radial Hankel path), each retinal cell the mean of 5×5 density samples
(Rust integrates the cells in closed form), the whole period's light kept
(Rust keeps a window and a uniform veil); the image convolved by FFT over a
symmetric extension. Reads calib/default.toml only for the lens constants.
Needs the release binary (`cargo build --release`; `NEDRT` names another).
"""
import math
import os
import struct
import subprocess
import tomllib
import zlib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
C = tomllib.loads((ROOT / "calib/default.toml").read_text())
ZD = C["panel"]["lens_distance_mm"] * 1e-3
DTHETA = C["panel"]["pixel_pitch_um"] * 1e-6 / (2 * ZD)
FS = C["lens"]["focal_length_mm"] * 1e-3
NS = C["material"]["index_at_spec"]
CHANNELS = [(c["wavelength_nm"] * 1e-9, c["index"]) for c in C["channel"]]
NEDRT = Path(os.environ.get("NEDRT", ROOT / "target" / "release" / "nedrt"))

PUPIL_M = 4e-3
PERIOD_CELLS = 301  # the PSF's period: its light beyond ±150 cells wraps (≈0.1 %)
SUB = 5  # density samples per cell side (odd: they centre on the cell)


def vergence(lam, n):
    return 1 / ZD - (n - 1) / (FS * (NS - 1))


def pupil_psf(lam, n, accommodation_d):
    """Cells of the lens-alone PSF through a centred pupil of PUPIL_M in the
    lens plane, one period (PERIOD_CELLS²) summing to 1, centred."""
    # Pupil step for which the FFT's angular spacing is DTHETA / SUB.
    fft_n = PERIOD_CELLS * SUB
    step = lam / (PERIOD_CELLS * DTHETA)
    a = PUPIL_M / 2
    side = math.ceil(2 * a / step) + 2
    u = (np.arange(side) - (side - 1) / 2) * step
    # Each sample's share of the disk by 8×8 sub-samples.
    o = ((np.arange(8) + 0.5) / 8 - 0.5) * step
    fine = (u[:, None] + o[None, :]).ravel()
    inside = (fine[:, None] ** 2 + fine[None, :] ** 2) <= a * a
    amp = inside.reshape(side, 8, side, 8).mean(axis=(1, 3))
    rho2 = u[:, None] ** 2 + u[None, :] ** 2
    q = amp * np.exp(1j * math.pi / lam * (vergence(lam, n) - accommodation_d) * rho2)
    field = np.zeros((fft_n, fft_n), complex)
    field[:side, :side] = q
    density = np.abs(np.fft.fft2(field)) ** 2
    # Sample (k, l) lies at angle (k, l)·DTHETA/SUB (wrapped): shift so that
    # cell 0's SUB×SUB samples, centred on angle 0, come first.
    density = np.roll(density, (SUB // 2, SUB // 2), axis=(0, 1))
    cells = density.reshape(PERIOD_CELLS, SUB, PERIOD_CELLS, SUB).sum(axis=(1, 3))
    cells = np.fft.fftshift(cells)
    return cells / cells.sum()


def perceive(planes, kernels):
    out = []
    for x, h in zip(planes, kernels):
        up = np.kron(x, np.ones((2, 2)))
        a = h.shape[0] // 2
        padded = np.pad(up, a, mode="symmetric")
        shape = padded.shape
        full = np.fft.irfft2(np.fft.rfft2(padded) * np.fft.rfft2(h, s=shape), s=shape)
        out.append(full[2 * a:2 * a + up.shape[0], 2 * a:2 * a + up.shape[1]])
    return np.array(out)


def write_png(path, rgb8):
    h, w, _ = rgb8.shape
    raw = b"".join(b"\x00" + rgb8[y].tobytes() for y in range(h))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def make_image():
    """96×96 of edges, gradients and fine texture in every channel (seeded)."""
    rng = np.random.default_rng(31)
    y, x = np.mgrid[0:96, 0:96] / 96
    img = np.zeros((96, 96, 3))
    for c in range(3):
        img[..., c] = 0.4 + 0.3 * np.sin(2 * math.pi * (3 + 4 * c) * x * y)
        for _ in range(6):
            x0, y0, x1, y1 = np.sort(rng.integers(0, 96, 2)).tolist() + np.sort(rng.integers(0, 96, 2)).tolist()
            img[y0:y1, x0:x1, c] = rng.random()
    img += 0.1 * rng.standard_normal((96, 96, 3))
    return np.round(np.clip(img, 0, 1) * 255).astype(np.uint8)


@pytest.mark.skipif(not NEDRT.exists(), reason=f"needs the release binary {NEDRT} (cargo build --release)")
@pytest.mark.parametrize("accommodation_d", [0.0, 0.5, 1.5, 2.5])
def test_a_4mm_pupil_in_the_lens_plane_scores_as_the_independent_model(tmp_path, accommodation_d):
    rgb8 = make_image()
    write_png(tmp_path / "in.png", rgb8)
    out = subprocess.run(
        [str(NEDRT), "--no-cache", "sim", "--method", "conventional", "--pupil-mm", "4", "--eye-relief-mm", "0",
         "--accom", str(accommodation_d), "--input", str(tmp_path / "in.png"), "--out", str(tmp_path / "p.tif")],
        capture_output=True, text=True, check=True, timeout=600).stdout
    line = next(line for line in out.splitlines() if line.startswith("vs sharp"))
    theirs = float(line.split()[3])
    assert "radial" in out and "pupil 4.0 mm at 0.0 mm" in out, out

    planes = rgb8.transpose(2, 0, 1) / 255.0
    kernels = [pupil_psf(lam, n, accommodation_d) for lam, n in CHANNELS]
    mine = perceive(planes, kernels)
    sharp = np.kron(planes, np.ones((1, 2, 2)))
    psnr = 10 * math.log10(1 / np.mean((mine - sharp) ** 2))
    print(f"{accommodation_d} D: numpy {psnr:.3f} dB, nedrt {theirs:.2f} dB")
    assert abs(psnr - theirs) <= 0.25, f"{accommodation_d} D: numpy {psnr:.3f} dB, nedrt {theirs:.2f} dB"
