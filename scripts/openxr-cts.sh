#!/usr/bin/env bash
# Khronos' OpenXR conformance test suite (OpenXR-CTS) against nedrt's OpenXR
# runtime, one test case at a time (issue 58; docs/openxr.md has the table).
#
#   scripts/openxr-cts.sh CTS_BUILD [--out DIR] [--plugin vulkan2|vulkan]
#                         [--validation] [--timeout SECONDS] [--only 'CATCH2 TEST SPEC']
#
# CTS_BUILD is the build folder of a KhronosGroup/OpenXR-CTS checkout, built
# as the CTS's own BUILDING.md says ("Linux Release"). This script does not
# build the CTS: it finds `conformance_cli` in that folder. It builds nedrt's
# runtime and service, starts `nedrt run --stereo --source socket` on the test
# panel (tests/data/small-panel.toml: 64×48 at 240 Hz, so that lavapipe keeps
# up), and runs every automated case (`exclude:[interactive]`) with the
# Vulkan plugin at API version 1.0 (nedrt is an OpenXR 1.0 runtime), each in
# its own process under a deadline, so that a crash or a hang is that case's
# result and the rest still run. --validation adds the CTS's optional checks
# that invalid handles and structure types are refused (-H -T; with them the
# CTS leaves out its conformance layer). The service is restarted before each case,
# so that no case inherits another's connection.
#
# It writes to DIR (default: a new folder under /tmp, printed at the end):
#   results.tsv   case, status (passed/failed/skipped/crashed/hung), first line
#   results.md    the same as a Markdown table, with the counts and commits
#   cases/N.*     each case's JUnit XML, its output, and the service's log
# and exits 0 when every case ran to an outcome (passed, failed or skipped),
# 1 when one crashed or hung, 2 on bad usage.
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$PWD

usage() {
    sed -n '4,6p' "$0" | sed 's/^# \{0,1\}//' >&2
    exit 2
}
[ $# -ge 1 ] || usage
cts_build=$1
shift
out="" plugin=vulkan2 timeout_s=300 only="" validation=()
value() { # the option's value, or a clear error
    [ $# -ge 2 ] || { echo "openxr-cts.sh: $1 needs a value" >&2; exit 2; }
}
while [ $# -gt 0 ]; do
    case $1 in
    --out) value "$@"; out=$2; shift 2 ;;
    --plugin) value "$@"; plugin=$2; shift 2 ;;
    --timeout) value "$@"; timeout_s=$2; shift 2 ;;
    --only) value "$@"; only=$2; shift 2 ;;
    --validation) validation=(--invalidHandleValidation --invalidTypeValidation); shift ;;
    *) echo "openxr-cts.sh: unknown argument '$1'" >&2; usage ;;
    esac
done
case $timeout_s in '' | *[!0-9]*)
    echo "openxr-cts.sh: --timeout $timeout_s: expected whole seconds" >&2
    exit 2
    ;;
esac
case $plugin in vulkan | vulkan2) ;; *)
    echo "openxr-cts.sh: --plugin $plugin: nedrt offers only the Vulkan plugins (vulkan, vulkan2)" >&2
    exit 2
    ;;
esac
cli=$(find "$cts_build" -type f -name conformance_cli -perm -u+x 2>/dev/null | head -1 || true)
if [ -z "$cli" ]; then
    echo "openxr-cts.sh: no conformance_cli under '$cts_build': build the CTS first, as its BUILDING.md says" >&2
    exit 2
fi
cli_dir=$(cd "$(dirname "$cli")" && pwd)
cts_src=$(sed -n 's/^CMAKE_HOME_DIRECTORY:INTERNAL=//p' "$cts_build/CMakeCache.txt" 2>/dev/null || true)
cts_commit=$(git -C "${cts_src:-$cts_build}" rev-parse HEAD 2>/dev/null || echo unknown)
[ -n "$out" ] || out=$(mktemp -d /tmp/nedrt-cts.XXXXXX)
mkdir -p "$out/cases"
out=$(cd "$out" && pwd)

