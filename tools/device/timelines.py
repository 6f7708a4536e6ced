"""What a device check's frame timelines say, case by case (docs/benchmarks.md,
"What the H200's timelines say about the steady state"): the figures quoted
there are this script's output on docs/devcheck/2026-11-28-h200-2/summary.json.

    python3 tools/device/timelines.py SUMMARY.json [--frames CASE [FIRST [COUNT]]]

With --frames, one case's frames instead ("model 1 f32": network, views,
precision), from the FIRST-th (0) on, COUNT of them (40), each with its
submission, predicted refresh, preprocess span and hold, ready, shown or
replaced, its present (the take to the present's end), ms, and the frame
budget's level it ran (`auto`; the log's `levels` name them); then the
present loop's refreshes over the same time: each refresh, its wake and
lead (the refresh less the wake), the frame taken and the present's end.

For each `frame_log` record of the pipeline step, over the frames after the
20th (in the log's order):
- the preprocess stage's own time (its span less the gate's hold) at p50 and
  p90, and its wall p50 (the hold in);
- how many frames the gate held back, and their hold's p50 and max;
- submission to the refresh predicted for the frame (its plan's lead), p50;
- the gaps between submissions at p10, p50 and p90;
- the present loop's lead (each refresh less its planned wake) over the
  refreshes after the 20th, p50;
- for `auto`, the frame budget's levels the frames after the 20th ran, by
  name and count;
- the pipeline's bound (mean + 4 deviations, the service's `Estimate` with
  its warm-up, in floating point) fed, frame by frame in the order they were
  taken, with submission to ready less the hold (the feed before
  2026-11-28), less also the queueing behind a held frame as far as its
  hold made it longer (the feed since), and with the frames' own work (their
  stages' spans less the hold); each bound's p50 after the 20th frame shown;
- the plan's lead that follows (docs/service.md, "Just in time"): a source
  submits a frame the pipeline's bound (the feed since), the present loop's
  lead and a 32nd of a refresh before the refresh it is made for, so its end
  to end p50 is at least their sum (the source's own making comes on top
  when it is quicker than its bound); set beside the refresh, this says
  whether a case can meet issue 39's line (p50 within one refresh) once the
  estimate has settled.
Then, where the logs have the device path's record and whole-submission
times (since issue 56's item 5), the stage's own time split p50 into its
stages on the device, the host's recording, the device's work beyond the
stages (the uploads' copies, unpacks, layers, encodes) and the rest (the
submission's and the fence's latency).
Percentiles are the sorted values' element at p·(n − 1), rounded down."""

import json
import sys
from pathlib import Path

SKIP = 20
DEVIATIONS = 4
WARM_UP = 8


class Estimate:
    """The service's `pacing::Estimate` in floating point: the first
    WARM_UP samples averaged plainly with the largest left out (the
    deviation at least half the mean shrunk by 3/4 a sample), then
    gains 1/8 and 1/4."""

    def __init__(self):
        self.mean, self.dev, self.first = 0.0, 0.0, []

    def observe(self, x: float):
        if len(self.first) < WARM_UP:
            self.first.append(x)
            kept = sorted(self.first)
            kept = kept if len(kept) == 1 else kept[:-1]
            self.mean = sum(kept) / len(kept)
            spread = sum(abs(v - self.mean) for v in kept) / len(kept)
            self.dev = max(spread, self.mean / 2 * 0.75 ** (len(kept) - 1))
        else:
            self.dev = (3 * self.dev + abs(x - self.mean)) / 4
            self.mean = (7 * self.mean + x) / 8

    def bound(self) -> float:
        return self.mean + DEVIATIONS * self.dev


def pct(values: list, p: float):
    v = sorted(values)
    return v[int(p * (len(v) - 1))] if v else None


def own_ms(f: dict) -> list:
    """Each frame's preprocess stage's own time: its span less the gate's hold."""
    return [s[1][1] - s[1][0] - h for s, h in zip(f["stages_ms"], f["held_ms"])]


