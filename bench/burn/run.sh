#!/usr/bin/env bash
# Makes the full-width model if it is missing, builds (release, one job by
# default: JOBS=N for more) and runs the benchmark; arguments go to the binary,
# e.g. ./run.sh --json out/burn-bench.json
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
cd "$here"
[ -f models/dcnn_w32.onnx ] || ./make-models.sh
cargo build --release -j"${JOBS:-1}"
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
exec ./target/release/nedrt-bench-burn "$@"
