"""Training mechanics on the smoke preset (tiny network, small aperture):
a step lowers the loss, runs are deterministic given the seed, resuming
equals training straight through, and DDP runs on two CPU processes (gloo)."""
import dataclasses
import os
import subprocess
import sys

import torch

from nedrt_train import calib as calib_mod
from nedrt_train.data import TrainingImages, dead_leaves, validation_images
from nedrt_train.train import PRESETS, System, train

SMOKE = PRESETS["smoke"]


def test_one_step_lowers_the_loss_on_a_fixed_batch():
    torch.manual_seed(0)
    system = System(SMOKE, calib_mod.load(SMOKE.calib))
    x = TrainingImages(32, seed=3).batch(2)
    blur = [(c.detach(), v.detach()) for c, v in system.optics.target_blur()]
    opt = torch.optim.Adam(system.parameters(), lr=1e-3)
    before, _ = system(x, 1.0, blur)
    opt.zero_grad()
    before.backward()
    opt.step()
    after, _ = system(x, 1.0, blur)
    assert after.item() < before.item()
    # Both the network and the DOE received gradients.
    assert system.optics.doe.logit.grad.abs().sum() > 0


def test_deterministic_given_seed_and_resume_equals_straight(tmp_path):
    cfg = dataclasses.replace(SMOKE, steps=2)
    train(cfg, tmp_path / "a")
    train(cfg, tmp_path / "b")
    a = torch.load(tmp_path / "a" / "checkpoint.pt", weights_only=False)["system"]
    b = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=False)["system"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    train(dataclasses.replace(cfg, steps=1), tmp_path / "c")
    train(cfg, tmp_path / "c", resume=True)
    c = torch.load(tmp_path / "c" / "checkpoint.pt", weights_only=False)["system"]
    assert all(torch.equal(a[k], c[k]) for k in a)


def test_data_is_in_range_and_validation_is_fixed():
    import numpy as np
    img = dead_leaves(np.random.default_rng(1), 48)
    assert img.shape == (48, 48, 3) and img.min() >= 0 and img.max() <= 1
    assert torch.equal(validation_images(32), validation_images(32))


def test_ddp_smoke_two_cpu_processes(tmp_path):
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(calib_mod.REPO / "models"))
    out = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
         "-m", "nedrt_train.train", "--preset", "smoke", "--device", "cpu", "--out", str(tmp_path / "ddp")],
        capture_output=True, text=True, env=env, timeout=300,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert (tmp_path / "ddp" / "checkpoint.pt").exists()
    assert (tmp_path / "ddp" / "result.json").exists()


def test_export_run_writes_onnx_doe_and_card(tmp_path):
    import json

    import numpy as np
    import onnxruntime as ort

    from nedrt_train.export import export_run
    train(dataclasses.replace(SMOKE, steps=1), tmp_path / "run")
    card = export_run(tmp_path / "run", tmp_path / "out", "smoke")
    # The command line, as a module (entry point after every definition).
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(calib_mod.REPO / "models"))
    cli = subprocess.run([sys.executable, "-m", "nedrt_train.export", "--run", str(tmp_path / "run"), "--name", "smoke",
                          "--out", str(tmp_path / "cli"), "--displays", str(tmp_path / "displays")],
                         capture_output=True, text=True, env=env, timeout=300)
    assert cli.returncode == 0, cli.stderr[-2000:]
    assert (tmp_path / "displays" / "astronaut.png").exists()
    assert set(card["files"]) == {"dcnn-smoke.onnx", "doe-smoke-design.safetensors", "doe-smoke-fabrication.safetensors"}
    assert json.loads((tmp_path / "out" / "card-smoke.json").read_text())["steps"] == 1
    sess = ort.InferenceSession(str(tmp_path / "out" / "dcnn-smoke.onnx"), providers=["CPUExecutionProvider"])
    y = sess.run(None, {"image": np.random.rand(1, 3, 16, 24).astype(np.float32)})[0]
    assert y.shape == (1, 3, 16, 24)


def test_displays_are_exact_16_bit_pngs_that_nedrt_evaluates(tmp_path):
    import numpy as np

    from nedrt_train.export import write_displays, write_png16
    from nedrt_train.unet import UNet
    rgb = np.random.default_rng(0).random((5, 7, 3))
    write_png16(tmp_path / "x.png", rgb)
    exe = calib_mod.REPO / "target" / "release" / "nedrt"
    net = UNet(width=4, levels=2)
    with torch.no_grad():  # identity network: display = input
        net.out.weight.zero_()
        net.out.bias.zero_()
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    from PIL import Image
    Image.fromarray((np.random.default_rng(1).random((16, 24, 3)) * 255).astype(np.uint8)).save(imgs / "a.png")
    write_displays(net, imgs, tmp_path / "displays")
    if not exe.exists():
        import pytest
        pytest.skip("nedrt not built")
    import json
    out = subprocess.run([str(exe), "--calib", str(calib_mod.REPO / "tests/data/small-aperture.toml"), "eval",
                          "--images", str(imgs), "--out-dir", str(tmp_path / "eval"), "--methods", "doe-only",
                          "--display-dir", str(tmp_path / "displays")], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    methods = json.loads((tmp_path / "eval" / "eval.json").read_text())["methods"]
    # The identity D-CNN's 16-bit display scores as the unprocessed input (to 16-bit rounding).
    for a, b in zip(methods[0]["rows"], methods[1]["rows"]):
        assert abs(a["vs_sharp"]["psnr_db"] - b["vs_sharp"]["psnr_db"]) < 1e-3
