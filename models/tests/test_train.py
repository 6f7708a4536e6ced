"""Training mechanics on the smoke preset (tiny network, small aperture):
a step lowers the loss, runs are deterministic given the seed, resuming
equals training straight through, DDP runs on two CPU processes (gloo), and
a resumed DDP run gives each rank its own random state back."""
import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from nedrt_train import calib as calib_mod
from nedrt_train.data import TrainingImages, dead_leaves, validation_images
from nedrt_train.train import PRESETS, System, train

REPO = Path(__file__).resolve().parents[2]
SMALL = str(REPO / "tests" / "data" / "small-aperture.toml")
IMAGES = REPO / "data" / "images"
SMOKE = dataclasses.replace(PRESETS["smoke"], calib=SMALL, images=str(IMAGES))


def test_one_step_lowers_the_loss_on_a_fixed_batch():
    torch.manual_seed(0)
    system = System(SMOKE, calib_mod.load(SMOKE.calib))
    x = TrainingImages(32, 3, IMAGES / "train").batch(2)
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


def test_resume_from_a_checkpoint_without_per_rank_state(tmp_path):
    # Checkpoints written before per-rank random state (rank 0's generators
    # for every rank) still resume, and equal training straight through.
    cfg = dataclasses.replace(SMOKE, steps=2)
    train(cfg, tmp_path / "a")
    train(dataclasses.replace(cfg, steps=1), tmp_path / "old")
    ckpt = tmp_path / "old" / "checkpoint.pt"
    state = torch.load(ckpt, weights_only=False)
    mine = state.pop("rank_rng")[0]
    depth, data = np.random.default_rng(), np.random.default_rng()
    depth.bit_generator.state, data.bit_generator.state = mine["depth"], mine["data"]
    state.update(rng=[depth], data_rng=[data], torch_rng=mine["torch"])
    torch.save(state, ckpt)
    train(cfg, tmp_path / "old", resume=True)
    a = torch.load(tmp_path / "a" / "checkpoint.pt", weights_only=False)["system"]
    b = torch.load(ckpt, weights_only=False)["system"]
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_ddp_resume_gives_each_rank_its_own_random_state(tmp_path):
    # Two gloo processes: 4 steps straight through, and 2 steps + resume to 4
    # (models/tests/ddp_draws.py records every draw of each rank).
    env = dict(os.environ, OMP_NUM_THREADS="1")
    out = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
         str(Path(__file__).with_name("ddp_draws.py")), "--out", str(tmp_path), "--calib", SMALL,
         "--images", str(IMAGES), "--steps", "4", "--split", "2"],
        capture_output=True, text=True, env=env, timeout=300,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    draws = [torch.load(tmp_path / f"draws-rank{r}.pt", weights_only=False) for r in (0, 1)]
    for rank, d in enumerate(draws):
        assert sorted(d["straight"]) == [0, 1, 2, 3] and sorted(d["first"]) == [0, 1]
        assert sorted(d["resumed"]) == [2, 3], rank
        # (b) after the resume each rank draws what the uninterrupted run drew.
        for part in ("first", "resumed"):
            for step, (depth, batch) in d[part].items():
                assert depth == d["straight"][step][0], (rank, part, step)
                assert torch.equal(batch, d["straight"][step][1]), (rank, part, step)
    # (a) the two ranks draw different depths and batches after the resume
    # (before the fix every rank got rank 0's generators back).
    assert [draws[0]["resumed"][s][0] for s in (2, 3)] != [draws[1]["resumed"][s][0] for s in (2, 3)]
    for step in (2, 3):
        assert not torch.equal(draws[0]["resumed"][step][1], draws[1]["resumed"][step][1]), step
    # And so the resumed run ends with the uninterrupted run's weights.
    a = torch.load(tmp_path / "straight" / "checkpoint.pt", weights_only=False)
    b = torch.load(tmp_path / "resumed" / "checkpoint.pt", weights_only=False)
    assert a["step"] == b["step"] == 4 and len(b["rank_rng"]) == 2
    assert all(torch.equal(a["system"][k], b["system"][k]) for k in a["system"])


def test_data_is_in_range_and_validation_is_fixed():
    import numpy as np
    img = dead_leaves(np.random.default_rng(1), 48)
    assert img.shape == (48, 48, 3) and img.min() >= 0 and img.max() <= 1
    assert torch.equal(validation_images(32, IMAGES / "val"), validation_images(32, IMAGES / "val"))


def test_ddp_smoke_two_cpu_processes(tmp_path):
    # From the repository root, the calibration relative to it; the images by default (data/images).
    env = dict(os.environ, OMP_NUM_THREADS="1")
    out = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
         "-m", "nedrt_train.train", "--preset", "smoke", "--calib", "tests/data/small-aperture.toml",
         "--device", "cpu", "--out", str(tmp_path / "ddp")],
        capture_output=True, text=True, env=env, timeout=300, cwd=REPO,
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
    # The command line, as a module (entry point after every definition), from
    # another directory: the calibration is the run's, the images named.
    env = dict(os.environ, OMP_NUM_THREADS="1")
    cli = subprocess.run([sys.executable, "-m", "nedrt_train.export", "--run", str(tmp_path / "run"), "--name", "smoke",
                          "--out", str(tmp_path / "cli"), "--displays", str(tmp_path / "displays"),
                          "--images", str(IMAGES)],
                         capture_output=True, text=True, env=env, timeout=300, cwd=tmp_path)
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
    exe = REPO / "target" / "release" / "nedrt"
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
    out = subprocess.run([str(exe), "--calib", str(REPO / "tests/data/small-aperture.toml"), "eval",
                          "--images", str(imgs), "--out-dir", str(tmp_path / "eval"), "--methods", "doe-only",
                          "--display-dir", str(tmp_path / "displays")], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    methods = json.loads((tmp_path / "eval" / "eval.json").read_text())["methods"]
    # The identity D-CNN's 16-bit display scores as the unprocessed input (to 16-bit rounding).
    for a, b in zip(methods[0]["rows"], methods[1]["rows"]):
        assert abs(a["vs_sharp"]["psnr_db"] - b["vs_sharp"]["psnr_db"]) < 1e-3
