"""`nedrt-train dcnn` (nedrt_train/distill.py) on a tiny synthetic teacher:
it trains, checkpoints, resumes exactly where an uninterrupted run would
be, refuses a checkpoint of another configuration, and exports a model the
runtime can load (ONNX with its DOE beside it and a card)."""
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from safetensors.torch import save_file

from nedrt_train import distill

REPO = Path(__file__).resolve().parents[2]
DEPTHS = 2
PATCH = 16
VAL = 24


def kernels(size: int) -> dict:
    """A blur seen at two depths: Σ_D A_Dᵀ A_D, Σ_D A_Dᵀ T_D and Σ_D T_Dᵀ T_D
    of a 3-tap blur per axis on the mirrored 2size × 2size grid."""
    n = 2 * size
    k = torch.zeros(n, n)
    for dy, wy in ((-1, 0.25), (0, 0.5), (1, 0.25)):
        for dx, wx in ((-1, 0.25), (0, 0.5), (1, 0.25)):
            k[dy % n, dx % n] = wy * wx
    spec = torch.fft.rfft2(k)
    gram = torch.fft.irfft2(spec.abs() ** 2, s=(n, n))
    adjoint = torch.fft.irfft2(spec.conj(), s=(n, n))
    delta = torch.zeros(n, n)
    delta[0, 0] = 1
    per = {"normal": gram * 4, "adjoint_target": adjoint * 4, "target_gram": delta * 4}
    out = {}
    for name, v in per.items():
        one = v[None].repeat(3, 1, 1)
        out[name + "_per_depth"] = one[None].repeat(DEPTHS, 1, 1, 1).contiguous()
        out[name] = (one * DEPTHS).contiguous()
    return out


def write_teacher(root: Path):
    rng = np.random.default_rng(0)
    images = root / "images"
    for part, count, size in (("train", 3, 32), ("val", 2, VAL)):
        (images / part).mkdir(parents=True)
        folder = root / "teacher" / part
        folder.mkdir(parents=True)
        displays = {}
        for i in range(count):
            pixels = (rng.random((size, size, 3)) * 255).astype(np.uint8)
            Image.fromarray(pixels).save(images / part / f"p{i}.png")
            displays[f"p{i}"] = torch.from_numpy(pixels / 255.0).permute(2, 0, 1).float().contiguous()
        save_file(displays, str(folder / "displays.safetensors"))
        wiener = root / "teacher" / f"{part}-wiener"
        wiener.mkdir(parents=True)
        save_file({k: (v * 0.9 + 0.05).contiguous() for k, v in displays.items()}, str(wiener / "displays.safetensors"))
    meta = {"format": "nedrt objective kernels 1", "depths_d": json.dumps([0.0, 1.0])}
    for size in (PATCH, VAL):
        meta.update(width=str(size), height=str(size))
        save_file(kernels(size), str(root / "teacher" / "train" / f"operator-{size}x{size}.safetensors"), metadata=meta)
    (root / "teacher" / "train" / "prefilter.json").write_text(json.dumps({"prefilter": "optimal@target"}))
    return images, root / "teacher"


def config(images, teacher, steps, **kw):
    kw = {"width": 2, "levels": 2, "patch": PATCH, "batch": 2, "steps": steps, "validate_every": 2,
          "checkpoint_every": 1, **kw}
    return distill.DistillConfig(teacher=str(teacher), images=str(images), **kw)


def test_the_objective_of_the_kernels_is_the_blur_error(tmp_path):
    """The quadratic form of `kernels` is ½ Σ_D ‖b ∗ d − d‖²-like: zero where
    the display is the blurred image's preimage; checked on a flat field,
    which the blur keeps."""
    images, teacher = write_teacher(tmp_path)
    obj = distill.Objective.load(teacher / "train" / f"operator-{PATCH}x{PATCH}.safetensors")
    flat = torch.full((1, 3, PATCH, PATCH), 0.4)
    assert obj(flat, flat).abs().item() < 1e-4
    assert obj.depth_mse(flat, flat).abs().max().item() < 1e-6
    other = torch.rand(1, 3, PATCH, PATCH)
    assert obj(other, flat).item() > 0
    assert torch.allclose(obj.depth_mse(other, flat).sum(1), obj.mse(other, flat) * DEPTHS, rtol=1e-4)


