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
    -r tests/python/requirements.txt -r models/requirements.txt

echo "== cargo fmt --check"
cargo fmt --all --check
echo "== cargo clippy --all-targets -- -D warnings"
cargo clippy --all-targets -- -D warnings
echo "== cargo test --release"
cargo test --release --workspace
echo "== pytest tests/python models/tests"
# One thread: OpenMP busy-waiting makes two threads slower on a shared 2-core machine.
OMP_NUM_THREADS=1 .venv/bin/python -m pytest -q -W ignore::DeprecationWarning tests/python models/tests
