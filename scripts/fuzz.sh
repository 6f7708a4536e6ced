#!/usr/bin/env bash
# Runs the fuzz targets (fuzz/fuzz_targets and fuzz/wire, docs/reliability.md) with
# cargo fuzz (libFuzzer, nightly toolchain), each for SECONDS, seeded from
# the repo's own files (fuzz/seeds/<target>). Findings land in
# fuzz/artifacts/<target>; the grown corpus in fuzz/corpus/<target> (not
# committed). A crash exits non-zero; make it a regression test (the
# target's seeds or a unit test) before fixing it.
#
#   bash scripts/fuzz.sh [SECONDS] [TARGET ...]   (default 60 s, every target)
#
# NEDRT_FUZZ_BUILD=dev builds the targets unoptimised (CI: about half the
# build time, several times fewer executions a second); the default,
# release, is for long runs.
#
# Prints one line per target: executions, coverage (libFuzzer's `cov`
# edges and `ft` features) and the corpus size.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-60}"
shift || true
if ! cargo +nightly --version >/dev/null 2>&1; then
    rustup toolchain install nightly --profile minimal
fi
if ! cargo fuzz --version >/dev/null 2>&1; then
    cargo install cargo-fuzz --locked
fi
# Two fuzz crates: fuzz/ (the parsers as the service and the commands run
# them, linking the service) and fuzz/wire (the wire format alone, linking
# nedrt-protocol only). Each target runs from the crate that has it.
fuzz_dirs=(fuzz fuzz/wire)
declare -A dir_of=()
all=()
for d in "${fuzz_dirs[@]}"; do
    while read -r t; do
        dir_of[$t]="$d"
        all+=("$t")
    done < <(cargo +nightly fuzz list --fuzz-dir "$d")
done
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    targets=("${all[@]}")
fi
for t in "${targets[@]}"; do
    if [ -z "${dir_of[$t]:-}" ]; then
        echo "no fuzz target $t (there are: ${all[*]})" >&2
        exit 2
    fi
done
# Rust code without unsafe blocks of its own: no sanitizer (-s none), so
# panics, overflows (debug assertions stay on), hangs and over-large
# allocations are what it finds, at several times the speed.
profile=(-O)
if [ "${NEDRT_FUZZ_BUILD:-release}" = dev ]; then profile=(--dev); fi
# Only the crates whose targets run are built.
for d in "${fuzz_dirs[@]}"; do
    for t in "${targets[@]}"; do
        if [ "${dir_of[$t]}" = "$d" ]; then
            cargo +nightly fuzz build --fuzz-dir "$d" "${profile[@]}" -s none >&2
            break
        fi
    done
done
status=0
for t in "${targets[@]}"; do
    mkdir -p "fuzz/corpus/$t" "fuzz/artifacts/$t" "fuzz/seeds/$t"
    log="fuzz/artifacts/$t/last-run.log"
    # -rss_limit_mb: the loaders' own caps keep a run far below this;
    # -timeout: one input taking seconds is a hang worth a look.
    if ! cargo +nightly fuzz run --fuzz-dir "${dir_of[$t]}" "${profile[@]}" -s none "$t" "fuzz/corpus/$t" "fuzz/seeds/$t" -- \
        -max_total_time="$seconds" -rss_limit_mb=3072 -timeout=10 -max_len=65536 \
        -print_final_stats=1 >"$log" 2>&1; then
        status=1
        echo "$t: FAILED, see $log and fuzz/artifacts/$t" >&2
        tail -n 30 "$log" >&2
    fi
    execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo "?")
    last=$(grep -E '^#[0-9]+' "$log" | tail -n 1 || true)
    cov=$(echo "$last" | grep -o 'cov: [0-9]*' | grep -o '[0-9]*' || echo "?")
    ft=$(echo "$last" | grep -o 'ft: [0-9]*' | grep -o '[0-9]*' || echo "?")
    corpus=$(ls "fuzz/corpus/$t" | wc -l)
    echo "$t: ${seconds} s, ${execs} executions, cov ${cov}, ft ${ft}, corpus ${corpus}"
done
exit $status
