#!/usr/bin/env bash
# The device check (issues 29 and 38): every figure a lent accelerator can
# give, in two calls of the device tool (docs/benchmarks.md, "On a lent
# accelerator").
#
# How to launch it on the accelerator machine:
#   1. here, once per commit:  bash scripts/device-check.sh --prepare
#      (builds .devcheck/: the release binary, stripped and xz-compressed,
#      the Vulkan loader packages, a manifest naming the commit; then --plan)
#   2. the device tool, two calls from the repository root, the second right
#      after the first on the warm machine:
#        run(command="bash scripts/device-check.sh", carry=[".devcheck"], timeout_s=600)
#        run(command="bash scripts/device-check.sh --call 2", carry=[".devcheck"], timeout_s=270)
#      each ends within its envelope (each step under its cap; --plan lists
#      them) and writes under $OUT: summary.json, report.md, log.txt; the
#      first also metrics.csv, checkpoint/ (the continued carried checkpoint:
#      card.json and its tensors file; docs/training.md says how to commit it)
#      and dcnn-full.{onnx,card.json}; the second tradeoff.{md,json,svg,png}
#   3. give_back; report.md's tables go into docs/benchmarks.md; the network
#      is scored, logged and shipped if it passes with `nedrt-train judge` (docs/training.md).
#
#   bash scripts/device-check.sh --plan     what travels (≤ 60 MiB), each call's steps and caps
#   OUT=$(mktemp -d) bash scripts/device-check.sh --smoke
#                                           every call's steps at tiny sizes on this CPU (CI);
#                                           needs the trainer's .venv (bash scripts/test.sh makes it)
set -euo pipefail
cd "$(dirname "$0")/.."
# Here the trainer's torch is in .venv (scripts/test.sh); on the device
# machine, python3 is the one with PyTorch and CUDA.
py=python3
if [ -x .venv/bin/python ]; then py=.venv/bin/python; fi
exec "$py" tools/device/check.py "$@"
