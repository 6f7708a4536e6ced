"""Side-by-side benchmark: nedrt (Rust) against a plain numpy implementation
of the same computations on the same inputs, in one run, rounds interleaved.

    cargo build --release
    .venv/bin/python tools/bench/compare_numpy.py [--rounds 3]

1. One PSF: G, 1.0 D, three-lens DOE, pupil on the planner's ≈6 µm grid,
   the planner's window and sub-sampling. Rust: the whole planner (grid
   choice, pupil, FFT over the period with the convergence loop on m), and
   the MFT and FFT propagators alone; numpy: the MFT (E·Q·Eᵀ with BLAS) and
   the FFT over the period, on the pupil Rust wrote.
2. One perceived 512×512 display image (3 channels, 1.0 D) through lens +
   DOE and through the lens: symmetric padding, real FFT convolution,
   crop, veil. numpy in float32 like Rust.
Prints a Markdown table (for docs/benchmarks.md) and checks the results agree.
"""
import argparse
import json
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
NEDRT = ROOT / "target" / "release" / "nedrt"
DUMP = ROOT / "out" / "bench"


def nedrt(*args):
    env = dict(os.environ, NEDRT_CACHE_DIR=str(DUMP / "cache"))
    out = subprocess.run([str(NEDRT), *args], check=True, capture_output=True, text=True, env=env).stdout
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def timed(f, repeat):
    f()
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        r = f()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts), r