def test_the_perceived_distance_is_the_blurred_difference(tmp_path):
    """`seen_distance` is the mean squared blurred difference (each depth of
    the test kernels sees the 3-tap blur, symmetric extension), computed
    here by direct sums; the ceiling's invisible content costs nothing."""
    images, teacher = write_teacher(tmp_path)
    obj = distill.Objective.load(teacher / "train" / f"operator-{PATCH}x{PATCH}.safetensors")
    gen = torch.Generator().manual_seed(4)
    a, b = torch.rand(2, 3, PATCH, PATCH, generator=gen), torch.rand(2, 3, PATCH, PATCH, generator=gen)
    e = torch.nn.functional.pad(a - b, (1, 1, 1, 1), mode="replicate")
    taps = torch.tensor([0.25, 0.5, 0.25])
    blurred = sum(wy * wx * e[..., 1 + dy:1 + dy + PATCH, 1 + dx:1 + dx + PATCH]
                  for dy, wy in zip((-1, 0, 1), taps) for dx, wx in zip((-1, 0, 1), taps))
    want = (blurred ** 2).mean(dim=(1, 2, 3))
    assert torch.allclose(obj.seen_distance(a, b), want, rtol=1e-4), (obj.seen_distance(a, b), want)
    assert config(images, teacher, 1, distill_metric="perceived").distill_metric == "perceived"
    with pytest.raises(ValueError, match="distill-metric"):
        distill.train(config(images, teacher, 1, distill_metric="retinal"), tmp_path / "bad")


@pytest.mark.parametrize("loss", ["mse", "psnr"])
def test_resume_continues_exactly(tmp_path, loss):
    images, teacher = write_teacher(tmp_path)
    straight = distill.train(config(images, teacher, 4, loss=loss), tmp_path / "straight")
    distill.train(config(images, teacher, 4, loss=loss), tmp_path / "split", stop_after=2)
    resumed = distill.train(config(images, teacher, 4, loss=loss), tmp_path / "split", resume=True)
    a = torch.load(tmp_path / "straight" / "checkpoint.pt", weights_only=True)["net"]
    b = torch.load(tmp_path / "split" / "checkpoint.pt", weights_only=True)["net"]
    for k in a:
        assert torch.equal(a[k], b[k]), k
    assert straight["validation"][-1]["dcnn_db"] == resumed["validation"][-1]["dcnn_db"]
    assert "dcnn_mean_db" in straight["validation"][-1]


def test_a_checkpoint_of_another_configuration_is_refused_naming_the_fields(tmp_path):
    images, teacher = write_teacher(tmp_path)
    distill.train(config(images, teacher, 1), tmp_path / "run")
    with pytest.raises(SystemExit) as e:
        distill.train(config(images, teacher, 2, lr=0.5), tmp_path / "run", resume=True)
    assert str(e.value) == (f"error: {tmp_path / 'run' / 'checkpoint.pt'} was made with another configuration: "
                            "lr 0.001 ≠ this run's 0.5; steps 1 ≠ this run's 2")


def test_export_writes_the_model_its_doe_and_a_card(tmp_path):
    images, teacher = write_teacher(tmp_path)
    distill.train(config(images, teacher, 1), tmp_path / "run")
    doe = REPO / "designs" / "multifocal" / "doe-fabrication.safetensors"
    card = distill.export(tmp_path / "run", tmp_path / "out", "tiny", doe)
    for f in ("tiny.onnx", "tiny.doe.safetensors", "tiny.card.json"):
        assert (tmp_path / "out" / f).is_file(), f
    assert (tmp_path / "out" / "tiny.doe.safetensors").read_bytes() == doe.read_bytes()
    assert card["steps"] == 1 and card["macs_per_pixel"] > 0
    import onnx
    model = onnx.load(str(tmp_path / "out" / "tiny.onnx"))
    assert [i.name for i in model.graph.input] == ["image"]
    assert card["finished"] and card["validation"]


def test_the_card_of_a_stopped_run_keeps_its_validations(tmp_path):
    """A run stopped before its last step (no result.json) is exported with
    the validations its checkpoint holds, and the card says it is unfinished."""
    images, teacher = write_teacher(tmp_path)
    distill.train(config(images, teacher, 4), tmp_path / "run", stop_after=2)
    (tmp_path / "run" / "result.json").unlink()  # as when the process is killed
    doe = REPO / "designs" / "multifocal" / "doe-fabrication.safetensors"
    card = distill.export(tmp_path / "run", tmp_path / "out", "stopped", doe)
    assert card["steps"] == 2 and not card["finished"]
    assert [v["step"] for v in card["validation"]] == [2]


def test_the_wiener_base_starts_at_the_wiener(tmp_path):
    """--base wiener: the residual's last layer starts at zero, so before
    it learns anything the network's display image is the Wiener's."""
    images, teacher = write_teacher(tmp_path)
    result = distill.train(config(images, teacher, 1, base="wiener", lr=1e-12), tmp_path / "run")
    v = result["validation"][-1]
    assert v["dcnn_db"] == pytest.approx(v["wiener_db"], abs=1e-6)
    with pytest.raises(ValueError, match="choose input or wiener"):
        distill.train(config(images, teacher, 1, base="teacher"), tmp_path / "bad")


