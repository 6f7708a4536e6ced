"""Export of the unrolled preprocessor (unrolled.py) for the runtime: each
step's correction as ONNX (opset 17, input `planes` 1×9×H×W: the relaxed
point, the dual and the gradient / L, each per channel; output `correction`
1×3×H×W; dynamic H and W; metadata `nedrt.output = correction`, so the
runtime does not clamp it), and a manifest, `NAME.unrolled.toml`, that gives
K, each step's penalty share ρ_k / L and relaxation α_k, the step's network
by file name and SHA-256, and the optics it was trained through: the
method, objective, DOE (nedrt's content hash) and calibration from the
kernel file's metadata, and that file's SHA-256 (docs/unrolled.md)."""
import hashlib
import math
from pathlib import Path

import torch
from torch import nn

from .objective import Objective

FORMAT = "nedrt unrolled 1"


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class _StepGraph(nn.Module):
    """A step's correction on the runtime's 9 stacked planes."""

    def __init__(self, step):
        super().__init__()
        self.step = step

    def forward(self, planes):
        return self.step.planes(planes)


def _export_step(step, path: Path):
    import onnx
    x = torch.zeros(1, 9, 32, 32)
    tmp = path.with_name(path.name + ".tmp")
    torch.onnx.export(
        _StepGraph(step).eval(), (x,), str(tmp), dynamo=False, opset_version=17,
        input_names=["planes"], output_names=["correction"],
        dynamic_axes={"planes": {2: "height", 3: "width"}, "correction": {2: "height", 3: "width"}},
    )
    model = onnx.load(str(tmp))
    entry = model.metadata_props.add()
    entry.key, entry.value = "nedrt.output", "correction"
    onnx.save(model, str(tmp))
    tmp.replace(path)


def _toml_str(v: str) -> str:
    return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'


def export(model, kernels: Path, out: Path, name: str, note: str = "", classical=None,
           checkpoint: bool = True, doe: Path = None) -> Path:
    """Writes `out/NAME.stepK.onnx` for each step with a correction and
    `out/NAME.unrolled.toml` (and the weights, `out/NAME.unrolled.pt`, where
    `checkpoint`); returns the manifest's path. `classical[k]`: step k has
    no correction (its correction must be zero)."""
    objective: Objective = model.objective
    meta = getattr(objective, "meta", None) or {}
    missing = [k for k in ("method", "objective", "doe", "calibration", "k_reg") if k not in meta]
    if missing:
        raise ValueError(f"{kernels}: the kernel file's metadata lacks {', '.join(missing)}")
    out.mkdir(parents=True, exist_ok=True)
    rho = torch.exp(model.log_rho.detach()).tolist()
    relaxation = (2 * torch.sigmoid(model.relax.detach())).tolist()
    lines = [
        f"# The unrolled preprocessor {name}: written by nedrt_train.unrolled_export; {note}".rstrip("; "),
        f"format = {_toml_str(FORMAT)}",
        f"method = {_toml_str(meta['method'])}",
        f"objective = {_toml_str(meta['objective'])}",
        f"doe = {_toml_str(meta['doe'])}",
        f"calibration = {_toml_str(meta['calibration'])}",
        f"k_reg = {float(meta['k_reg'])!r}",
        f"kernels_sha256 = {_toml_str(sha256(kernels))}",
        f"trained_size = [{objective.size[1]}, {objective.size[0]}]",
    ]
    for k in range(model.steps):
        if not (math.isfinite(rho[k]) and rho[k] > 0 and 0 < relaxation[k] < 2):
            raise ValueError(f"step {k + 1}: ρ = {rho[k]}, α = {relaxation[k]} out of range")
        lines += ["", "[[step]]", f"rho = {rho[k]!r}", f"relaxation = {relaxation[k]!r}"]
        if classical is not None and classical[k] and model.corrections is not None:
            last = model.corrections[k].last
            if last.weight.abs().max() > 0 or last.bias.abs().max() > 0:
                raise ValueError(f"step {k + 1}: called classical, but its correction is not zero")
        elif model.corrections is not None:
            path = out / f"{name}.step{k + 1}.onnx"
            _export_step(model.corrections[k], path)
            lines += [f"network = {_toml_str(path.name)}", f"network_sha256 = {_toml_str(sha256(path))}"]
    manifest = out / f"{name}.unrolled.toml"
    tmp = manifest.with_name(manifest.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(manifest)
    if doe is not None:
        # Where nedrt looks for a model's DOE: the manifest's name with
        # `.doe.safetensors` for its last extension.
        tmp = out / f"{name}.unrolled.doe.safetensors.tmp"
        tmp.write_bytes(Path(doe).read_bytes())
        tmp.replace(out / f"{name}.unrolled.doe.safetensors")
    if checkpoint:
        torch.save({"state": model.state_dict(), "steps": model.steps, "name": name},
                   out / f"{name}.unrolled.pt")
    return manifest
