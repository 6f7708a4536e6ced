#!/usr/bin/env bash
# How fast the focus viewer draws (docs/benchmarks.md, "The focus viewer"):
# the shipped 512×512 test image, release build, PSF cache warm (the first
# run computes it). Prints
#  1. `nedrt sweep` over 0–3 D in 0.1 D steps, one method and three: the
#     perceived images a second the CPU renders (no memo: every depth new);
#  2. with an X display (Xvfb is started if none) and xdotool: the window,
#     30 presses of → 0.4 s apart, then q: pictures drawn, median render and
#     present times (on whatever adapter wgpu picks; lavapipe here).
#
#   bash scripts/bench-viewer.sh
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q -p nedrt
nedrt=target/release/nedrt
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for methods in conventional conventional,ai,proposed; do
    echo "== sweep, $methods"
    "$nedrt" sweep --methods "$methods" --out "$out/s.png" 2>/dev/null | grep -E "rendered|wrote"
done
if ! command -v xdotool >/dev/null 2>&1; then
    echo "not run: the window (needs xdotool)"
    exit 0
fi
if [ -z "${DISPLAY:-}" ]; then
    Xvfb :93 -screen 0 1920x1080x24 -nolisten tcp -noreset >/dev/null 2>&1 &
    xvfb=$!
    trap 'kill $xvfb 2>/dev/null || true; rm -rf "$out"' EXIT
    export DISPLAY=:93
    sleep 1
fi
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
for methods in conventional conventional,ai,proposed; do
    echo "== window, $methods"
    "$nedrt" view --methods "$methods" --accom 0 >"$out/view.log" 2>&1 &
    pid=$!
    window=$(xdotool search --sync --name "^nedrt view$" | head -n 1)
    sleep 5
    xdotool windowfocus "$window"
    sleep 0.3
    for _ in $(seq 30); do xdotool key Right; sleep 0.4; done
    sleep 3
    xdotool key q
    wait "$pid"
    grep -E "window:|closed" "$out/view.log"
done
