"""The D-CNN stage's carried checkpoint (issue 41; docs/training.md,
"Carrying the training across lent GPUs"): a folder a run starts from
(`nedrt-train dcnn --from-checkpoint DIR`) and writes (`--save-checkpoint
DIR`), committed in the repository so that every lent GPU adds its minutes
to one network.

    DIR/card.json                            what it is (JSON, below)
    DIR/tensors-<sha256[:16]>.safetensors    the network (f32), Adam's moments
                                             (f32, bf16 or none), torch's RNG state

The card holds the tensors file's name, SHA-256 and size; the step, the
seconds trained and the schedule's warm-up start; the recipe (the
configuration); the data and Python random states; every validation; the
sessions (machine, steps, seconds, batch, validation figures); and the
identity the checkpoint was made under (`identity`): the step's declared
version, the calibration's SHA-256, the DOE design, the objective and the
network's size. A run continues a checkpoint only under the same identity:
another is refused naming the field and both values (`Refused`), and so is
a tensors file whose hash is not its card's. Nothing is unpickled: the
tensors are safetensors, the rest JSON.

Writing is atomic: the tensors file is written under its content's name
(temp + rename), then the card that names it (temp + rename); the card is
the commit point, so a folder is never seen half-written, and the files
the new card does not name are removed after it.
"""
import dataclasses
import hashlib
import json
import random
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from .atomic import atomic_write
from .distill_config import DistillConfig
from .distill_step import STEP_VERSION

FORMAT = "nedrt dcnn checkpoint 1"
MIB = 1 << 20
#: The room the device tool's travel limit leaves a committed checkpoint:
#: 60 MiB may travel (tools/device/check_runner.py), the working tree is
#: 39.5 MiB and .devcheck/ 10.1 MiB (docs/training.md has the sizes).
CARRY_BUDGET_MIB = 8.0
#: How Adam's moments travel: "auto" takes the first of f32, bf16, none
#: whose tensors file fits the budget.
MOMENTS = ("auto", "f32", "bf16", "none")
#: Fields of the configuration that are not the identity and may change
#: from one session to the next without a note: where the data lie, where
#: the step runs, how often it logs.
PLACE = ("teacher", "images", "init", "device", "threads", "validate_every", "checkpoint_every")

#: The modules (of this package) a step is made of: `code_sha256` hashes them.
STEP_MODULES = ("unet", "objective", "distill_data", "distill_step", "distill")


class Refused(ValueError):
    """A checkpoint this run may not continue; the message names why."""


@dataclass
class Carry:
    """A run's carried-checkpoint options (the command line's)."""
    source: Path | None = None         # --from-checkpoint DIR
    target: Path | None = None         # --save-checkpoint DIR
    fresh_if_refused: bool = False     # a refused source: start fresh, say why
    session_seconds: float | None = None  # time budget = the source's seconds + this
    session_note: str = ""             # recorded in the session (the device check: its commit)
    calib: Path | None = None          # the calibration; default: the kernels' own
    moments: str = "auto"
    budget_mib: float = CARRY_BUDGET_MIB


@dataclass
class Start:
    """A verified checkpoint: its card and its tensors (on the CPU)."""
    folder: Path
    card: dict
    tensors: dict

    @property
    def step(self) -> int:
        return int(self.card["step"])

    @property
    def seconds(self) -> float:
        return float(self.card["seconds"])


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def kernel_meta(path: Path) -> dict:
    """The metadata of a kernel file of `nedrt prefilter --operator`."""
    from safetensors import safe_open
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no kernel file (nedrt prefilter --operator WxH writes it)")
    with safe_open(str(path), framework="pt") as f:
        return dict(f.metadata() or {})


def code_sha256(folder: Path | None = None) -> str:
    """SHA-256 over the syntax trees (docstrings dropped, so comments,
    docstrings and layout do not count) of the modules a step is made of,
    this package's (or those in `folder`). Recorded in each session,
    compared only for a note: the identity holds the declared
    `STEP_VERSION`."""
    import ast
    folder = Path(__file__).parent if folder is None else Path(folder)
    h = hashlib.sha256()
    for module in STEP_MODULES:
        tree = ast.parse((folder / f"{module}.py").read_text())
        for node in ast.walk(tree):
            body = getattr(node, "body", None)
            if (isinstance(body, list) and body and isinstance(body[0], ast.Expr)
                    and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str)):
                node.body = body[1:] or [ast.Pass()]
        h.update(module.encode() + b"\0" + ast.dump(tree).encode() + b"\0")
    return h.hexdigest()