def test_the_raw_wiener_input_starts_at_the_clamped_wiener_and_learns_through_the_clamp(tmp_path):
    """--input wiener-raw: the network sees the Wiener before the clamp and
    starts exactly at the clamped Wiener; with --clamp-grad straight a value
    the clamp cuts still gets a gradient, with the clamp's own it gets none."""
    from safetensors.torch import load_file, save_file
    images, teacher = write_teacher(tmp_path)
    for part in ("train", "val"):
        clamped = load_file(str(teacher / f"{part}-wiener" / "displays.safetensors"))
        raw = {k: (v * 1.6 - 0.3).contiguous() for k, v in clamped.items()}
        (teacher / f"{part}-wiener-raw").mkdir()
        save_file(raw, str(teacher / f"{part}-wiener-raw" / "displays.safetensors"))
        save_file({k: v.clamp(0, 1).contiguous() for k, v in raw.items()},
                  str(teacher / f"{part}-wiener" / "displays.safetensors"))
    result = distill.train(config(images, teacher, 1, input="wiener-raw", lr=1e-12), tmp_path / "run")
    v = result["validation"][-1]
    assert v["dcnn_db"] == pytest.approx(v["wiener_db"], abs=1e-6)
    raw = torch.tensor([-0.5, 0.5, 1.5], requires_grad=True)
    for mode, expected in (("zero", [0.0, 1.0, 0.0]), ("straight", [1.0, 1.0, 1.0])):
        raw.grad = None
        cfg = config(images, teacher, 1, clamp_grad=mode)
        distill.clamp(raw, cfg).sum().backward()
        assert raw.grad.tolist() == expected
        assert distill.clamp(raw, cfg).tolist() == [0.0, 0.5, 1.0]
    # The card tells the runtime to run the same Wiener in front; without
    # the Wiener's K nothing is written.
    doe = REPO / "designs" / "multifocal" / "doe-fabrication.safetensors"
    with pytest.raises(ValueError, match="no Wiener K"):
        distill.export(tmp_path / "run", tmp_path / "out", "w", doe)
    assert not (tmp_path / "out" / "w.onnx").exists()
    (teacher / "train-wiener-raw" / "prefilter.json").write_text(json.dumps({"wiener_k": 0.05}))
    card = distill.export(tmp_path / "run", tmp_path / "out", "w", doe)
    assert (card["input"], card["wiener_k"]) == ("wiener-raw", 0.05)
    assert json.loads((tmp_path / "out" / "w.card.json").read_text())["input"] == "wiener-raw"
    with pytest.raises(ValueError, match="its own residual base"):
        distill.train(config(images, teacher, 1, input="wiener-raw", base="wiener"), tmp_path / "bad")
    with pytest.raises(ValueError, match="choose zero or straight"):
        distill.train(config(images, teacher, 1, clamp_grad="soft"), tmp_path / "bad2")


class DeviceRecorder(torch.utils._python_dispatch.TorchDispatchMode):
    """Every device of every tensor an operation takes or makes, and the
    host tensors uploaded (the batch's random draws come from numpy)."""

    def __init__(self):
        super().__init__()
        self.devices = {}
        self.uploads = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        leaves = [t for t in torch.utils._pytree.tree_leaves((args, kwargs, out))
                  if isinstance(t, torch.Tensor) and t.dim() > 0]
        if func in (torch.ops.aten.lift_fresh.default, torch.ops.aten._to_copy.default) and \
                leaves and leaves[0].device.type == "cpu":
            # torch.from_numpy(draws).to(device): the one upload a batch.
            self.uploads.append((str(func), leaves[0].dtype, str(leaves[-1].device)))
            leaves = leaves[-1:] if func == torch.ops.aten._to_copy.default else []
        for t in leaves:
            self.devices.setdefault(str(t.device), str(func))
        return out


