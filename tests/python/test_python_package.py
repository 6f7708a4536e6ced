"""The Python package `nedrt` (runtime/python, issue 58) against the CLI's
own output on the same input: every function equal to what `nedrt sim`,
`nedrt psf --at` and `nedrt eval` write (within 1e-6), and bad input raised
as a clear Python exception, never a crash.

scripts/test.sh builds the package into .venv (maturin) before pytest.
"""
import json
import re
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile
from safetensors.numpy import load_file

try:
    import nedrt
except ImportError as e:  # pragma: no cover - the message is the point
    raise ImportError(
        f"the nedrt package is not installed ({e}): scripts/test.sh builds it, or "
        "`maturin develop --release -m runtime/python/Cargo.toml` in the venv"
    ) from e

ROOT = Path(__file__).resolve().parents[2]
NEDRT = ROOT / "target" / "release" / "nedrt"


def cli(*args, cwd=ROOT):
    if not NEDRT.is_file():
        pytest.fail("target/release/nedrt is not built: scripts/test.sh builds it before pytest")
    r = subprocess.run([str(NEDRT), *map(str, args)], cwd=cwd, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return r.stdout


@pytest.fixture(scope="module")
def display():
    # From the repository root, as the CLI's relative design paths are.
    import os

    old = os.getcwd()
    os.chdir(ROOT)
    try:
        yield nedrt.Display(design="multifocal", cache=True)
    finally:
        os.chdir(old)


@pytest.fixture(scope="module")
def image():
    return np.random.default_rng(7).random((16, 24, 3), dtype=np.float32)


def test_perceived_and_prefilter_are_what_nedrt_sim_writes(display, image, tmp_path):
    src = tmp_path / "in.tif"
    tifffile.imwrite(src, image, photometric="rgb")
    for method, prefilter in (("doe+wiener", "native"), ("doe+wiener", "admm:3"), ("ai", "native")):
        out, disp = tmp_path / "p.tif", tmp_path / "d.tif"
        cli("--design", "multifocal", "sim", "--accom", "1.5", "--method", method, "--prefilter", prefilter,
            "--input", src, "--out", out, "--display-out", disp)
        seen = display.perceived(image, 1.5, method=method, prefilter=prefilter)
        made = display.prefilter(image, method=method, prefilter=prefilter)
        assert seen.shape == (32, 48, 3) and seen.dtype == np.float32
        assert made.shape == (16, 24, 3) and made.dtype == np.float32
        assert np.abs(seen - tifffile.imread(out)).max() <= 1e-6, (method, prefilter)
        assert np.abs(made - tifffile.imread(disp)).max() <= 1e-6, (method, prefilter)
    # The prefilter changed the frame: a comparison that can fail.
    assert np.abs(made - image).max() > 1e-3


def test_psfs_are_what_nedrt_psf_writes(display, tmp_path):
    cli("--design", "multifocal", "psf", "--at", "0.5", "--method", "doe+wiener", "--out-dir", tmp_path)
    want = load_file(str(tmp_path / "psfs.safetensors"))
    got = display.psfs(0.5, method="doe+wiener")
    assert got.shape == want["psfs"].shape and got.shape[0] == 3
    assert got.shape[1] == got.shape[2] and got.shape[1] % 2 == 1
    assert np.abs(got - want["psfs"]).max() <= 1e-6 * want["psfs"].max()
    # Each PSF's light in its window plus the veil is the light through the pupil.
    assert np.allclose(got.sum(axis=(1, 2)) + want["veil"], 1.0, atol=1e-6)


def test_evaluate_returns_nedrt_evals_numbers(display, tmp_path):
    images = tmp_path / "imgs"
    images.mkdir()
    rng = np.random.default_rng(3)
    for name in ("a", "b"):
        tifffile.imwrite(images / f"{name}.tif", rng.random((16, 16, 3), dtype=np.float32), photometric="rgb")
    out = tmp_path / "eval"
    cli("--design", "multifocal", "eval", "--images", images, "--methods", "conventional,doe+wiener",
        "--out-dir", out)
    want = json.loads((out / "eval.json").read_text())
    got = display.evaluate(images, methods=["conventional", "doe+wiener"])
    assert [m["method"] for m in got["methods"]] == [m["method"] for m in want["methods"]]
    assert len(got["methods"]) == 2 and got["images"] == want["images"]

    def numbers(x):
        if isinstance(x, dict):
            return [v for k in sorted(x) if k not in ("seconds", "time_s") for v in numbers(x[k])]
        if isinstance(x, list):
            return [v for e in x for v in numbers(e)]
        return [x] if isinstance(x, (int, float)) and not isinstance(x, bool) else []

    a, b = np.array(numbers(got["methods"])), np.array(numbers(want["methods"]))
    assert a.shape == b.shape and a.size > 10
    assert np.abs(a - b).max() <= 1e-6


def test_bad_input_raises_a_clear_error_and_the_display_still_works(display, image):
    cases = [
        (image.astype(np.float64), "float32"),
        (image[:, :, :2], "H×W×3"),
        (image[0], "H×W×3"),
        (np.full_like(image, np.nan), "NaN"),
        (image + 2.0, "in [0, 1]"),
        ([[0.5]], "float32"),
        (np.zeros((4, 4, 3), np.float32), "8×8"),
    ]
    for bad, needle in cases:
        with pytest.raises(nedrt.InputError, match=re.escape(needle)):
            display.perceived(bad, 1.0, method="doe+wiener")
    with pytest.raises(ValueError, match="unknown method"):
        display.perceived(image, 1.0, method="bogus")
    with pytest.raises(nedrt.InputError, match="prefilter"):
        display.prefilter(image, method="doe+wiener", prefilter="refine:0x")
    with pytest.raises(nedrt.InputError, match="does not exist"):
        nedrt.Display(design="no-such-design")
    with pytest.raises(nedrt.InputError, match="pupil"):
        nedrt.Display(eye="4cm")
    with pytest.raises(nedrt.NedrtError):
        nedrt.Display(calib="/no/such/calib.toml")
    with pytest.raises(nedrt.NedrtError, match="no-such-folder"):
        display.evaluate("/no-such-folder")
    # After every error the same display still answers.
    assert display.perceived(image, 1.0, method="doe-only").shape == (32, 48, 3)


def test_long_calls_release_the_gil(image):
    d = nedrt.Display(cache=False)
    ticks = []
    done = threading.Event()

    def tick():
        while not done.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.001)

    t = threading.Thread(target=tick)
    t.start()
    try:
        start = time.perf_counter()
        d.perceived(image, 1.0, method="doe+wiener")
        end = time.perf_counter()
    finally:
        done.set()
        t.join(timeout=30)
    during = [x for x in ticks if start < x < end]
    # A held GIL lets the other thread run only at the call's ends.
    assert end - start > 0.05 and len(during) >= 10, (end - start, len(during))
