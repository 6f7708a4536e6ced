"""The D-CNN stage's carried checkpoint (nedrt_train/distill_checkpoint.py,
issue 41) on test_distill.py's tiny synthetic teacher, one thread: a run
stopped at step k, carried and continued ends bit for bit where an
uninterrupted run ends (weights, Adam's moments, random state, validation);
a checkpoint made under another identity (calibration, design, objective,
width, step version) is refused naming the field and both values, or with
--fresh-if-refused starts afresh and says why; a tampered tensors file is
refused by its hash; the folder is written atomically; the moments travel
at the precision the budget allows, and without them Adam restarts with a
new warm-up; --init and export take a carried checkpoint."""
import json
from pathlib import Path

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from nedrt_train import distill
from nedrt_train import distill_checkpoint as carried
from nedrt_train.unet import UNet
from test_distill import PATCH, config, write_teacher

REPO = Path(__file__).resolve().parents[2]
CALIB = REPO / "calib" / "default.toml"


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def carry(**kw) -> carried.Carry:
    return carried.Carry(**{"calib": CALIB, **kw})


def net_of(run: Path) -> dict:
    return torch.load(run / "checkpoint.pt", weights_only=True)["net"]


def card_of(folder: Path) -> dict:
    return json.loads((folder / "card.json").read_text())


def name_in_kernels(teacher: Path, **meta):
    """Adds `meta` to the patch kernels' metadata (as nedrt prefilter writes
    the calibration and the DOE there)."""
    path = teacher / "train" / f"operator-{PATCH}x{PATCH}.safetensors"
    with safe_open(str(path), framework="pt") as f:
        old = f.metadata()
    save_file(load_file(str(path)), str(path), metadata={**old, **meta})


@pytest.mark.parametrize("loss", ["mse", "psnr"])
def test_a_carried_checkpoint_continues_exactly(tmp_path, loss):
    images, teacher = write_teacher(tmp_path)
    cfg = config(images, teacher, 4, loss=loss, validate_every=1)
    straight = distill.train(cfg, tmp_path / "straight", carry=carry(target=tmp_path / "straight-carried"))
    distill.train(cfg, tmp_path / "first", stop_after=2, carry=carry(target=tmp_path / "carried"))
    assert card_of(tmp_path / "carried")["step"] == 2
    # Another machine: a fresh run folder, the carried folder only.
    resumed = distill.train(cfg, tmp_path / "second", carry=carry(source=tmp_path / "carried",
                                                                    target=tmp_path / "carried"))
    a, b = net_of(tmp_path / "straight"), net_of(tmp_path / "second")
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k
    assert resumed["validation"] == straight["validation"]
    assert [v["step"] for v in resumed["validation"]] == [1, 2, 3, 4]
    # Weights, Adam's moments (f32 at this size) and torch's random state: the same bytes.
    ours, theirs = card_of(tmp_path / "carried"), card_of(tmp_path / "straight-carried")
    assert ours["moments"] == "f32" and ours["tensors"]["sha256"] == theirs["tensors"]["sha256"]
    assert ours["rng"] == theirs["rng"] and ours["step"] == 4
    assert resumed["started"] == {"checkpoint": str(tmp_path / "carried"), "step": 2, "sessions": 1}
    sessions = ours["sessions"]
    assert [(s["from_step"], s["to_step"], s["moments_in"]) for s in sessions] == [(0, 2, "fresh"), (2, 4, "f32")]
    assert sessions[-1]["machine"].startswith("CPU") and sessions[-1]["validation"]["step"] == 4
    assert ours["identity"]["network"] == {"width": 2, "levels": 2}