@pytest.mark.parametrize("device", ["meta", "cpu"])
def test_every_tensor_of_a_step_is_on_the_device_asked_for(tmp_path, device):
    """The step on a GPU is the step on the CPU with the device passed in:
    `prepare` puts the network, the optimiser, the objectives and the
    patches on `--device`, and one step (the v10 recipe's terms: raw Wiener
    input, PSNR loss vs target and sharp, perceived distillation) touches
    no tensor elsewhere. On `meta` a tensor left on the CPU would show here
    (or stop the step: devices do not mix)."""
    images, teacher = write_teacher(tmp_path)
    for part in ("train", "val"):
        from safetensors.torch import load_file, save_file
        raw = load_file(str(teacher / f"{part}-wiener" / "displays.safetensors"))
        (teacher / f"{part}-wiener-raw").mkdir()
        save_file(raw, str(teacher / f"{part}-wiener-raw" / "displays.safetensors"))
    sharp = teacher / "train-sharp"
    sharp.mkdir()
    for f in (teacher / "train").glob("operator-*.safetensors"):
        (sharp / f.name).write_bytes(f.read_bytes())
    cfg = config(images, teacher, 2, device=device, input="wiener-raw", loss="psnr", sharp_weight=1.0,
                 distill_metric="perceived", clamp_grad="straight")
    r = distill.prepare(cfg)
    assert {str(p.device) for p in r.net.parameters()} == {device}
    recorder = DeviceRecorder()
    with recorder:
        loss, terms = distill.step_once(r.net, r.opt, r.objective, r.data, cfg, r.sharp)
    assert set(recorder.devices) == {device}, recorder.devices
    # What came from the host: the batch's draws (integers), once.
    copies = [u for u in recorder.uploads if u[0] == "aten._to_copy.default"]
    want = [] if device == "cpu" else [("aten._to_copy.default", torch.int64, device)]
    assert copies == want, recorder.uploads
    assert loss.device.type == device and loss.dim() == 0
    # Adam's state followed the parameters.
    states = [v for s in r.opt.state.values() for v in s.values() if isinstance(v, torch.Tensor) and v.dim()]
    assert states and {str(v.device) for v in states} == {device}


def test_a_batch_is_the_same_whether_cut_at_once_or_patch_by_patch():
    """The batched crop (one gather per stack, the symmetries by group) cuts
    exactly what the patch-by-patch loop cuts, draw for draw."""
    rng = np.random.default_rng(3)
    photos = [rng.random((20, 20, 3)).astype(np.float32) for _ in range(3)]
    teachers = [torch.rand(3, 20, 20) for _ in range(3)]
    dense = distill.Patches(photos, teachers, 8, seed=5)
    loop = distill.Patches(photos, teachers, 8, seed=5)
    loop.dense = False
    loop.stacks = [list(s) for s in loop.stacks if s is not None] + [None]
    assert dense.dense
    for _ in range(3):
        a, b = dense.batch(16), loop.batch(16)
        assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1]) and a[2] is None and b[2] is None


def test_a_time_budget_ends_the_run_validated_and_finished(tmp_path):
    """--time-budget: the schedule follows the time and the run stops when
    it is spent, with a validation and a checkpoint at that step; the card
    calls it finished. --batch 0 on the CPU takes 8 (or --max-batch)."""
    images, teacher = write_teacher(tmp_path)
    result = distill.train(config(images, teacher, 50, time_budget=1e-3, validate_every=100, batch=0, max_batch=3),
                           tmp_path / "run")
    assert result["steps"] == 1 and result["finished"]
    assert [v["step"] for v in result["validation"]] == [1]
    assert result["config"]["batch"] == 3 and result["device"].startswith("CPU")
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    assert state["step"] == 1
    cfg = distill.DistillConfig(steps=100, time_budget=10.0)
    assert distill.lr_at(cfg, 500, 5.0) == pytest.approx(cfg.lr * (0.01 + 0.99 * 0.5))
    assert distill.lr_at(cfg, 500, 20.0) == pytest.approx(cfg.lr * 0.01)
    card = distill.export(tmp_path / "run", tmp_path / "out", "t",
                          REPO / "designs" / "multifocal" / "doe-fabrication.safetensors")
    assert card["finished"] and card["trained_on"].startswith("CPU")


def test_bf16_autocast_keeps_the_display_image_float32_and_close(tmp_path):
    """--amp bf16 runs the network's convolutions in bf16; the residual sum
    and what follows stay float32, within bf16's precision of the f32 step."""
    torch.manual_seed(0)
    net = distill.UNet(4, 2)
    x = torch.rand(2, 3, 16, 16)
    cfg32 = distill.DistillConfig(width=4, levels=2)
    cfg16 = distill.DistillConfig(width=4, levels=2, amp="bf16")
    a, b = distill.forward(net, x, cfg=cfg32), distill.forward(net, x, cfg=cfg16)
    assert a.dtype == b.dtype == torch.float32
    residual = (a - x).norm()
    assert 0 < ((a - b).norm() / residual).item() < 2e-2
    with pytest.raises(ValueError, match="choose off or bf16"):
        distill.forward(net, x, cfg=distill.DistillConfig(amp="fp8"))
