"""Writes tests/golden/unrolled/: a small unrolled preprocessor on the
golden display problem (tests/golden/optimal.json, its kernels and lsq
filter made by nedrt, its optimum checked by scipy), exported as the
runtime reads it, and what PyTorch computes with it: the independent side
of nedrt-stages' `the_unrolled_golden_is_what_the_runtime_computes`.

Three steps of different ρ and α; steps 1 and 3 carry a correction with
seeded random weights (its last layer not zero, so the corrections move the
display image), step 2 none (a classical step). Deterministic: the same
seed gives the same numbers (models/tests/test_unrolled.py checks the
committed ones are this script's).

    PYTHONPATH=models python3 tools/golden/make_unrolled_golden.py [OUT_DIR]
"""
import json
import math
import sys
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[2]
RHO = (0.03, 0.08, 0.2)
RELAXATION = (1.5, 1.8, 1.2)
WITH_NETWORK = (True, False, True)


def golden_model(golden: dict, seed: int = 55):
    from nedrt_train.objective import Objective
    from nedrt_train.unrolled import StepCorrection, Unrolled
    channels, h, w = len(golden["psfs"]), golden["height"], golden["width"]
    depths = len(golden["depths_d"])
    kernels = {k: np.asarray(v, dtype=np.float64).reshape((depths,) * k.endswith("_per_depth") + (channels, 2 * h, 2 * w))
               for k, v in golden["kernels"].items()}
    objective = Objective(kernels, depths)
    objective.meta = {"method": "doe+wiener", "objective": golden["objective"], "doe": "golden",
                      "calibration": "tests/golden/optimal.json", "k_reg": repr(golden["k_reg"])}
    torch.manual_seed(seed)
    model = Unrolled(objective, len(RHO), width=8)
    with torch.no_grad():
        model.log_rho.copy_(torch.tensor([math.log(r) for r in RHO]))
        model.relax.copy_(torch.tensor([math.log(a / (2 - a)) for a in RELAXATION]))
        for step, keep in zip(model.corrections, WITH_NETWORK):
            if keep:
                torch.nn.init.uniform_(step.last.weight, -0.3, 0.3)
                torch.nn.init.uniform_(step.last.bias, -0.05, 0.05)
    return model


def main(out: Path) -> None:
    from nedrt_train.unrolled_export import export
    golden_path = REPO / "tests/golden/optimal.json"
    golden = json.loads(golden_path.read_text())
    model = golden_model(golden)
    channels, h, w = len(golden["psfs"]), golden["height"], golden["width"]
    image = torch.tensor(golden["input"], dtype=torch.float32).reshape(1, channels, h, w)
    # Step 2's correction is zero (its last layer starts so): the classical
    # step, which the exporter writes without a network.
    with torch.no_grad():
        steps = model(image)
    out.mkdir(parents=True, exist_ok=True)
    export(model, golden_path, out, "golden", note="seeded random corrections (tools/golden/make_unrolled_golden.py)",
           classical=[not keep for keep in WITH_NETWORK], checkpoint=False)
    io = {"source": "tools/golden/make_unrolled_golden.py on tests/golden/optimal.json",
          "width": w, "height": h, "input": golden["input"],
          "steps": [s.flatten().tolist() for s in steps]}
    (out / "io.json").write_text(json.dumps(io))
    print(f"wrote {out}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else REPO / "tests/golden/unrolled")
