"""The unrolled preprocessor's classical core (nedrt_train.unrolled, issue
55) on the golden problem (tests/golden/optimal.json, checked against
scipy's L-BFGS-B in test_optimal.py): its split-solver steps reach nedrt's
optimum, and the untrained model is the classical solver."""
import numpy as np
import pytest
import torch

from nedrt_train.objective import Objective
from nedrt_train.unrolled import Unrolled, main
from test_optimal import CHANNELS, GOLDEN, H, W, planes


def golden_objective() -> Objective:
    depths = len(GOLDEN["depths_d"])
    kernels = {k: np.asarray(v, dtype=np.float64).reshape((depths,) * k.endswith("_per_depth") + (CHANNELS, 2 * H, 2 * W))
               for k, v in GOLDEN["kernels"].items()}
    return Objective(kernels, depths)


def test_the_split_steps_reach_nedrts_optimum():
    objective = golden_objective()
    image = torch.from_numpy(planes(GOLDEN["input"])[None]).float()
    optimum = torch.from_numpy(planes(GOLDEN["optimum"])[None]).float()
    with torch.no_grad():
        steps = Unrolled(objective, 400, learned=False)(image, image)
    values = [objective(d, image).item() for d in steps]
    best = objective(optimum, image).item()
    assert values[0] < objective(image.clamp(0, 1), image).item()
    assert all(0.0 <= float(d.min()) and float(d.max()) <= 1.0 for d in steps)
    assert values[-1] == pytest.approx(best, rel=1e-3), (values[-1], best)


def test_the_untrained_model_is_the_classical_solver_and_learns():
    objective = golden_objective()
    image = torch.from_numpy(planes(GOLDEN["input"])[None]).float()
    learned, classical = Unrolled(objective, 3), Unrolled(objective, 3, learned=False)
    with torch.no_grad():
        for a, b in zip(learned(image, image), classical(image, image)):
            assert torch.equal(a, b)
    loss = sum(objective.mse(d, image).mean() for d in learned(image, image))
    loss.backward()
    assert all(c.last.weight.grad.abs().sum() > 0 for c in learned.corrections)
    assert learned.log_rho.grad.abs().sum() > 0


def test_bad_kernels_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="no kernel file"):
        main(["--kernels", str(tmp_path / "none.safetensors")])