def case(record: dict) -> dict:
    """The figures of one case's `frame_log` record (columns)."""
    f = record["frames"]
    n = len(f["id"])
    span = [s[1][1] - s[1][0] for s in f["stages_ms"]]
    held = f["held_ms"]
    own = own_ms(f)
    later = range(SKIP, n)
    holds = [held[i] for i in later if held[i] > 0]
    submitted = sorted(f["submitted_ms"])
    gaps = [b - a for a, b in zip(submitted[SKIP:], submitted[SKIP + 1:])]
    # The queueing behind a held frame: the wait before the preprocess
    # stage, at most the hold of the frame the stage took before it.
    behind, last_hold = [0.0] * n, 0.0
    for i in sorted(range(n), key=lambda i: f["stages_ms"][i][1][0]):
        wait = f["stages_ms"][i][1][0] - f["stages_ms"][i][0][1]
        behind[i], last_hold = max(0.0, min(wait, last_hold)), held[i]
    feeds = {
        "less_hold": lambda i: f["ready_ms"][i] - f["submitted_ms"][i] - held[i],
        "less_hold_and_behind": lambda i: f["ready_ms"][i] - f["submitted_ms"][i] - held[i] - behind[i],
        "own_work": lambda i: sum(b - a for a, b in f["stages_ms"][i]) - held[i],
    }
    shown = sorted((i for i in range(n) if f["outcome"][i] == "shown"), key=lambda i: f["taken_ms"][i])
    bounds = {}
    for name, feed in feeds.items():
        e, b = Estimate(), []
        for i in shown:
            e.observe(feed(i))
            b.append(e.bound())
        bounds[name] = pct(b[SKIP:], 0.5)
    # Each level the frames after the 20th ran, in the ladder's order.
    names, levels = record.get("levels") or [], f.get("level") or [None] * n
    counts = {}
    for i in later:
        if levels[i] is not None:
            counts[levels[i]] = counts.get(levels[i], 0) + 1
    ran = {(names[k] if k < len(names) else f"level {k}"): counts[k] for k in sorted(counts)}
    r = record.get("refreshes") or {}
    leads = [t - w for t, w in zip(r.get("refresh_ms", []), r.get("wake_ms", [])) if w is not None]
    lead_p50 = pct(leads[SKIP:], 0.5)
    return {
        "case": f"{record['network']} {record['views']} {record['precision']}",
        "lead_p50": lead_p50,
        "own_p50": pct([own[i] for i in later], 0.5), "own_p90": pct([own[i] for i in later], 0.9),
        "wall_p50": pct([span[i] for i in later], 0.5),
        "held": len(holds), "of": len(later), "held_p50": pct(holds, 0.5), "held_max": max(holds, default=None),
        "ahead_p50": pct([f["predicted_ms"][i] - f["submitted_ms"][i] for i in later], 0.5),
        "gap_p10": pct(gaps, 0.1), "gap_p50": pct(gaps, 0.5), "gap_p90": pct(gaps, 0.9),
        **{f"bound_{k}": v for k, v in bounds.items()},
        "levels": ", ".join(f"{k} {v}" for k, v in ran.items()) or "–",
        **plan(bounds["less_hold_and_behind"], lead_p50, record.get("refresh_hz")),
    }


def plan(bound, lead, refresh_hz) -> dict:
    """The plan's lead from submission to refresh (`DisplaySchedule::ahead_ns`
    less the source's making) and the refresh it is set against."""
    if bound is None or lead is None or not refresh_hz:
        return {"plan_ms": None, "refresh_ms": None}
    period = 1000.0 / refresh_hz
    return {"plan_ms": bound + lead + period / 32, "refresh_ms": period}


