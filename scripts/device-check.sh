#!/usr/bin/env bash
# The device check (issue 29): every figure a lent accelerator can give, in
# one call of the device tool (docs/benchmarks.md, "On a lent accelerator").
#
# How to launch it on the accelerator machine:
#   1. here, once per commit:  bash scripts/device-check.sh --prepare
#      (builds .devcheck/: the release binary, stripped and xz-compressed,
#      the Vulkan loader packages, a manifest naming the commit; then --plan)
#   2. the device tool, one call, from the repository root:
#        run(command="bash scripts/device-check.sh", carry=[".devcheck"], timeout_s=600)
#      it ends within 9 minutes (each step under its cap; --plan lists them)
#      and writes under $OUT: summary.json, report.md, log.txt, metrics.csv,
#      dcnn-full.{onnx,card.json,doe.safetensors}
#   3. give_back; report.md's tables go into docs/benchmarks.md; the network
#      is scored here with nedrt eval (docs/benchmarks.md says how).
#
#   bash scripts/device-check.sh --plan     what travels (≤ 60 MiB) and each step's cap
#   OUT=$(mktemp -d) bash scripts/device-check.sh --smoke
#                                           every step at tiny sizes on this CPU (CI)
set -euo pipefail
cd "$(dirname "$0")/.."
# Here the trainer's torch is in .venv (scripts/test.sh); on the device
# machine, python3 is the one with PyTorch and CUDA.
py=python3
if [ -x .venv/bin/python ]; then py=.venv/bin/python; fi
exec "$py" tools/device/check.py "$@"
