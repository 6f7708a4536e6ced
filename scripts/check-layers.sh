#!/usr/bin/env bash
# The layering of docs/ARCHITECTURE.md, checked from Cargo's own view:
# each library crate depends only on the nedrt crates below it, none of them
# depends (directly) on clap, indicatif or anyhow, and none reads the
# environment outside its tests; and no module imports in a circle, neither
# in the Rust library crates nor in the trainer (tools/layers/import_cycles.py);
# and no library crate's pub fn or trait method returns Result<_, String>
# (tools/layers/string_errors.py); and no source file, Rust or Python,
# holds over 550 lines outside its tests nor a crate over 25 % of the Rust
# lines (tools/layers/sizes.py). Exit 1 naming every violation.
set -euo pipefail
cd "$(dirname "$0")/.."

declare -A allowed=(
    [nedrt-core]=""
    [nedrt-gpu]=""
    [nedrt-protocol]=""
    [nedrt-openxr]="nedrt-protocol"
    [nedrt-optics]="nedrt-core"
    [nedrt-infer]="nedrt-core nedrt-gpu"
    [nedrt-service]="nedrt-core nedrt-gpu nedrt-protocol"
    [nedrt-stages]="nedrt-core nedrt-gpu nedrt-optics nedrt-infer"
    [nedrt-command]="nedrt-core nedrt-gpu nedrt-protocol nedrt-optics nedrt-infer nedrt-service nedrt-stages"
    [nedrt-run]="nedrt-core nedrt-gpu nedrt-protocol nedrt-optics nedrt-infer nedrt-service nedrt-stages nedrt-command"
    [nedrt-app]="nedrt-core nedrt-gpu nedrt-protocol nedrt-optics nedrt-infer nedrt-service nedrt-stages nedrt-command"
    [nedrt-studies]="nedrt-core nedrt-gpu nedrt-protocol nedrt-optics nedrt-infer nedrt-service nedrt-stages nedrt-command nedrt-run nedrt-app"
)
declare -A dir=(
    [nedrt-core]=core [nedrt-gpu]=gpu [nedrt-protocol]=protocol [nedrt-openxr]=openxr [nedrt-optics]=optics
    [nedrt-infer]=infer [nedrt-service]=service [nedrt-stages]=stages [nedrt-command]=command
    [nedrt-run]=run [nedrt-app]=app
    [nedrt-studies]=studies
)
status=0
for crate in "${!allowed[@]}"; do
    deps=$(cargo tree -p "$crate" -e normal --depth 1 --prefix none \
        | tail -n +2 | awk '{print $1}')
    for d in $deps; do
        case "$d" in
        clap | indicatif | anyhow)
            echo "$crate depends on $d (command-line crates belong to the binary)"
            status=1
            ;;
        nedrt*)
            if [[ " ${allowed[$crate]} " != *" $d "* ]]; then
                echo "$crate depends on $d, which is not below it"
                status=1
            fi
            ;;
        esac
    done
    # Reading the environment: only the binary (and test code) may, and the
    # OpenXR runtime, which is loaded into an application and has no
    # command line: its settings are the environment (docs/openxr.md).
    if [ "$crate" = nedrt-openxr ]; then continue; fi
    hits=$(grep -rnE 'env::var|env::vars|current_dir\(\)|from_env\(|with_env\(' \
        "runtime/${dir[$crate]}/src" --include='*.rs' \
        | grep -vE '(/tests\.rs|_tests\.rs|/tests/):' || true)
    if [ -n "$hits" ]; then
        echo "$crate reads the environment:"
        echo "$hits"
        status=1
    fi
done
# A protocol client links nothing of the GPU or the window: the OpenXR
# runtime is loaded into every XR application, the protocol crate into
# every client.
for crate in nedrt-protocol nedrt-openxr; do
    heavy=$(cargo tree -p "$crate" -e normal --prefix none | awk '{print $1}' \
        | grep -xE 'wgpu|wgpu-core|wgpu-hal|winit|nedrt-service|nedrt-gpu' | sort -u || true)
    if [ -n "$heavy" ]; then
        echo "$crate links" $heavy
        status=1
    fi
done
# Import loops: between sibling modules of a Rust library crate, or between
# the trainer's modules (function-level imports included).
if ! cycles=$(python3 tools/layers/import_cycles.py 2>&1); then
    echo "$cycles"
    status=1
fi
# String errors: a library's public function or trait method returns a
# typed error, not Result<_, String> (FromStr's Err and test code excepted).
if ! strings=$(python3 tools/layers/string_errors.py 2>&1); then
    echo "$strings"
    status=1
fi
# Flag names only in the binary and the commands' wiring: the crates below
# nedrt-command return typed errors, the binary adds what to type.
if ! flags=$(python3 tools/layers/flag_names.py 2>&1); then
    echo "$flags"
    status=1
fi
# Sizes: no Rust or Python source file over 550 lines outside its tests
# (the trainer, tools/, scripts/, bench/ and the rest of the repository's
# Python too), no crate over a quarter of the Rust lines (a newcomer reads a
# crate as one kind of thing).
if ! sizes=$(python3 tools/layers/sizes.py 2>&1); then
    echo "$sizes"
    status=1
fi
if [ "$status" = 0 ]; then
    echo "layers: every library crate depends only on the crates below it; none on clap, indicatif or anyhow; none reads the environment (the OpenXR runtime excepted); nedrt-protocol and nedrt-openxr link no wgpu or winit; no import cycle in the Rust library crates nor in the trainer; no public function or trait method of a library crate returns Result<_, String>; no library below the commands' wiring names a command-line flag; no Rust or Python source file over 550 lines outside tests, no crate over 25 % of the Rust lines"
fi
exit "$status"