# The columns case() reads; a log without one (an older binary's) is left out.
NEEDS = ("id", "outcome", "held_ms", "submitted_ms", "predicted_ms", "stages_ms", "ready_ms", "taken_ms")


def table(logs: list) -> list:
    """The figures of every case with all the columns case() reads, as a
    Markdown table (the device check's report shows it too)."""
    ms = lambda v: "–" if v is None else f"{v:.2f}"
    rows = ["| case | own p50 ms | own p90 ms | wall p50 ms | held back | hold p50 / max ms | submitted ahead p50 ms "
            "| submission gaps p10/p50/p90 ms | present's lead p50 ms | bound p50 ms: less the hold "
            "| less also the queue behind it | own work | plan's lead ms (within a refresh) | levels run |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    within = lambda c: "–" if c["plan_ms"] is None else (
        f"{c['plan_ms']:.2f} ({'yes' if c['plan_ms'] <= c['refresh_ms'] else 'no'}: {c['refresh_ms']:.2f})")
    for r in logs:
        if not all(k in r.get("frames", {}) for k in NEEDS):
            continue
        c = case(r)
        rows.append(f"| {c['case']} | {ms(c['own_p50'])} | {ms(c['own_p90'])} | {ms(c['wall_p50'])} | "
                    f"{c['held']} of {c['of']} | {ms(c['held_p50'])} / {ms(c['held_max'])} | {ms(c['ahead_p50'])} | "
                    f"{ms(c['gap_p10'])} / {ms(c['gap_p50'])} / {ms(c['gap_p90'])} | {ms(c['lead_p50'])} | "
                    f"{ms(c['bound_less_hold'])} | {ms(c['bound_less_hold_and_behind'])} | {ms(c['bound_own_work'])} | "
                    f"{within(c)} | {c['levels']} |")
    return rows if len(rows) > 2 else []


# The columns overhead() reads besides NEEDS: the device path's record and
# device times (frame_gpu_ms since issue 56's item 5).
OVERHEAD = ("gpu_ms", "record_ms", "frame_gpu_ms")