echo "== building nedrt and its OpenXR runtime" >&2
cargo build --release --quiet -p nedrt --bin nedrt
cargo build --release --quiet -p nedrt-openxr --lib
nedrt=$repo/target/release/nedrt
cat >"$out/nedrt_openxr.json" <<EOF
{"file_format_version": "1.0.0", "runtime": {"name": "nedrt", "library_path": "$repo/target/release/libnedrt_openxr.so"}}
EOF
export XR_RUNTIME_JSON=$out/nedrt_openxr.json
export NEDRT_SOCKET=$out/nedrt.sock
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
export NEDRT_OPENXR_LOG=${NEDRT_OPENXR_LOG:-quiet}

service_pid=""
stop_service() {
    if [ -n "$service_pid" ]; then
        kill "$service_pid" 2>/dev/null || true
        wait "$service_pid" 2>/dev/null || true
        service_pid=""
    fi
}
trap stop_service EXIT
start_service() {
    rm -f "$NEDRT_SOCKET"
    NEDRT_LOG=nedrt=warn "$nedrt" --calib tests/data/small-panel.toml run --stereo \
        --backend cpu --preprocess conventional --source socket --socket "$NEDRT_SOCKET" \
        --sink headless >"$1" 2>&1 &
    service_pid=$!
    for _ in $(seq 100); do
        [ -S "$NEDRT_SOCKET" ] && return 0
        kill -0 "$service_pid" 2>/dev/null || break
        sleep 0.1
    done
    echo "openxr-cts.sh: the service did not open $NEDRT_SOCKET (log: $1)" >&2
    exit 1
}

spec="exclude:[interactive]"
[ -z "$only" ] || spec=$only
# The case names, one a line: Catch2's --list-tests at quiet verbosity, between
# the CTS's "Test names:" and its report's banner (it prints the list twice).
(cd "$cli_dir" && ./conformance_cli -G "$plugin" --apiVersion 1.0 --list-tests --verbosity quiet "$spec") |
    awk '/^Test names:/ {on = 1; next} /^\*/ {on = 0} on && NF && !seen[$0]++' >"$out/cases.txt"
total=$(wc -l <"$out/cases.txt")
echo "== $total cases, plugin $plugin, CTS $cts_commit; results in $out" >&2

printf 'case\tstatus\tfirst line\n' >"$out/results.tsv"
n=0
while IFS= read -r name; do
    n=$((n + 1))
    base=$out/cases/$n
    start_service "$base.service.log"
    # Catch2's test spec: a backslash escapes its special characters.
    escaped=$(printf '%s' "$name" | sed 's/[][\\,*"~]/\\&/g')
    set +e
    (cd "$cli_dir" && timeout -k 10 "$timeout_s" ./conformance_cli -G "$plugin" --apiVersion 1.0 \
        "${validation[@]}" --disableFileLineLogging --reporter "junit::out=$base.xml" --reporter console \
        "$escaped") >"$base.out" 2>&1
    rc=$?
    set -e
    stop_service
    python3 scripts/openxr-cts-case.py "$name" "$rc" "$base.xml" "$base.out" >>"$out/results.tsv"
    printf '%4d/%d %s\n' "$n" "$total" "$(tail -1 "$out/results.tsv" | cut -f1,2)" >&2
done <"$out/cases.txt"

python3 scripts/openxr-cts-case.py --table "$out/results.tsv" "$cts_commit" \
    "$(git rev-parse --short HEAD)" "$plugin${validation:+ with -H -T}" >"$out/results.md"
tail -n +2 "$out/results.tsv" | cut -f2 | sort | uniq -c >&2
echo "== $out/results.md" >&2
if cut -f2 "$out/results.tsv" | grep -qE '^(crashed|hung)$'; then exit 1; fi
