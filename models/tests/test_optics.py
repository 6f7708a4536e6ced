"""The differentiable model against the Rust simulator's golden vectors
(PSFs to 1e-5 relative, perceived images ≥ 60 dB), its gradients against
finite differences, and the convolution against a direct sum."""
import dataclasses
import json
import math
from pathlib import Path

import pytest
import torch

from nedrt_train import calib as calib_mod
from nedrt_train.optics import PsfModel, convolve, grid, perceive, symmetric_index, three_lens_init, up2

REPO = Path(__file__).resolve().parents[2]
VECTORS = json.loads((REPO / "tests/golden/vectors.json").read_text())
CAL = calib_mod.load(REPO / "calib" / "default.toml")


@pytest.fixture(scope="module")
def model():
    return PsfModel(CAL, CAL.doe_design_pitch_m, window=31)


def test_doe_initialisation_matches_the_golden_probe():
    s = grid(CAL, CAL.doe_design_pitch_m)
    h = three_lens_init(CAL, s)
    assert len(s) == VECTORS["doe"]["samples"]
    for i, j, height in VECTORS["doe"]["probe_row_col_height_m"]:
        assert abs(h[i, j].item() - height) < 1e-15


def test_sigmoid_parameterisation_keeps_heights_in_range(model):
    h = model.doe()
    assert h.min() >= 0 and h.max() <= CAL.doe_max_height_m
    # The initial profile is reproduced to the clamp of the logit (1e-4 of max).
    s = grid(CAL, CAL.doe_design_pitch_m)
    assert (h - three_lens_init(CAL, s)).abs().max() < 1e-4 * CAL.doe_max_height_m + 1e-12


RADIAL = json.loads((REPO / "tests/golden/radial.json").read_text())


@pytest.mark.parametrize("entry", RADIAL["psfs"], ids=lambda e: f'{e["optics"]}-{e["channel"]}-{e["accommodation_d"]}')
def test_psfs_match_the_rust_simulator(entry):
    # nedrt's 2-D exact path at ≈ 3 µm on the three-lens radial DOE
    # (tests/golden/radial.json, examples/make_radial_golden.rs) against the
    # trainer's radial model at its training quadrature (3 µm): the cells to
    # 0.5 % of the peak, the veil to 1e-3. (The midpoint sums of
    # vectors.json are no longer a model of either side.)
    from nedrt_train.radial import RadialPsfModel
    names = [c.name for c in CAL.channels]
    ch = names.index(entry["channel"])
    doe = RADIAL["doe"]
    assert doe["pitch_m"] == CAL.doe_design_pitch_m
    m = RadialPsfModel(CAL, doe["pitch_m"], RADIAL["window"])
    with torch.no_grad():
        cells, veil = m.psf(ch, entry["psi_rad"], with_doe=entry["optics"] == "lens+doe",
                            height_m=torch.tensor(doe["height_m"], dtype=torch.float64))
    theirs = torch.tensor(entry["two_d"]["cells"], dtype=torch.float64).reshape(cells.shape)
    assert (cells - theirs).abs().max() <= 5e-3 * theirs.max()
    assert abs(veil.item() - entry["two_d"]["veil"]) < 1e-3


def test_perceived_image_matches_the_rust_simulator(model):
    p = VECTORS["perceived"]
    n = p["width"]
    x = torch.tensor(p["input"], dtype=torch.float64).reshape(3, n, n)
    with torch.no_grad():
        system = model.system(p["accommodation_d"])
        blur = model.target_blur()
        for key, psfs in [("perceived", system), ("target", blur)]:
            mine = perceive(x, psfs)
            theirs = torch.tensor(p[key], dtype=torch.float64).reshape(mine.shape)
            psnr = 10 * math.log10(1 / ((mine - theirs) ** 2).mean().item())
            assert psnr >= 60, f"{key}: {psnr:.1f} dB"


def test_convolution_is_convolution_not_correlation():
    torch.manual_seed(0)
    x = torch.rand(7, 9, dtype=torch.float64)
    k = torch.rand(5, 5, dtype=torch.float64)  # asymmetric
    got = convolve(x, k)
    a = 2
    iy = symmetric_index(7 + 2 * a, a, 7)
    ix = symmetric_index(9 + 2 * a, a, 9)
    padded = x[iy][:, ix]
    want = torch.zeros_like(x)
    for dy in range(-a, a + 1):
        for dx in range(-a, a + 1):
            want += k[dy + a, dx + a] * padded[a - dy:a - dy + 7, a - dx:a - dx + 9]
    assert torch.allclose(got, want, atol=1e-12)
    # A kernel wider than the frame mirrors repeatedly.
    assert convolve(x, torch.rand(21, 21, dtype=torch.float64)).shape == x.shape


def test_up2():
    x = torch.tensor([[1.0, 2.0]])
    assert up2(x).tolist() == [[1, 1, 2, 2], [1, 1, 2, 2]]


def test_gradients_of_the_optics_match_finite_differences():
    # A small aperture and window so that gradcheck (float64) stays quick;
    # the whole chain: sigmoid → DOE phase → MFT → cells → perceived image.
    small = dataclasses.replace(CAL, aperture_radius_m=60e-6)
    m = PsfModel(small, 10e-6, window=5)
    x = torch.rand(1, 3, 6, 6, dtype=torch.float64)

    def perceived(logit):
        height = small.doe_max_height_m * torch.sigmoid(logit)
        psfs = [m.psf(ch, small.psi_rad(ch, 1.0), height_m=height) for ch in range(3)]
        return perceive(x, psfs)

    logit = m.doe.logit.detach().clone().requires_grad_(True)
    assert torch.autograd.gradcheck(perceived, (logit,), eps=1e-6, atol=1e-7, rtol=1e-4)