def changed(tmp_path, images, teacher, what, monkeypatch):
    """This run's config and carry options, with `what` changed against the
    checkpoint's; and the field the refusal must name."""
    cfg, opts = config(images, teacher, 4), {}
    if what == "calibration":
        other = tmp_path / "other.toml"
        other.write_text(CALIB.read_text() + "\n# another calibration\n")
        opts["calib"] = other
        return cfg, opts, "calibration.sha256"
    if what == "design":
        name_in_kernels(teacher, doe="0123456789abcdef")
        return cfg, opts, "design.doe null ≠ this run's 0123456789abcdef"
    if what == "objective":
        return config(images, teacher, 4, loss="psnr"), opts, "objective.loss mse ≠ this run's psnr"
    if what == "width":
        return config(images, teacher, 4, width=3), opts, "network.width 2 ≠ this run's 3"
    monkeypatch.setattr(carried, "STEP_VERSION", carried.STEP_VERSION + 1)
    return cfg, opts, f"code.step_version {carried.STEP_VERSION - 1} ≠ this run's {carried.STEP_VERSION}"


@pytest.mark.parametrize("what", ["calibration", "design", "objective", "width", "code"])
def test_a_checkpoint_of_another_identity_is_refused_naming_the_field(tmp_path, what, monkeypatch):
    images, teacher = write_teacher(tmp_path)
    distill.train(config(images, teacher, 4), tmp_path / "first", stop_after=2,
                  carry=carry(target=tmp_path / "carried"))
    cfg, opts, field = changed(tmp_path, images, teacher, what, monkeypatch)
    with pytest.raises(SystemExit) as e:
        distill.train(cfg, tmp_path / "second", carry=carry(source=tmp_path / "carried", **opts))
    message = str(e.value)
    assert message.startswith(f"error: checkpoint {tmp_path / 'carried'}: ") and field in message, message
    assert "≠ this run's" in message
    assert not (tmp_path / "second" / "checkpoint.pt").exists()
    # --fresh-if-refused: a fresh run, which says why.
    result = distill.train(cfg, tmp_path / "fresh", carry=carry(source=tmp_path / "carried", fresh_if_refused=True,
                                                                 **opts))
    assert field in result["started"]["fresh"] and result["steps"] == 4
    assert result["sessions"][0]["from_step"] == 0 and result["sessions"][0]["moments_in"] == "fresh"


def test_a_tampered_tensors_file_is_refused_by_its_hash(tmp_path, capsys):
    images, teacher = write_teacher(tmp_path)
    cfg = config(images, teacher, 2)
    distill.train(cfg, tmp_path / "run", carry=carry(target=tmp_path / "carried"))
    capsys.readouterr()
    distill.main(["checkpoint", str(tmp_path / "carried")])
    shown = json.loads(capsys.readouterr().out)
    assert shown["step"] == 2 and shown["moments"] == "f32" and len(shown["sessions"]) == 1
    path = tmp_path / "carried" / card_of(tmp_path / "carried")["tensors"]["file"]
    data = bytearray(path.read_bytes())
    data[-1] ^= 1  # one bit of the last tensor's last value
    path.write_bytes(bytes(data))
    with pytest.raises(carried.Refused, match="SHA-256 .* its card says .*not the file the card describes"):
        carried.read(tmp_path / "carried")
    with pytest.raises(SystemExit, match="not the file the card describes"):
        distill.train(cfg, tmp_path / "again", carry=carry(source=tmp_path / "carried"))
    with pytest.raises(SystemExit, match="not the file the card describes"):
        distill.main(["checkpoint", str(tmp_path / "carried")])
    # A card of another format is refused as such.
    card = card_of(tmp_path / "carried")
    (tmp_path / "carried" / "card.json").write_text(json.dumps({**card, "format": "nedrt dcnn checkpoint 0"}))
    with pytest.raises(carried.Refused, match="format nedrt dcnn checkpoint 0 ≠ this trainer's"):
        carried.read(tmp_path / "carried")