def kernels_path(cfg: DistillConfig, folder: str = "train") -> Path:
    return Path(cfg.teacher) / folder / f"operator-{cfg.patch}x{cfg.patch}.safetensors"


def calibration_path(cfg: DistillConfig, calib: Path | None = None) -> Path:
    """The calibration the teacher's kernels were made with: `calib`, else
    the file their metadata names, under the current directory."""
    if calib is None:
        named = kernel_meta(kernels_path(cfg)).get("calibration")
        if not named:
            raise ValueError(f"{kernels_path(cfg)}: the kernels name no calibration; pass --calib FILE")
        calib = Path(named)
    calib = Path(calib).resolve()
    if not calib.is_file():
        raise FileNotFoundError(f"{calib}: the calibration the kernels were made with is not here "
                                "(run from the repository root, or pass --calib FILE)")
    return calib


def identity(cfg: DistillConfig, calib: Path | None = None) -> dict:
    """What a checkpoint is, which a run continuing it must share: read
    from the kernels the run trains on (their metadata: the DOE, the
    objective, the depths), the calibration they were made with
    (`calibration_path`) and the recipe."""
    target = kernel_meta(kernels_path(cfg))
    sharp = kernel_meta(kernels_path(cfg, "train-sharp")) if cfg.sharp_weight else {}
    calib = calibration_path(cfg, calib)
    return {
        "format": FORMAT,
        "code": {"step_version": STEP_VERSION},
        "calibration": {"sha256": sha256(calib)},
        "design": {"doe": target.get("doe"), "method": target.get("method"), "wiener_k": target.get("k_reg")},
        "objective": {"kernels": target.get("objective"), "kernel_format": target.get("format"),
                      "depths_d": target.get("depths_d"), "sharp_kernels": sharp.get("objective"),
                      "loss": cfg.loss, "sharp_weight": cfg.sharp_weight, "distill": cfg.distill,
                      "distill_metric": cfg.distill_metric, "teacher_set": cfg.teacher_set,
                      "range_penalty": cfg.range_penalty, "clamp_grad": cfg.clamp_grad, "input": cfg.input,
                      "base": cfg.base},
        "network": {"width": cfg.width, "levels": cfg.levels},
    }


def differences(theirs: dict, ours: dict, prefix: str = "") -> list:
    """(field, theirs, ours) of every leaf that differs, dotted names."""
    out = []
    for key in sorted(set(theirs) | set(ours), key=str):
        a, b = theirs.get(key), ours.get(key)
        name = f"{prefix}{key}"
        if isinstance(a, dict) and isinstance(b, dict):
            out += differences(a, b, name + ".")
        elif a != b:
            out.append((name, a, b))
    return out


def shown(v) -> str:
    """A value in a message: long strings (hashes) cut to 16 characters."""
    if isinstance(v, str) and len(v) > 24:
        return v[:16] + "…"
    return json.dumps(v) if not isinstance(v, str) else v


def explain(diffs: list) -> str:
    return "; ".join(f"{f} {shown(a)} ≠ this run's {shown(b)}" for f, a, b in diffs)


def read(folder: Path) -> Start:
    """The card and tensors of `folder`, the tensors checked against the card's hash."""
    from safetensors.torch import load
    folder = Path(folder)
    card_path = folder / "card.json"
    if not card_path.is_file():
        raise FileNotFoundError(f"checkpoint {folder}: no card.json")
    card = json.loads(card_path.read_text())
    if card.get("format") != FORMAT:
        raise Refused(f"checkpoint {folder}: format {shown(card.get('format'))} ≠ this trainer's {FORMAT}")
    entry = card["tensors"]
    path = folder / entry["file"]
    if Path(entry["file"]).name != entry["file"] or not path.is_file():
        raise Refused(f"checkpoint {folder}: its card names {entry['file']}, which is not in the folder")
    data = path.read_bytes()
    digest = hashlib.sha256(data).hexdigest()
    if digest != entry["sha256"]:
        raise Refused(f"checkpoint {folder}: {entry['file']} has SHA-256 {shown(digest)}, its card says "
                      f"{shown(entry['sha256'])}: not the file the card describes")
    return Start(folder, card, load(data))


def load(folder: Path, ours: dict) -> Start:
    """`read`, and refused unless made under the identity `ours`."""
    start = read(folder)
    diffs = differences(start.card["identity"], ours)
    if diffs:
        raise Refused(f"checkpoint {folder}: {explain(diffs)}")
    return start


