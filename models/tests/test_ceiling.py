"""`nedrt-train ceiling` (nedrt_train/ceiling.py): its per-depth errors are
the trainer's (and so the evaluation's), and its L-BFGS-B optimum is no
worse than an independent projected-gradient solution of the same problem
and no worse than where it started."""
import shutil

import pytest

import torch

from nedrt_train import ceiling, distill
from test_distill import VAL, write_teacher


def setup(tmp_path):
    images, teacher = write_teacher(tmp_path)
    (teacher / "train-sharp").mkdir()
    kernels = f"operator-{VAL}x{VAL}.safetensors"
    shutil.copyfile(teacher / "train" / kernels, teacher / "train-sharp" / kernels)
    return images, teacher, distill.Objective.load(teacher / "train" / kernels)


def test_depth_errors_are_the_trainers(tmp_path):
    _, _, objective = setup(tmp_path)
    gen = torch.Generator().manual_seed(1)
    image, display = torch.rand(3, VAL, VAL, generator=gen), torch.rand(3, VAL, VAL, generator=gen)
    errors = ceiling.DepthErrors(objective, image)(torch.fft.rfft2(distill.Objective.mirror(display.double())))
    expected = objective.depth_mse(display[None], image[None])[0].double()
    assert errors.shape == expected.shape == (2,)
    assert torch.allclose(errors, expected, rtol=1e-4), (errors, expected)


def test_depth_errors_live_on_the_device_asked_for(tmp_path):
    """--device: the errors' spectra and the photograph's go to the device
    (meta here), and an evaluation there stays there; the solver's iterate
    alone crosses to the CPU (scipy)."""
    _, _, objective = setup(tmp_path)
    image = torch.rand(3, VAL, VAL)
    errors = ceiling.DepthErrors(objective, image, "meta")
    held = [v for v in vars(errors).values() if isinstance(v, torch.Tensor)]
    assert held and {t.device.type for t in held} == {"meta"}
    d_hat = torch.fft.rfft2(distill.Objective.mirror(torch.rand(3, VAL, VAL, device="meta", dtype=torch.float64)))
    assert errors(d_hat).device.type == "meta"


def test_the_ceiling_beats_projected_adam_and_its_start(tmp_path):
    images, teacher, objective = setup(tmp_path)
    image = torch.rand(3, VAL, VAL, generator=torch.Generator().manual_seed(2))
    errors = ceiling.DepthErrors(objective, image)
    start = torch.full_like(image, 0.5)

    def loss(d):
        return -ceiling.psnr(errors(torch.fft.rfft2(distill.Objective.mirror(d.double())))).mean()

    best, _, value = ceiling.solve(start, errors, errors, 0.0, 200)
    assert float(best.min()) >= 0 and float(best.max()) <= 1
    assert value == float(loss(best)) or abs(value - float(loss(best))) < 1e-3
    assert value < float(loss(start)) - 1.0
    # An independent solver: projected Adam from another start.
    d = torch.rand(3, VAL, VAL, generator=torch.Generator().manual_seed(3)).requires_grad_(True)
    opt = torch.optim.Adam([d], lr=0.01)
    for _ in range(1500):
        opt.zero_grad()
        loss(d).backward()
        opt.step()
        with torch.no_grad():
            d.clamp_(0, 1)
    assert value <= float(loss(d.detach())) + 0.02, (value, float(loss(d.detach())))


def test_the_command_reports_every_row(tmp_path, capsys):
    images, teacher, _ = setup(tmp_path)
    out = tmp_path / "ceiling.json"
    ceiling.main(["--teacher", str(teacher), "--images", str(images), "--sharp-weight", "0,1",
                  "--iterations", "20", "--out", str(out)])
    import json
    result = json.loads(out.read_text())
    assert list(result["rows"]) == ["wiener", "optimal@target", "ceiling w=0", "ceiling w=1"]
    rows = result["rows"]
    assert rows["ceiling w=0"]["vs_target"]["mean_db"] >= rows["optimal@target"]["vs_target"]["mean_db"]
    assert "| ceiling w=1 |" in capsys.readouterr().out


def test_bad_input_is_refused_by_name(tmp_path):
    images, teacher, _ = setup(tmp_path)
    with pytest.raises(SystemExit, match="--sharp-weight"):
        ceiling.main(["--teacher", str(teacher), "--images", str(images), "--sharp-weight", "-1"])
    with pytest.raises(SystemExit, match="--sharp-weight 'x'"):
        ceiling.main(["--teacher", str(teacher), "--images", str(images), "--sharp-weight", "x"])
    with pytest.raises(SystemExit, match="train-sharp.*no kernel file"):
        shutil.rmtree(teacher / "train-sharp")
        ceiling.main(["--teacher", str(teacher), "--images", str(images)])


def test_the_training_split_ceiling_is_a_teacher_for_distillation(tmp_path):
    """--split train --write DIR: the display images of every training
    photograph in [0, 1], in a folder `nedrt-train dcnn --teacher-set` reads."""
    import json

    from safetensors.torch import load_file, save_file

    from test_distill import DEPTHS, config, kernels
    images, teacher, _ = setup(tmp_path)
    meta = {"format": "nedrt objective kernels 1", "depths_d": json.dumps(list(range(DEPTHS))),
            "width": "32", "height": "32"}
    for folder in ("train", "train-sharp"):
        save_file(kernels(32), str(teacher / folder / "operator-32x32.safetensors"), metadata=meta)
    with pytest.raises(SystemExit, match="exactly one"):
        ceiling.main(["--teacher", str(teacher), "--images", str(images), "--split", "train",
                      "--sharp-weight", "0,1", "--write", str(teacher / "train-ceiling")])
    assert not (teacher / "train-ceiling").exists()
    ceiling.main(["--teacher", str(teacher), "--images", str(images), "--split", "train",
                  "--sharp-weight", "1", "--iterations", "5", "--write", str(teacher / "train-ceiling")])
    displays = load_file(str(teacher / "train-ceiling" / "displays.safetensors"))
    assert sorted(displays) == ["p0", "p1", "p2"]
    for d in displays.values():
        assert d.shape == (3, 32, 32) and float(d.min()) >= 0 and float(d.max()) <= 1
    assert json.loads((teacher / "train-ceiling" / "prefilter.json").read_text())["sharp_weight"] == 1
    result = distill.train(config(images, teacher, 1, teacher_set="train-ceiling"), tmp_path / "run")
    assert result["teacher"]["train"]["prefilter"] == "ceiling w=1"


def test_shards_together_are_the_whole_teacher(tmp_path):
    """--shard 1/2 and 2/2 split the photographs; the teacher they leave is
    the unsharded one, photograph for photograph."""
    images, teacher, _ = setup(tmp_path)
    args = ["--teacher", str(teacher), "--images", str(images), "--sharp-weight", "1", "--iterations", "5"]
    ceiling.main(args + ["--write", str(tmp_path / "whole")])
    for k in (1, 2):
        ceiling.main(args + ["--shard", f"{k}/2", "--write", str(tmp_path / "shared")])
    names = distill.photo_names(images / "val")
    assert len(names) >= 2
    whole = distill.load_teacher(tmp_path / "whole", names)
    shared = distill.load_teacher(tmp_path / "shared", names)
    assert not (tmp_path / "shared" / "displays.safetensors").exists()
    for name in names:
        assert torch.equal(whole[name], shared[name]), name
    for bad in ("0/2", "3/2", "x", "1/0"):
        with pytest.raises(SystemExit, match="--shard"):
            ceiling.main(args + ["--shard", bad])