def test_writing_is_atomic_the_card_last(tmp_path, monkeypatch):
    """A write that dies before its card leaves the previous checkpoint
    whole (its card names its own tensors, which verify); a finished write
    leaves one tensors file and no temporary."""
    images, teacher = write_teacher(tmp_path)
    cfg = config(images, teacher, 4)
    distill.train(cfg, tmp_path / "run", stop_after=2, carry=carry(target=tmp_path / "carried"))
    before = card_of(tmp_path / "carried")
    real = carried.atomic_write

    def dies_at_the_card(path, data):
        if path.name == "card.json":
            raise OSError("disk gone")
        real(path, data)
    monkeypatch.setattr(carried, "atomic_write", dies_at_the_card)
    with pytest.raises(OSError):
        distill.train(cfg, tmp_path / "run", resume=True, carry=carry(target=tmp_path / "carried"))
    assert card_of(tmp_path / "carried") == before
    assert carried.read(tmp_path / "carried").step == 2
    monkeypatch.setattr(carried, "atomic_write", real)
    distill.train(cfg, tmp_path / "run", resume=True, carry=carry(target=tmp_path / "carried"))
    files = sorted(p.name for p in (tmp_path / "carried").iterdir())
    assert files == sorted(["card.json", card_of(tmp_path / "carried")["tensors"]["file"]])
    assert carried.read(tmp_path / "carried").step == 4


def test_the_moments_travel_as_the_budget_allows(tmp_path):
    """The full-width network (32–256 channels, 1.93 M parameters: 7.3 MiB
    of f32 weights) leaves no room in the 8 MiB budget for its moments;
    the half width carries them in f32. A checkpoint without them restarts
    Adam, and the learning rate warms up again from that step; one with
    bf16 moments brings them back rounded to bf16."""
    full, half = (sum(p.numel() for p in UNet(w, 4).parameters()) for w in (32, 16))
    assert full == 1_925_667 and half == 482_067
    assert carried.choose_moments(full, "auto", carried.CARRY_BUDGET_MIB) == "none"
    assert carried.choose_moments(full, "auto", 16) == "bf16"
    assert carried.choose_moments(half, "auto", carried.CARRY_BUDGET_MIB) == "f32"
    with pytest.raises(ValueError, match="choose auto"):
        carried.choose_moments(half, "f8", 8)
    images, teacher = write_teacher(tmp_path)
    cfg = config(images, teacher, 6)
    distill.train(cfg, tmp_path / "a", stop_after=3, carry=carry(target=tmp_path / "none", moments="none"))
    names = set(load_file(str(tmp_path / "none" / card_of(tmp_path / "none")["tensors"]["file"])))
    assert not any(n.startswith("adam.") for n in names) and "rng.torch" in names
    result = distill.train(cfg, tmp_path / "b", carry=carry(source=tmp_path / "none", target=tmp_path / "none"))
    assert result["sessions"][-1]["moments_in"] == "reset" and card_of(tmp_path / "none")["warm_start"] == 3
    lr = [float(line.split(",")[1]) for line in (tmp_path / "b" / "metrics.csv").read_text().splitlines()[1:]]
    assert lr == pytest.approx([float(f"{distill.lr_at(cfg, s, 0.0, 3):.3g}") for s in (3, 4, 5)])
    # The warm-up's first step again: a quarter of the uninterrupted run's
    # 4/200 of the peak at this step.
    assert lr[0] == pytest.approx(distill.lr_at(cfg, 3) / 4, rel=1e-2)
    distill.train(cfg, tmp_path / "c", stop_after=3, carry=carry(target=tmp_path / "bf16", moments="bf16"))
    r = distill.prepare(cfg)
    start = carried.read(tmp_path / "bf16")
    assert carried.restore(start, r.net, r.opt, r.data) == "bf16"
    full_state = torch.load(tmp_path / "c" / "checkpoint.pt", weights_only=True)["optimizer"]["state"]
    for i, s in r.opt.state_dict()["state"].items():
        assert s["exp_avg"].dtype == torch.float32
        assert torch.equal(s["exp_avg"], full_state[i]["exp_avg"].bfloat16().float())


