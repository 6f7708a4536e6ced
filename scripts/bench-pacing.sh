#!/usr/bin/env bash
# The end-to-end latency of `nedrt run` against its stages' own time
# (issue 39, just-in-time presentation): the small test panel (240 Hz),
# no preprocessing, the pattern source, the headless sink, on whatever
# adapter wgpu finds (lavapipe here). Each run prints end-to-end p50, the
# stages' p50s summed (upload + dcnn + encode + present), the excess over
# them and the issue's bound (a third of a refresh); at the end each
# build's spread over its runs (min–max and median).
#
#   scripts/bench-pacing.sh                     # target/release/nedrt, 3 runs
#   RUNS=5 FRAMES=2000 scripts/bench-pacing.sh
#   BASE=/path/to/old/nedrt scripts/bench-pacing.sh   # interleaved with another build
#
# A benchmark, not a test: the machine's load moves every number.
set -euo pipefail
cd "$(dirname "$0")/.."
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
RUNS="${RUNS:-3}"
FRAMES="${FRAMES:-1000}"
NEW="${NEW:-target/release/nedrt}"
[ -x "$NEW" ] || { echo "$NEW: build it first (cargo build --release -p nedrt)" >&2; exit 1; }
binaries=("$NEW")
[ -n "${BASE:-}" ] && binaries=("$BASE" "$NEW")
json="$(mktemp)"
runs="$(mktemp)"
trap 'rm -f "$json" "$runs"' EXIT
for i in $(seq "$RUNS"); do
    for b in "${binaries[@]}"; do
        "$b" run --calib tests/data/small-panel.toml --preprocess conventional \
            --source pattern --sink headless --frames "$FRAMES" --report-json "$json" \
            >/dev/null 2>&1
        python3 - "$b" "$i" "$json" "$runs" <<'PY'
import json, sys
b, i, path, runs = sys.argv[1:]
r = json.load(open(path))
s = {x["stage"]: x for x in r["stages"]}
stages = sum(s[k]["p50_ms"] for k in ("upload", "preprocess", "encode", "present"))
e2e = s["end-to-end"]["p50_ms"]
third = 1000 / 240 / 3
print(f"{b} run {i}: end-to-end p50 {e2e:.3f} ms, stages {stages:.3f} ms, "
      f"excess {e2e - stages:.3f} ms (bound {third:.3f}); presented {r['presented']} "
      f"of {r['submitted']}, {r['missed_refreshes']} refreshes missed, "
      f"late {r.get('late', {}).get('count', 'n/a')}")
with open(runs, "a") as out:
    out.write(json.dumps({"build": b, "e2e": e2e, "stages": stages, "excess": e2e - stages,
                          "presented": r["presented"], "submitted": r["submitted"],
                          "late": r.get("late", {}).get("count")}) + "\n")
PY
    done
done
python3 - "$runs" <<'PY'
import json, statistics, sys
rows = [json.loads(line) for line in open(sys.argv[1])]
def spread(values, fmt):
    values = [v for v in values if v is not None]
    if not values:
        return "n/a"
    return f"{min(values):{fmt}}–{max(values):{fmt}} (median {statistics.median(values):{fmt}})"
for b in dict.fromkeys(r["build"] for r in rows):
    mine = [r for r in rows if r["build"] == b]
    print(f"{b}, {len(mine)} runs: excess {spread([r['excess'] for r in mine], '.3f')} ms "
          f"(bound {1000 / 240 / 3:.3f}), end-to-end p50 {spread([r['e2e'] for r in mine], '.3f')} ms, "
          f"presented {spread([r['presented'] for r in mine], '.0f')} of "
          f"{'/'.join(str(s) for s in sorted({r['submitted'] for r in mine}))}, "
          f"late {spread([r['late'] for r in mine], '.0f')}")
PY
