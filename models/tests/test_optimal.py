"""nedrt's bounded least-squares display image (`--prefilter optimal`,
runtime/optics/src/sim/optimal.rs) against an independent solver: the
problem of tests/golden/optimal.json (examples/make_optimal_golden.rs: the
multifocal design's PSFs cut to 21 cells, a 24×16 crop of a training
photograph) rebuilt here with numpy's symmetric padding and scipy's
convolutions, and solved with scipy's L-BFGS-B from a flat start."""
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.signal import fftconvolve

REPO = Path(__file__).resolve().parents[2]
GOLDEN = json.loads((REPO / "tests/golden/optimal.json").read_text())
W, H = GOLDEN["width"], GOLDEN["height"]
CHANNELS = len(GOLDEN["psfs"])


def planes(flat):
    return np.asarray(flat, dtype=np.float64).reshape(CHANNELS, H, W)


def kernel(psf):
    n = psf["window"]
    return np.asarray(psf["cells"], dtype=np.float64).reshape(n, n), psf["veil"]


def up2(x):
    return np.repeat(np.repeat(x, 2, axis=0), 2, axis=1)


def blur(retinal, psf):
    """crop(x ∗ h): the retinal image extended symmetrically by the PSF's
    half-window, convolved, cropped back."""
    k, _ = kernel(psf)
    a = k.shape[0] // 2
    return fftconvolve(np.pad(retinal, a, mode="symmetric"), k, mode="valid")


def blur_adjoint(residual, psf):
    """Adjoint of `blur`: correlate onto the padded grid, fold the padding back."""
    k, _ = kernel(psf)
    a = k.shape[0] // 2
    padded = fftconvolve(residual, k[::-1, ::-1], mode="full")
    h2, w2 = residual.shape
    ys = symmetric(np.arange(h2 + 2 * a) - a, h2)
    xs = symmetric(np.arange(w2 + 2 * a) - a, w2)
    out = np.zeros_like(residual)
    np.add.at(out, (ys[:, None], xs[None, :]), padded)
    return out


def symmetric(i, n):
    k = np.mod(i, 2 * n)
    return np.where(k < n, k, 2 * n - 1 - k)


def perceived(d, psf):
    return blur(up2(d), psf) + psf["veil"] * d.mean()


def targets(image, c):
    sharp = up2(image)
    blurred = blur(sharp, GOLDEN["blur"][c]) + GOLDEN["blur"][c]["veil"] * image.mean()
    return [blurred if b else sharp for b in GOLDEN["blurred"]]


def objective(d, image, c):
    """½ Σ_D ‖A_D d − t_D‖² and its gradient."""
    value, grad = 0.0, np.zeros_like(d)
    for psf, t in zip(GOLDEN["psfs"][c], targets(image, c)):
        r = perceived(d, psf) - t
        value += 0.5 * np.sum(r * r)
        g = blur_adjoint(r, psf)
        grad += g.reshape(H, 2, W, 2).sum(axis=(1, 3)) + psf["veil"] * r.sum() / d.size
    return value, grad


def psnr_per_depth(display, image):
    """PSNR of the perceived image against its target, over all channels, per depth."""
    out = []
    for di in range(len(GOLDEN["depths_d"])):
        err = np.mean([np.mean((perceived(display[c], GOLDEN["psfs"][c][di]) - targets(image[c], c)[di]) ** 2)
                       for c in range(CHANNELS)])
        out.append(10 * np.log10(1.0 / err))
    return np.array(out)


@pytest.fixture(scope="module")
def solved():
    image = planes(GOLDEN["input"])
    ours = planes(GOLDEN["optimum"])
    theirs = np.empty_like(ours)
    for c in range(CHANNELS):
        res = minimize(lambda x: (lambda v, g: (v, g.ravel()))(*objective(x.reshape(H, W), image[c], c)),
                       np.full(H * W, 0.5), jac=True, method="L-BFGS-B", bounds=[(0.0, 1.0)] * (H * W),
                       options={"maxiter": 20000, "maxfun": 40000, "ftol": 1e-15, "gtol": 1e-12})
        theirs[c] = res.x.reshape(H, W)
    return image, ours, theirs


def test_the_objective_is_the_same_operator():
    """nedrt's objective value at its optimum, recomputed here."""
    image, ours = planes(GOLDEN["input"]), planes(GOLDEN["optimum"])
    for c in range(CHANNELS):
        value, _ = objective(ours[c], image[c], c)
        assert value == pytest.approx(GOLDEN["objective_value"][c], rel=1e-4)


def test_the_gradient_is_the_objectives():
    image = planes(GOLDEN["input"])
    rng = np.random.default_rng(1)
    d = rng.uniform(0.2, 0.8, (H, W))
    step = rng.normal(size=(H, W))
    _, g = objective(d, image[1], 1)
    eps = 1e-5
    numeric = (objective(d + eps * step, image[1], 1)[0] - objective(d - eps * step, image[1], 1)[0]) / (2 * eps)
    assert numeric == pytest.approx(np.sum(g * step), rel=1e-6)


def test_nedrts_optimum_matches_lbfgsb_to_five_hundredths_of_a_db(solved):
    image, ours, theirs = solved
    assert ours.min() >= 0.0 and ours.max() <= 1.0
    for c in range(CHANNELS):
        mine, ref = objective(ours[c], image[c], c)[0], objective(theirs[c], image[c], c)[0]
        # nedrt's optimum is at least as good as L-BFGS-B's, to 0.1 %.
        assert mine <= ref * 1.001, (c, mine, ref)
    ours_db, theirs_db = psnr_per_depth(ours, image), psnr_per_depth(theirs, image)
    assert abs(ours_db.mean() - theirs_db.mean()) <= 0.05, (ours_db, theirs_db)
    # And the clamp is active: the problem is not an unbounded one in disguise.
    assert np.mean((theirs <= 1e-9) | (theirs >= 1 - 1e-9)) > 0.01


def test_the_trainers_loss_is_this_objective():
    """nedrt_train.distill.Objective on nedrt's kernels of the golden problem
    (`kernels`, what `nedrt prefilter --operator` writes) against the direct
    sums above, at the optimum and at an arbitrary display image."""
    import torch

    from nedrt_train.distill import Objective
    depths = len(GOLDEN["depths_d"])
    kernels = {k: np.asarray(v, dtype=np.float64).reshape((depths,) * k.endswith("_per_depth") + (CHANNELS, 2 * H, 2 * W))
               for k, v in GOLDEN["kernels"].items()}
    loss = Objective(kernels, depths)
    image = planes(GOLDEN["input"])
    rng = np.random.default_rng(3)
    for display in (planes(GOLDEN["optimum"]), rng.uniform(0, 1, (CHANNELS, H, W))):
        direct = sum(objective(display[c], image[c], c)[0] for c in range(CHANNELS))
        d, i = torch.from_numpy(display[None]).float(), torch.from_numpy(image[None]).float()
        assert loss(d, i).item() == pytest.approx(direct, rel=2e-4)
        # Per depth: the evaluation's PSNR of that depth (over all channels).
        theirs = psnr_per_depth(display, image)
        ours = (-10 * torch.log10(loss.depth_mse(d, i)))[0].numpy()
        assert np.abs(ours - theirs).max() < 1e-3, (ours, theirs)