def test_init_and_export_take_a_carried_checkpoint(tmp_path):
    images, teacher = write_teacher(tmp_path)
    distill.train(config(images, teacher, 2), tmp_path / "run", carry=carry(target=tmp_path / "carried"))
    weights = carried.network_of(carried.read(tmp_path / "carried"))
    r = distill.prepare(config(images, teacher, 2, init=str(tmp_path / "carried")))
    for k, v in r.net.state_dict().items():
        assert torch.equal(v, weights[k]), k
    with pytest.raises(ValueError, match="width 2 and 2 levels, this run's is 3"):
        distill.prepare(config(images, teacher, 2, width=3, init=str(tmp_path / "carried")))
    card = distill.export(tmp_path / "carried", tmp_path / "out", "carried",
                          REPO / "designs" / "multifocal" / "doe-fabrication.safetensors")
    assert card["steps"] == 2 and card["finished"] and card["trained_on"].startswith("CPU")
    assert card["validation"][-1]["step"] == 2 and len(card["sessions"]) == 1
    assert (tmp_path / "out" / "carried.onnx").is_file()


def test_the_command_line_carries_a_run(tmp_path, monkeypatch, capsys):
    """nedrt-train dcnn --save-checkpoint, then --from-checkpoint with
    --session-seconds (the time budget: the checkpoint's seconds plus the
    session's) and --fresh-if-refused; the calibration is the one the
    kernels name, found under the current directory."""
    images, teacher = write_teacher(tmp_path)
    name_in_kernels(teacher, calibration="calib/default.toml")
    monkeypatch.chdir(REPO)
    common = ["--teacher", str(teacher), "--images", str(images), "--width", "2", "--levels", "2", "--patch",
              str(PATCH), "--batch", "2", "--validate-every", "2", "--threads", "1", "--steps", "1000"]
    distill.main([*common, "--out", str(tmp_path / "a"), "--save-checkpoint", str(tmp_path / "carried"),
                  "--session-seconds", "1e-3"])
    first = card_of(tmp_path / "carried")
    assert first["step"] == 1 and first["config"]["time_budget"] == 1e-3
    distill.main([*common, "--out", str(tmp_path / "b"), "--from-checkpoint", str(tmp_path / "carried"),
                  "--fresh-if-refused", "--save-checkpoint", str(tmp_path / "carried"), "--session-seconds", "1e-3",
                  "--session-note", "test"])
    second = card_of(tmp_path / "carried")
    assert second["step"] == 2 and second["config"]["time_budget"] == pytest.approx(first["seconds"] + 1e-3)
    assert [s["note"] for s in second["sessions"]] == ["", "test"]
    assert second["calibration"] == str(CALIB)
    capsys.readouterr()
    with pytest.raises(SystemExit):
        distill.main([*common, "--out", str(tmp_path / "c"), "--fresh-if-refused"])
    assert "--fresh-if-refused goes with --from-checkpoint" in capsys.readouterr().err


def test_the_code_hash_ignores_comments_docstrings_and_layout(tmp_path):
    """The step code's hash (recorded per session) moves with the code, not
    with its comments, docstrings or line breaks."""
    package = Path(distill.__file__).parent
    for name in carried.STEP_MODULES:
        (tmp_path / f"{name}.py").write_text((package / f"{name}.py").read_text())
    assert carried.code_sha256(tmp_path) == carried.code_sha256()
    step = tmp_path / "distill_step.py"
    text = step.read_text()
    edited = text.replace('"""The D-CNN stage\'s step', '"""Reworded: the D-CNN stage\'s step', 1)
    edited = edited.replace("def clamp(raw, cfg=None):", "def clamp(raw,\n          cfg=None):  # a comment", 1)
    assert edited != text
    step.write_text(edited)
    assert carried.code_sha256(tmp_path) == carried.code_sha256()
    step.write_text(edited.replace("display = raw.clamp(0, 1)", "display = raw.clamp(0, 2)", 1))
    assert carried.code_sha256(tmp_path) != carried.code_sha256()
