"""A D-CNN stage's run (distill.py) as the runtime's model (`nedrt-train
dcnn export`): the network as ONNX, the frozen DOE it was trained for
beside it, and the model card (the recipe, the hardware, the teacher, the
validation figures, the files' hashes). The run is a run folder
(checkpoint.pt) or a carried checkpoint (distill_checkpoint.py's folder,
e.g. models/checkpoints/dcnn-full)."""
import dataclasses
import json
import os
from pathlib import Path

import torch

from . import distill_checkpoint as carried
from .distill_config import DistillConfig, is_finished
from .unet import UNet


def export(run: Path, out: Path, name: str, doe: Path) -> dict:
    """A run's network as the runtime's model: `out/NAME.onnx`, the frozen
    DOE it was trained for beside it (`out/NAME.doe.safetensors`, what
    nedrt loads with a model), and `out/NAME.card.json`."""
    import platform
    import shutil

    from .export import export_onnx, sha256
    if (run / "card.json").is_file():
        # A carried checkpoint: its card holds what result.json would.
        start = carried.read(run)
        c = start.card
        cfg = DistillConfig(**c["config"])
        state = {"net": carried.network_of(start), "step": c["step"], "seconds": c["seconds"],
                 "history": c.get("validation")}
        sessions = c.get("sessions") or [{}]
        result = {"steps": c["step"], "device": sessions[-1].get("machine"), "teacher": c.get("teacher"),
                  "validation": c.get("validation"), "sessions": c.get("sessions")}
        wiener_k = c.get("wiener_k")
        if cfg.input == "wiener-raw" and not wiener_k:
            raise ValueError(f"{run / 'card.json'}: no Wiener K (wiener_k) for a network on the raw Wiener")
    else:
        state = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=True)
        cfg = DistillConfig(**state["config"])
        result = json.loads((run / "result.json").read_text()) if (run / "result.json").exists() else {}
        wiener_k = wiener_k_of(cfg)
    if not doe.is_file():
        raise FileNotFoundError(f"{doe}: DOE file not found")
    net = UNet(cfg.width, cfg.levels)
    net.load_state_dict(state["net"])
    out.mkdir(parents=True, exist_ok=True)
    onnx_path, doe_path = out / f"{name}.onnx", out / f"{name}.doe.safetensors"
    export_onnx(net, onnx_path)
    shutil.copyfile(doe, doe_path)
    if result.get("steps") != state["step"]:
        # Written by an earlier stop of a run resumed since: the checkpoint is newer.
        result = {}
    card = {
        "name": name, "recipe": "nedrt-train dcnn (docs/training.md, the D-CNN stage)",
        "config": dataclasses.asdict(cfg), "steps": state["step"],
        "wall_time_s": state.get("seconds"),
        "hardware": {"platform": platform.platform(), "processor": platform.processor(),
                     "cpu_count": os.cpu_count(), "torch_threads": cfg.threads or torch.get_num_threads(),
                     "torch": torch.__version__,
                     "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None},
        # The device the run trained on (its result.json), beside the exporting machine.
        "trained_on": result.get("device"),
        "doe": {"source": str(doe), "sha256": sha256(doe)},
        "teacher": result.get("teacher") or teacher_manifest(cfg),
        # A run stopped before its last step has no result.json: its
        # checkpoint's history holds the validations it did make.
        "validation": result.get("validation", state.get("history")),
        "finished": is_finished(cfg, state["step"], state.get("seconds") or 0.0),
        "parameters": sum(p.numel() for p in net.parameters()),
        "macs_per_pixel": net.macs_per_pixel(),
        "files": {p.name: sha256(p) for p in [onnx_path, doe_path]},
    }
    if result.get("sessions"):
        card["sessions"] = result["sessions"]
    if wiener_k is not None:
        # The runtime runs the same Wiener in front of the network
        # (nedrt-stages' preprocess::dcnn_system reads these two fields).
        card["input"], card["wiener_k"] = "wiener-raw", wiener_k
    (out / f"{name}.card.json").write_text(json.dumps(card, indent=1))
    return card


def wiener_k_of(cfg: DistillConfig, required: bool = True) -> float | None:
    """The Wiener's K in front of a network on the raw Wiener (`--input
    wiener-raw`; nedrt prefilter --prefilter native --unclamped records
    it), or None for a network on the image; a missing one is an error
    where `required`."""
    if cfg.input != "wiener-raw":
        return None
    manifest = Path(cfg.teacher) / "train-wiener-raw" / "prefilter.json"
    k = json.loads(manifest.read_text()).get("wiener_k") if manifest.is_file() else None
    if not (isinstance(k, (int, float)) and k > 0):
        if not required:
            return None
        raise ValueError(f"{manifest}: no Wiener K (wiener_k); run nedrt prefilter --prefilter native "
                         "--unclamped again")
    return float(k)


def teacher_manifest(cfg: DistillConfig) -> dict | None:
    """The teacher's prefilter.json, as a run records it in result.json."""
    path = Path(cfg.teacher) / cfg.teacher_set / "prefilter.json"
    return {"train": json.loads(path.read_text())} if path.is_file() else None