def choose_moments(parameters: int, asked: str, budget_mib: float) -> str:
    """The moments' precision: `asked`, or under "auto" the first of f32,
    bf16 and none whose tensors file (weights f32 + two moments) fits."""
    if asked not in MOMENTS:
        raise ValueError(f"moments {asked!r}: choose {', '.join(MOMENTS)}")
    if asked != "auto":
        return asked
    for kind, per in (("f32", 12), ("bf16", 8)):
        if parameters * per <= budget_mib * MIB:
            return kind
    return "none"


def tensors_of(net, opt, moments: str) -> dict:
    out = {f"net.{k}": v.detach().to("cpu").contiguous() for k, v in net.state_dict().items()}
    if moments != "none":
        dtype = torch.float32 if moments == "f32" else torch.bfloat16
        state = opt.state_dict()["state"]
        for i, (name, _) in enumerate(net.named_parameters()):
            s = state.get(i)
            if not s:
                continue
            out[f"adam.step.{name}"] = torch.as_tensor(s["step"], dtype=torch.float32).reshape(())
            for key in ("exp_avg", "exp_avg_sq"):
                out[f"adam.{key}.{name}"] = s[key].detach().to("cpu", dtype).contiguous()
    out["rng.torch"] = torch.get_rng_state()
    return out


def write(folder: Path, net, opt, moments: str, card: dict) -> dict:
    """Writes `folder` atomically: the tensors (the network, Adam's moments
    at `moments`, torch's RNG state), then `card` with their name and hash.
    Returns the card written."""
    from safetensors.torch import save
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    data = save(tensors_of(net, opt, moments), metadata={"format": FORMAT})
    digest = hashlib.sha256(data).hexdigest()
    name = f"tensors-{digest[:16]}.safetensors"
    atomic_write(folder / name, data)
    card = {"format": FORMAT, **card, "moments": moments,
            "tensors": {"file": name, "sha256": digest, "bytes": len(data)},
            "written": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    atomic_write(folder / "card.json", (json.dumps(card, indent=1) + "\n").encode())
    for old in folder.glob("tensors-*.safetensors*"):
        if old.name != name:
            old.unlink()
    return card


def restore(start: Start, net, opt, data) -> str:
    """The checkpoint's network, Adam's moments (where it holds them) and
    random states into this run's; returns how the moments came in
    ("f32", "bf16", or "reset": Adam starts afresh)."""
    t = start.tensors
    net.load_state_dict({k[len("net."):]: v for k, v in t.items() if k.startswith("net.")})
    moments = start.card["moments"]
    if moments != "none":
        names = [n for n, _ in net.named_parameters()]
        state = opt.state_dict()
        state["state"] = {i: {"step": t[f"adam.step.{n}"].clone(), "exp_avg": t[f"adam.exp_avg.{n}"].float(),
                              "exp_avg_sq": t[f"adam.exp_avg_sq.{n}"].float()}
                          for i, n in enumerate(names) if f"adam.step.{n}" in t}
        opt.load_state_dict(state)
    rng = start.card["rng"]
    data.rng.bit_generator.state = rng["data"]
    random.setstate((rng["python"][0], tuple(rng["python"][1]), rng["python"][2]))
    torch.set_rng_state(t["rng.torch"])
    return moments if moments != "none" else "reset"


def network_of(start: Start) -> dict:
    """The network's state dict (`--init DIR`, `dcnn export --run DIR`)."""
    return {k[len("net."):]: v for k, v in start.tensors.items() if k.startswith("net.")}


def recipe_notes(card: dict, cfg: DistillConfig) -> list:
    """What this run's recipe changes against the checkpoint's (schedule,
    batch, patch: allowed; the identity's fields are refused before)."""
    saved = {k: v for k, v in card.get("config", {}).items() if k not in PLACE}
    ours = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in PLACE}
    return [f"{f} {shown(b)} (the checkpoint's {shown(a)})" for f, a, b in differences(saved, ours)]


def summary(start: Start) -> dict:
    """What `nedrt-train dcnn checkpoint DIR` prints of a verified checkpoint."""
    c = start.card
    return {"folder": str(start.folder), "step": c["step"], "seconds": round(c["seconds"], 1),
            "moments": c["moments"], "tensors": c["tensors"], "identity": c["identity"],
            "sessions": c.get("sessions", []), "validation": (c.get("validation") or [])[-1:]}
