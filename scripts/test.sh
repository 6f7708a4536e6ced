#!/usr/bin/env bash
# Every test of the project: formatting, lints, Rust unit and integration
# tests, and the Python cross-checks. Installs the Python test tools into
# .venv on first use, so it works on a fresh machine with a Rust toolchain
# and python3. The README's test command; CI runs it through .ci/run.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ ! -x .venv/bin/python ]; then
    python3 -m venv .venv
fi
.venv/bin/python -m pip install --quiet --disable-pip-version-check \
    -r tests/python/requirements.txt -r models/requirements.txt "setuptools>=70.1"
# The trainer as a package (models/pyproject.toml, the `nedrt-train` command),
# editable; built with the venv's setuptools, so it needs no network.
.venv/bin/python -m pip install --quiet --disable-pip-version-check --no-build-isolation -e models

# The ort backend's tests load ONNX Runtime from the onnxruntime wheel just installed.
ORT_DYLIB_PATH="$(ls "$PWD"/.venv/lib/python3*/site-packages/onnxruntime/capi/libonnxruntime.so.* | head -n 1)"
export ORT_DYLIB_PATH NEDRT_REQUIRE_ORT=1
# GPU tests run on any Vulkan adapter (Mesa's lavapipe in CI, which sets
# NEDRT_REQUIRE_GPU=1); without one they say why they skip.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"

# The window test needs an X display: without one, start a private Xvfb
# (if installed) for the duration of the tests.
if [ -z "${DISPLAY:-}" ] && command -v Xvfb >/dev/null 2>&1; then
    for n in $(seq 90 120); do
        if [ ! -e "/tmp/.X11-unix/X$n" ] && [ ! -e "/tmp/.X$n-lock" ]; then
            Xvfb ":$n" -screen 0 1024x768x24 -nolisten tcp >/dev/null 2>&1 &
            xvfb_pid=$!
            trap 'kill $xvfb_pid 2>/dev/null || true' EXIT
            export DISPLAY=":$n"
            for _ in $(seq 50); do [ -e "/tmp/.X11-unix/X$n" ] && break; sleep 0.1; done
            break
        fi
    done
fi

echo "== cargo fmt --check"
cargo fmt --all --check
echo "== cargo clippy --all-targets -- -D warnings"
cargo clippy --all-targets -- -D warnings
echo "== cargo test --release"
cargo test --release --workspace
echo "== pytest tests/python models/tests"
# One thread: OpenMP busy-waiting makes two threads slower on a shared 2-core machine.
OMP_NUM_THREADS=1 .venv/bin/python -m pytest -q -W ignore::DeprecationWarning tests/python models/tests