def overhead(logs: list) -> list:
    """Where the preprocess stage's own time goes beyond its stages' device
    time (issue 56, item 5), p50 over the frames after the 20th that have
    every part, as a Markdown table: the host's recording up to the
    submission (the uploads' copies into staging memory and the passes'
    recording), the whole submission on the device less its stages (the
    uploads' copies, unpacks, layers and encodes), and the rest, the
    submission's and the fence's latency (own time less the record and the
    whole submission)."""
    ms = lambda v: "–" if v is None else f"{v:.2f}"
    rows = ["| case | own p50 ms | stages on GPU | record (host) | device beyond the stages "
            "| submission and fence | frames |",
            "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in logs:
        f = r.get("frames", {})
        if not all(k in f for k in NEEDS + OVERHEAD):
            continue
        later = [i for i in range(SKIP, len(f["id"]))
                 if f["record_ms"][i] is not None and f["frame_gpu_ms"][i] is not None]
        own = own_ms(f)
        stages = {i: f["gpu_ms"][i] or 0.0 for i in later}
        p50 = lambda g: pct([g(i) for i in later], 0.5)
        rows.append(f"| {r['network']} {r['views']} {r['precision']} | {ms(p50(lambda i: own[i]))} | "
                    f"{ms(p50(lambda i: stages[i]))} | {ms(p50(lambda i: f['record_ms'][i]))} | "
                    f"{ms(p50(lambda i: f['frame_gpu_ms'][i] - stages[i]))} | "
                    f"{ms(p50(lambda i: own[i] - f['record_ms'][i] - f['frame_gpu_ms'][i]))} | {len(later)} |")
    return rows if len(rows) > 2 else []


def frames(record: dict, first: int, count: int) -> list:
    """One case's frames as table rows, from the `first`-th on."""
    f, r = record["frames"], record.get("refreshes") or {}
    present = {(fr, t): p - t for fr, t, p in zip(r.get("frame", []), r.get("taken_ms", []),
                                               r.get("presented_ms", [])) if fr is not None and p is not None}
    ms = lambda v: "–" if v is None else f"{v:.2f}"
    names, levels = record.get("levels") or [], f.get("level") or [None] * len(f["id"])
    level_of = lambda i: "–" if levels[i] is None else (
        names[levels[i]] if levels[i] < len(names) else str(levels[i]))
    rows = ["| id | outcome | submitted | predicted | preprocess | held | ready | shown or replaced | present | level |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for i in range(first, min(first + count, len(f["id"]))):
        span = f["stages_ms"][i][1]
        end = f["shown_ms"][i] if f["outcome"][i] != "replaced" else f["replaced_ms"][i]
        rows.append(f"| {f['id'][i]} | {f['outcome'][i]} | {ms(f['submitted_ms'][i])} | {ms(f['predicted_ms'][i])} | "
                    f"{ms(span[1] - span[0])} | {ms(f['held_ms'][i])} | {ms(f['ready_ms'][i])} | {ms(end)} | "
                    f"{ms(present.get((f['id'][i], f['taken_ms'][i])))} | {level_of(i)} |")
    shown = range(first, min(first + count, len(f["id"])))
    if not r.get("refresh_ms") or not shown:
        return rows
    start = min(f["submitted_ms"][i] for i in shown)
    end = max(v for i in shown for v in (f["shown_ms"][i], f["replaced_ms"][i], f["ready_ms"][i]) if v is not None)
    rows += ["", "| refresh | wake | lead | frame | presented |", "| --- | --- | --- | --- | --- |"]
    for j, t in enumerate(r["refresh_ms"]):
        if start <= t <= end:
            frame = r["frame"][j]
            rows.append(f"| {ms(t)} | {ms(r['wake_ms'][j])} | {ms(t - r['wake_ms'][j])} | "
                        f"{'–' if frame is None else frame} | {ms(r['presented_ms'][j])} |")
    return rows


def main(argv: list) -> int:
    args = argv[1:]
    pick = None
    if len(args) >= 3 and args[1] == "--frames":
        try:
            extra = [int(a) for a in args[3:5]]
        except ValueError:
            extra = [-1]
        if len(args) > 5 or any(a < 0 for a in extra):
            args = []
        else:
            pick = (args[2], *extra, *(0, 40)[len(extra):])
            args = args[:1]
    if len(args) != 1:
        print("usage: timelines.py SUMMARY.json [--frames CASE [FIRST [COUNT]]]", file=sys.stderr)
        return 2
    path = Path(args[0])
    try:
        summary = json.loads(path.read_text())
        steps = summary["steps"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        print(f"timelines.py: {path}: not a device check's summary.json ({e})", file=sys.stderr)
        return 1
    logs = [r for s in steps if s.get("name") == "pipeline" for r in s.get("records", [])
            if r.get("kind") == "frame_log" and r.get("frames", {}).get("id")]
    if not logs:
        print(f"timelines.py: {path}: no frame timelines in its pipeline step", file=sys.stderr)
        return 1
    name = lambda r: f"{r['network']} {r['views']} {r['precision']}"
    if pick:
        record = next((r for r in logs if name(r) == pick[0]), None)
        if record is None:
            print(f"timelines.py: no case {pick[0]!r}; there are: {', '.join(name(r) for r in logs)}", file=sys.stderr)
            return 1
        print("\n".join(frames(record, pick[1], pick[2])))
        return 0
    rows = table(logs)
    if not rows:
        print(f"timelines.py: {path}: no case's timelines have every column ({', '.join(NEEDS)})", file=sys.stderr)
        return 1
    print("\n".join(rows))
    split = overhead(logs)
    if split:
        print("\nWhere the preprocess stage's own time goes beyond its stages (p50 ms):\n")
        print("\n".join(split))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
