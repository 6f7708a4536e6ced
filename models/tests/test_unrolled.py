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


def _golden_script():
    import importlib.util
    from test_optimal import REPO
    spec = importlib.util.spec_from_file_location("make_unrolled_golden", REPO / "tools/golden/make_unrolled_golden.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module, REPO


def test_the_committed_unrolled_golden_is_the_scripts(tmp_path):
    import json
    script, repo = _golden_script()
    script.main(tmp_path)
    committed = json.loads((repo / "tests/golden/unrolled/io.json").read_text())
    made = json.loads((tmp_path / "io.json").read_text())
    assert len(made["steps"]) == len(committed["steps"]) == 3
    for a, b in zip(made["steps"], committed["steps"]):
        assert np.abs(np.asarray(a) - np.asarray(b)).max() <= 1e-6
    ours = (tmp_path / "golden.unrolled.toml").read_text()
    theirs = (repo / "tests/golden/unrolled/golden.unrolled.toml").read_text()
    strip = lambda t: [l for l in t.splitlines() if not l.startswith("network_sha256")]
    assert strip(ours) == strip(theirs)


def test_each_exported_step_is_its_correction_on_onnx_runtime(tmp_path):
    import onnxruntime as ort
    import tomllib
    script, repo = _golden_script()
    model = script.golden_model(GOLDEN)
    script.main(tmp_path)
    steps = tomllib.loads((tmp_path / "golden.unrolled.toml").read_text())["step"]
    assert [("network" in s) for s in steps] == list(script.WITH_NETWORK)
    rng = np.random.default_rng(0)
    planes = rng.uniform(-1, 1, (1, 9, 13, 21)).astype(np.float32)
    for k, s in enumerate(steps):
        if "network" not in s:
            continue
        session = ort.InferenceSession(str(tmp_path / s["network"]))
        meta = session.get_modelmeta().custom_metadata_map
        assert meta.get("nedrt.output") == "correction"
        got = session.run(None, {"planes": planes})[0]
        with torch.no_grad():
            want = model.corrections[k].planes(torch.from_numpy(planes)).numpy()
        assert np.abs(got - want).max() <= 1e-5
        assert (got < 0).any(), "a correction is signed"


def test_a_classical_step_with_a_correction_is_refused(tmp_path):
    from nedrt_train.unrolled_export import export
    script, repo = _golden_script()
    model = script.golden_model(GOLDEN)
    with pytest.raises(ValueError, match="not zero"):
        export(model, repo / "tests/golden/optimal.json", tmp_path, "bad", classical=[True, False, False])
