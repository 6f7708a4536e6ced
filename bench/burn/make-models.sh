#!/usr/bin/env bash
# Makes the models the benchmark imports into burn at build time, besides the
# shipped models/dcnn.onnx: the full-width D-CNN architecture (U-Net width 32,
# 4 levels, 3 → 3 channels), which is not shipped trained, exported with random
# weights (speed does not depend on them) by the project's own trainer code.
# Deterministic: the same seed gives the same file, byte for byte.
# Then lists each model's ONNX operators (burn-onnx must import all of them).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
py=${PYTHON:-$root/.venv/bin/python}
if [ ! -x "$py" ]; then
    echo "error: no Python at $py; make the project's venv (models/README.md) or set PYTHON" >&2
    exit 1
fi
mkdir -p "$here/models"
cd "$root"
PYTHONPATH=models "$py" - "$here/models/dcnn_w32.onnx" <<'PY'
import sys
import torch
from nedrt_train.unet import UNet
from nedrt_train.export import export_onnx

torch.manual_seed(0)
export_onnx(UNet(32, 4), sys.argv[1])
PY
PYTHONPATH=models "$py" - models/dcnn.onnx "$here/models/dcnn_w32.onnx" <<'PY'
import collections
import sys
import onnx
from onnx import numpy_helper

for path in sys.argv[1:]:
    m = onnx.load(path)
    ops = collections.Counter(n.op_type for n in m.graph.node)
    params = sum(numpy_helper.to_array(i).size for i in m.graph.initializer)
    opset = ",".join(f"{d or 'ai.onnx'}:{v}" for d, v in ((o.domain, o.version) for o in m.opset_import))
    print(f"{path}: {params} parameters, opset {opset}, ops {dict(sorted(ops.items()))}")
PY
