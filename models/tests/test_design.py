"""The DOE design stage: its frequency-domain error equals a direct
simulation of the clamped display, its display-grid transfer is nedrt's
display kernel, runs resume exactly, and a resume with another calibration
or target is refused."""
import dataclasses
import math
import shutil
from pathlib import Path

import pytest
import torch

from nedrt_train import calib as calib_mod
from nedrt_train.design import (DesignConfig, DesignModel, design, display_kernel, training_crops,
                                wiener_display, wiener_gain)
from nedrt_train.optics import perceive, target, up2

REPO = Path(__file__).resolve().parents[2]
SMALL_PATH = str(REPO / "tests" / "data" / "small-aperture.toml")
TRAIN = REPO / "data" / "images" / "train"
TINY = DesignConfig(target="allsharp", window=9, frequencies=32, crops=2, steps=3, checkpoint_every=1, calib=SMALL_PATH,
                    spectrum_alpha=2.0)


def tiny_model(target="allsharp"):
    cfg = dataclasses.replace(TINY, target=target)
    crops = training_crops(TRAIN, cfg.crops, cfg.frequencies // 2, cfg.seed)
    return DesignModel(cfg, calib_mod.load(SMALL_PATH), 2.0, crops=crops), crops


@pytest.mark.parametrize("kind", ["allsharp", "multifocal"])
def test_parseval_error_equals_the_simulated_clamped_display(kind):
    model, crops = tiny_model(kind)
    calib, optics = model.calib, model.optics
    with torch.no_grad():
        errors = model.clamped_errors()
        k_reg = float(model.log_k.exp())
        sweep = [optics.psfs(ch, [calib.psi_rad(ch, d) for d in model.sweep_d]) for ch in range(3)]
        mean_psfs = [(c.mean(0), float(v.mean())) for c, v in sweep]
        blur = optics.target_blur()
        for i, d in enumerate(model.design_d):
            mse = 0.0
            for crop in crops:
                _, h, w = crop.shape
                gains = [wiener_gain(display_kernel(c), v, k_reg, h, w) for c, v in mean_psfs]
                display = wiener_display(crop, gains)
                goal = target(crop, calib, d, blur) if kind == "multifocal" else up2(crop)
                mse += float(((perceive(display, optics.system(d)) - goal) ** 2).mean())
            mse /= len(crops)
            assert errors[i].item() == pytest.approx(mse, rel=1e-6), d


def test_display_transfer_is_the_transform_of_nedrts_display_kernel():
    model, _ = tiny_model()
    cells, veil = model.optics.psf(1, 3.0, with_doe=True)
    h = model._spectrum(cells[None], veil[None])[0]
    k = model.display_transfer(h)
    md = model.cfg.frequencies
    kernel = display_kernel(cells)
    side = kernel.shape[-1]
    grid = torch.zeros(md, md, dtype=kernel.dtype)
    grid[:side, :side] = kernel
    grid = torch.roll(grid, (-(side // 2), -(side // 2)), (0, 1))
    direct = torch.fft.fft2(grid).real
    direct[0, 0] += veil
    assert torch.allclose(k, direct, atol=1e-12)


def test_resume_equals_straight_through_and_refuses_another_target_or_calibration(tmp_path):
    design(TINY, tmp_path / "a", tune=False, images_dir=TRAIN)
    design(dataclasses.replace(TINY, steps=1), tmp_path / "b", tune=False, images_dir=TRAIN)
    design(TINY, tmp_path / "b", resume=True, tune=False, images_dir=TRAIN)
    a = torch.load(tmp_path / "a" / "checkpoint.pt", weights_only=False)["model"]
    b = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=False)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(ValueError, match="target = 'allsharp'"):
        design(dataclasses.replace(TINY, target="multifocal"), tmp_path / "a", resume=True, tune=False, images_dir=TRAIN)
    other = tmp_path / "other.toml"
    shutil.copy(SMALL_PATH, other)
    other.write_text(other.read_text().replace("aperture_radius_mm = 1.5", "aperture_radius_mm = 1.4"))
    with pytest.raises(ValueError, match="calib_sha"):
        design(dataclasses.replace(TINY, calib=str(other)), tmp_path / "a", resume=True, tune=False, images_dir=TRAIN)
    # A fresh run never overwrites a checkpoint silently.
    with pytest.raises(ValueError, match="--resume"):
        design(TINY, tmp_path / "a", tune=False, images_dir=TRAIN)


def test_a_design_step_improves_the_objective():
    model, _ = tiny_model("multifocal")
    opt = torch.optim.Adam(model.parameters(), lr=0.05)
    before, _ = model.objective()
    for _ in range(3):
        loss, _ = model.objective()
        opt.zero_grad()
        loss.backward()
        opt.step()
    after, _ = model.objective()
    assert after.item() < before.item()
    assert math.isfinite(after.item())


def test_a_pupil_range_is_one_design_whose_objective_is_the_mean_over_its_pupils():
    # docs/model.md §4a: the small calibration's 3 mm aperture, pupils of
    # 1.5 and 2.5 mm: one DOE (shared parameters), the objective the mean of
    # the single-pupil objectives, the target's blur through each pupil.
    cal = calib_mod.load(SMALL_PATH)
    crops = training_crops(TRAIN, TINY.crops, TINY.frequencies // 2, TINY.seed)
    both = DesignModel(dataclasses.replace(TINY, target="multifocal", pupils_mm=(1.5, 2.5)), cal, 2.0, crops=crops)
    singles = [DesignModel(dataclasses.replace(TINY, target="multifocal", pupils_mm=(p,)), cal, 2.0, crops=crops)
               for p in (1.5, 2.5)]
    assert len(list(both.parameters())) == 2  # the DOE's heights and log κ, once each
    assert both.other_pupils[0].doe is both.optics.doe
    with torch.no_grad():
        mean = torch.stack([m.clamped_errors() for m in singles]).mean(0)
        assert torch.allclose(both.clamped_errors(), mean, rtol=1e-12)
        assert not torch.allclose(singles[0].clamped_errors(), singles[1].clamped_errors())
        assert not torch.allclose(both.pupil_blur(0), both.pupil_blur(1))
    loss, _ = both.objective()
    loss.backward()
    assert torch.isfinite(both.optics.doe.logit.grad).all()