def numpy_psf(info, q):
    n, w, sub = info["pupil_samples"], info["window"], info["sub_samples"]
    lam, dth, step = info["wavelength_m"], info["cell_rad"], info["pupil_step_m"]
    s = (np.arange(n) - (n - 1) / 2) * step
    energy = np.sum(np.abs(q) ** 2)

    def mft():
        k = np.arange(w * sub)
        theta = ((k // sub) - (w - 1) / 2 + ((k % sub) + 0.5) / sub - 0.5) * dth
        e = np.exp(-2j * np.pi * np.outer(theta, s) / lam)
        u = e @ q @ e.T
        p = np.abs(u) ** 2 * (dth / sub) ** 2 * step ** 2 / (lam ** 2 * energy)
        return p.reshape(w, sub, w, sub).sum(axis=(1, 3))

    def fft():
        p_cells = info["period_cells"]
        m = sub * p_cells
        delta = (0.5 / sub - 0.5) * dth
        tilt = np.exp(-2j * np.pi * s * delta / lam)
        folded = np.zeros((m, m), complex)
        qt = q * tilt[:, None] * tilt[None, :]
        for i0 in range(0, n, m):
            for j0 in range(0, n, m):
                blk = qt[i0:i0 + m, j0:j0 + m]
                folded[:blk.shape[0], :blk.shape[1]] += blk
        power = np.abs(np.fft.fft2(folded)) ** 2 / (m * m * energy)
        cells = power.reshape(p_cells, sub, p_cells, sub).sum(axis=(1, 3))
        cells = np.roll(cells, (p_cells // 2, p_cells // 2), axis=(0, 1))
        start = p_cells // 2 - (w - 1) // 2
        return cells[start:start + w, start:start + w]

    return mft, fft


def numpy_perceived(image, kernels, veils):
    def run():
        out = []
        for x, h, v in zip(image, kernels, veils):
            up = np.kron(x, np.ones((2, 2), np.float32))
            a = h.shape[0] // 2
            padded = np.pad(up, a, mode="symmetric")
            shape = (padded.shape[0], padded.shape[1])
            spec = np.fft.rfft2(padded) * np.fft.rfft2(h.astype(np.float32), s=shape)
            full = np.fft.irfft2(spec, s=shape)
            # Kernel at the origin corner: output row y is full row y + 2a.
            res = full[2 * a:2 * a + up.shape[0], 2 * a:2 * a + up.shape[1]]
            out.append(res + np.float32(v * x.mean()))
        return np.array(out, np.float32)
    return run


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    rows = []
    ceil = nedrt("bench", "ceilings")[0]
    rust_psf, np_mft, np_fft, rust_perc, np_perc = [], [], [], {"doe": [], "lens": []}, {"doe": [], "lens": []}
    for _ in range(args.rounds):
        info = nedrt("bench", "psf", "--dump", str(DUMP), "--repeat", "1")[0]
        rust_psf.append(info)
        q = np.fromfile(DUMP / "pupil.f64").view(complex).reshape(info["pupil_samples"], -1)
        mft, fft = numpy_psf(info, q)
        t_mft, p_mft = timed(mft, 1)
        t_fft, p_fft = timed(fft, 1)
        ref = np.fromfile(DUMP / "psf.f64").reshape(info["window"], -1)
        assert np.max(np.abs(p_mft - ref)) < 1e-9 * ref.max(), "numpy MFT disagrees with nedrt"
        assert np.max(np.abs(p_fft - ref)) < 1e-9 * ref.max(), "numpy FFT disagrees with nedrt"
        np_mft.append(t_mft)
        np_fft.append(t_fft)
        for line in nedrt("bench", "perceived", "--dump", str(DUMP), "--repeat", "3"):
            rust_perc[line["optics"]].append(line)
            w = line["window"]
            image = np.fromfile(DUMP / "image.f64").astype(np.float32).reshape(3, line["height"], line["width"])
            kernels = np.fromfile(DUMP / f"kernel_{line['optics']}.f64").reshape(3, w, w)
            t, _ = timed(numpy_perceived(image, kernels, line["veil"]), 3)
            np_perc[line["optics"]].append(t)

    med = lambda xs: statistics.median(xs)
    i0 = rust_psf[0]
    gflops = ceil["f64_gemm_gflops"]
    t_planner = med([r["planner_s"] for r in rust_psf])
    t_rfft = med([r["fft_s"] for r in rust_psf])
    t_rmft = med([r["mft_s"] for r in rust_psf])
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
          f"numpy {np.__version__}; measured ceilings: f64 GEMM {gflops:.1f} GFLOP/s, copy {ceil['copy_gbps']:.1f} GB/s")
    print(f"PSF: G 1.0 D, DOE, N = {i0['pupil_samples']} ({i0['pupil_step_m']*1e6:.2f} µm), window {i0['window']}, "
          f"sub-samples {i0['sub_samples']}, period {i0['period_cells']} cells, FFT size {i0['fft_size']}\n")
    print("| computation | nedrt (Rust) | numpy | numpy / nedrt | nedrt GFLOP/s (share of GEMM ceiling) |")
    print("| --- | --- | --- | --- | --- |")
    print(f"| PSF, whole planner (Rust) vs numpy MFT | {t_planner:.3f} s | {med(np_mft):.3f} s | {med(np_mft)/t_planner:.1f}× | – |")
    print(f"| PSF, MFT alone (same W, m, N) | {t_rmft:.3f} s | {med(np_mft):.3f} s | {med(np_mft)/t_rmft:.2f}× | "
          f"{i0['mft_flops']/t_rmft/1e9:.1f} ({i0['mft_flops']/t_rmft/1e9/gflops:.0%}) |")
    print(f"| PSF, FFT over the period alone | {t_rfft:.3f} s | {med(np_fft):.3f} s | {med(np_fft)/t_rfft:.2f}× | "
          f"{i0['fft_flops']/t_rfft/1e9:.1f} ({i0['fft_flops']/t_rfft/1e9/gflops:.0%}) |")
    for name in ["doe", "lens"]:
        r = med([x["seconds"] for x in rust_perc[name]])
        w = rust_perc[name][0]["window"]
        print(f"| perceived 512×512, 3 ch, {'lens + DOE' if name == 'doe' else 'lens'} (kernel {w}×{w}) | {r:.3f} s | "
              f"{med(np_perc[name]):.3f} s | {med(np_perc[name])/r:.2f}× | – |")


if __name__ == "__main__":
    main()
