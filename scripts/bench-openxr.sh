#!/usr/bin/env bash
# The OpenXR runtime's copy-out on this machine (docs/openxr.md): the
# `openxr` crate's client renders N frames through libnedrt_openxr.so into a
# running `nedrt run --stereo --source socket --sink headless` on the shipped
# calibration (1920×1080, two 960×1080 views), and the runtime's summary
# gives the copy-out's mean per image and how its predicted display times
# held; the client gives xrEndFrame's time per frame (copy-out of both eyes,
# conversion and the two sends). Needs the OpenXR loader and a Vulkan
# adapter (lavapipe here).
#   scripts/bench-openxr.sh [FRAMES] [--calib FILE]
set -euo pipefail
cd "$(dirname "$0")/.."
frames="${1:-200}"
shift || true
cargo build --release -q -p nedrt -p nedrt-openxr --bins --lib --examples
dir="$(mktemp -d)"
trap 'kill "$service" 2>/dev/null || true; rm -rf "$dir"' EXIT
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
target/release/nedrt "$@" run --stereo --preprocess conventional --backend cpu \
    --source socket --socket "$dir/nedrt.sock" --sink headless \
    --report-json "$dir/report.json" >"$dir/service.log" 2>&1 &
service=$!
for _ in $(seq 100); do [ -e "$dir/nedrt.sock" ] && break; sleep 0.1; done
printf '{"file_format_version": "1.0.0", "runtime": {"name": "nedrt", "library_path": "%s"}}\n' \
    "$PWD/target/release/libnedrt_openxr.so" >"$dir/manifest.json"
XR_RUNTIME_JSON="$dir/manifest.json" NEDRT_SOCKET="$dir/nedrt.sock" \
    target/release/examples/openxr_client --frames "$frames" --report "$dir/client.json" \
    2> >(grep nedrt-openxr >&2 || true)
# The service's report: the client's frames shown at, after or before the
# display time each was rendered for.
kill -TERM "$service"
wait "$service" || true
python3 - "$dir/client.json" "$dir/report.json" <<'PY'
import json, statistics, sys
c = json.load(open(sys.argv[1]))
for cl in json.load(open(sys.argv[2])).get("clients", []):
    if cl["client"] > 0:
        print(f"service: client {cl['client']}: {cl['shown']} shown, {cl['on_time']} at their display time, "
              f"{cl['late']} late, {cl['early']} early; submitted {cl['mean_lead_ms']:.2f} ms ahead on average")
t = sorted(c["end_frame_ms"])
print(f"client: {c['frames']} frames, views {c['view_sizes']}; xrEndFrame median {statistics.median(t):.2f} ms, "
      f"p10 {t[len(t)//10]:.2f}, p90 {t[9*len(t)//10]:.2f} ms")
PY
