#!/usr/bin/env bash
# nedrt's own kernels at several commits, timed one after another in one
# sitting: for each COMMIT, checks it out in a temporary git worktree, builds
# this harness against that commit's runtime (burn's build is shared through
# this folder's target/, so only nedrt and the harness compile) and times
# nedrt alone (--only nedrt). Flags after "--" go to the binary (default:
# --models dcnn --sizes 64,256 --iters 3). Needs the harness built once
# (./run.sh or cargo build --release) and models/dcnn_w32.onnx for the
# full-width model (./make-models.sh). Rebuilds the current tree's binary
# at the end.
#
#   ./history.sh f4bb6de 8cf95ec HEAD -- --models dcnn --sizes 64,256 --iters 3
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
repo=$(git -C "$here" rev-parse --show-toplevel)
commits=()
args=()
while [ $# -gt 0 ]; do
    if [ "$1" = -- ]; then
        shift
        args=("$@")
        break
    fi
    commits+=("$1")
    shift
done
if [ ${#commits[@]} -eq 0 ]; then
    echo "usage: $0 COMMIT... [-- flags of nedrt-bench-burn]" >&2
    exit 2
fi
[ ${#args[@]} -gt 0 ] || args=(--models dcnn --sizes 64,256 --iters 3)
for c in "${commits[@]}"; do
    git -C "$repo" rev-parse --verify -q "$c^{commit}" > /dev/null || {
        echo "$0: '$c' is not a commit of $repo" >&2
        exit 2
    }
    git -C "$repo" cat-file -e "$c:bench/burn/Cargo.toml" 2> /dev/null || {
        echo "$0: commit '$c' has no bench/burn (it predates the harness)" >&2
        exit 2
    }
done
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
export CARGO_TARGET_DIR="$here/target"
tmp=$(mktemp -d)
cleanup() {
    git -C "$repo" worktree remove --force "$tmp/wt" 2> /dev/null || true
    rm -rf "$tmp"
}
trap cleanup EXIT
echo "nedrt alone (--only nedrt ${args[*]}), $(date -u +%F), $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg)"
echo
for c in "${commits[@]}"; do
    git -C "$repo" worktree add --detach -q "$tmp/wt" "$c"
    # The full-width model is made, not committed (models/.gitignore).
    mkdir -p "$tmp/wt/bench/burn/models"
    cp "$here"/models/*.onnx "$tmp/wt/bench/burn/models/" 2> /dev/null || true
    (cd "$tmp/wt/bench/burn" && cargo build --release -q -j"${JOBS:-2}")
    echo "## $(git -C "$repo" log -1 --format='%h %s' "$c" | cut -c1-120)"
    echo
    echo "| model | size | GMAC | iters | nedrt median ms | nedrt p90 ms | nedrt device ms | burn median ms | burn p90 ms | nedrt : burn | max abs diff (÷ branch) | first run ms nedrt / burn | GMAC/s nedrt / burn |"
    echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    (cd "$tmp/wt/bench/burn" &&
        "$CARGO_TARGET_DIR/release/nedrt-bench-burn" --only nedrt "${args[@]}" 2> "$tmp/err" ||
        { cat "$tmp/err" >&2; exit 1; }) | grep '^| ' | grep -v '^| model\|^|---'
    echo
    git -C "$repo" worktree remove --force "$tmp/wt"
done
(cd "$here" && cargo build --release -q -j"${JOBS:-2}")
