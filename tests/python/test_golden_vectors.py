"""Independent numpy implementation of docs/model.md checked against the golden
vectors the Rust simulator writes (tests/golden/vectors.json). Reads only
calib/default.toml and the vectors: the trainer and the Rust optics share no
code. Run: python -m pytest tests/python
"""
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
V = json.loads((ROOT / "tests/golden/vectors.json").read_text())
C = tomllib.loads((ROOT / "calib/default.toml").read_text())

R = C["lens"]["aperture_radius_mm"] * 1e-3
ZD = C["panel"]["lens_distance_mm"] * 1e-3
DTHETA = C["panel"]["pixel_pitch_um"] * 1e-6 / (2 * ZD)
FS = C["lens"]["focal_length_mm"] * 1e-3
NS = C["material"]["index_at_spec"]
CH = {c["name"]: (c["wavelength_nm"] * 1e-9, c["index"]) for c in C["channel"]}
L0, N0 = CH[C["doe"]["design_channel"]]


def vergence(name):
    lam, n = CH[name]
    return 1 / ZD - (n - 1) / (FS * (NS - 1))  # 1/f_λ = (n_λ − 1)/(f_s (n_s − 1))


def psi(name, d):
    lam, _ = CH[name]
    return math.pi / lam * (vergence(name) - d) * R * R


def grid(pitch):
    n = math.ceil(2 * R / pitch - 1e-9) + 1
    return (np.arange(n) - (n - 1) / 2) * pitch


def doe_init(pitch):
    s = grid(pitch)
    rho2 = (s[None, :] ** 2 + s[:, None] ** 2) / R ** 2
    d0 = C["doe"]["design_channel"]
    total = sum(np.exp(-1j * psi(d0, d) * rho2) for d in C["depths"]["main_d"])
    phi = np.mod(np.angle(total), 2 * np.pi)
    return phi / (2 * np.pi) * L0 / (N0 - 1)


PITCH = C["doe"]["design_pitch_um"] * 1e-6
S = grid(PITCH)
HEIGHT = doe_init(PITCH)


def psf(name, psi_rad, with_doe, window, sub):
    lam, n = CH[name]
    rho = np.hypot(S[None, :], S[:, None])
    amp = np.clip((R - rho) / PITCH + 0.5, 0, 1)
    phase = psi_rad * rho ** 2 / R ** 2
    if with_doe:
        phase = phase + 2 * np.pi * (n - 1) * HEIGHT / lam
    q = amp * np.exp(1j * phase)
    k = np.arange(window * sub)
    theta = ((k // sub) - (window - 1) / 2 + ((k % sub) + 0.5) / sub - 0.5) * DTHETA
    e = np.exp(-2j * np.pi * np.outer(theta, S) / lam)
    u = e @ q @ e.T
    scale = (DTHETA / sub) ** 2 * PITCH ** 2 / (lam ** 2 * np.sum(np.abs(q) ** 2))
    p = np.abs(u) ** 2 * scale
    return p.reshape(window, sub, window, sub).sum(axis=(1, 3))


def perceive(planes, kernels, veils):
    out = []
    for x, h, v in zip(planes, kernels, veils):
        up = np.kron(x, np.ones((2, 2)))
        a = h.shape[0] // 2
        padded = np.pad(up, a, mode="symmetric")
        # Direct 'valid' correlation with the flipped kernel = convolution.
        hf = h[::-1, ::-1]
        res = np.zeros_like(up)
        for dy in range(h.shape[0]):
            for dx in range(h.shape[1]):
                res += hf[dy, dx] * padded[dy:dy + up.shape[0], dx:dx + up.shape[1]]
        out.append(res + v * x.mean())
    return np.array(out)


def test_doe_initialisation():
    assert V["doe"]["samples"] == len(S)
    for i, j, h in V["doe"]["probe_row_col_height_m"]:
        assert abs(HEIGHT[i, j] - h) < 1e-15


@pytest.mark.parametrize("entry", V["psfs"], ids=lambda e: f'{e["optics"]}-{e["channel"]}-{e["accommodation_d"]}')
def test_psf(entry):
    if entry["accommodation_d"] is not None:
        assert abs(psi(entry["channel"], entry["accommodation_d"]) - entry["psi_rad"]) < 1e-9
    mine = psf(entry["channel"], entry["psi_rad"], entry["optics"] == "lens+doe", entry["window"], entry["sub_samples"])
    theirs = np.array(entry["cells"]).reshape(mine.shape)
    # The trainer's bar is 1e-5 relative; two float64 MFTs agree far closer.
    assert np.max(np.abs(mine - theirs)) <= 1e-9 * theirs.max()
    assert abs((1 - mine.sum()) - entry["veil"]) < 1e-9


def test_perceived_and_target():
    p = V["perceived"]
    n = p["width"]
    x = np.array(p["input"]).reshape(3, n, n)
    at = p["accommodation_d"]
    system = [psf(c, psi(c, at), True, 31, 4) for c in "RGB"]
    blur = [psf(c, C["target_blur"]["psi_rad"], False, 31, 4) for c in "RGB"]
    for key, kernels in [("perceived", system), ("target", blur)]:
        mine = perceive(x, kernels, [1 - k.sum() for k in kernels])
        theirs = np.array(p[key]).reshape(mine.shape)
        mse = np.mean((mine - theirs) ** 2)
        psnr = 10 * np.log10(1 / mse)
        assert psnr >= 60, f"{key}: {psnr:.1f} dB"
