"""Rounds of `nedrt bench pipeline` for one or more builds, interleaved, and
each build's spread over the rounds (docs/benchmarks.md quotes its tables):

    python3 tools/bench/rounds.py --rounds 6 \\
        --build before=/tmp/old/nedrt --build after=target/release/nedrt \\
        [--pause-s 15] [--early-s 0.35] [--keep DIR] -- \\
        --design multifocal bench pipeline --networks none --frame-paths device \\
        --panel 480x270 --frames 200 --max-seconds 8
    python3 tools/bench/rounds.py --summarise DIR [--early-s 0.35]

Each round runs every build once, in the order given, with the arguments
after `--` and `--frame-log` added; the machine's load drifts, so builds
compared side by side share it. Per build and case (network, frame path,
views, precision), over the rounds, each as min–max (median): frames shown
of those submitted; dropped; replaced early (replaced in the present slot
by a newer frame, and submitted in the first --early-s seconds: the
warm-up's share of the drops); late; e2e p50; submitted ahead (the
bench's `ahead_ms`); the preprocess stage's own time (its span less the
gate's hold) of the first frame and the median (the lower middle) of the
next nine; and alike the host's time before the stage's submission
(`record_ms`, where the build logs it): the warm-up's cost. `--keep DIR`
keeps each run's bench records and frame logs (DIR/NAME/ROUND/, the
builds' order in DIR/builds.txt); `--summarise DIR` tabulates kept runs
again without running anything.

A benchmark, not a test: the machine's load moves every number."""

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# The table's columns, each a key of a run's row.
COLUMNS = ["shown", "dropped", "replaced early", "late", "e2e p50 ms", "submitted ahead ms",
           "first preprocess ms", "next 9 preprocess ms", "first recorded ms", "next 9 recorded ms"]
INTEGER = {"shown", "dropped", "replaced early", "late"}


class RoundsError(Exception):
    """A run or a kept file that cannot be read; the message names it."""


def case_key(record: dict) -> tuple:
    return (record["network"], record["frame_path"], int(record.get("views") or 1),
            record.get("precision", "f32"))


def bench_records(stdout: str, source: str) -> list:
    """The bench's per-case JSON lines (kind "pipeline") in its output."""
    records = []
    for line in stdout.splitlines():
        line = line.strip()
        if not line.startswith("{"):
            continue
        try:
            r = json.loads(line)
        except json.JSONDecodeError as e:
            raise RoundsError(f"{source}: a JSON line that does not parse: {e}") from None
        if r.get("kind") == "pipeline":
            records.append(r)
    if not records:
        raise RoundsError(f"{source}: no `bench pipeline` record (a JSON line of kind \"pipeline\")")
    return records


def replaced_early(frame_log: dict, early_s: float) -> int:
    return sum(1 for f in frame_log["frames"]
               if f.get("outcome") == "replaced" and f["submitted_ms"] < early_s * 1000.0)


def first_and_next(frame_log: dict, read) -> tuple:
    """A figure of the first frame to reach the preprocess stage and the
    median (the lower middle) of the next nine's, by id; None where there
    are none or the log lacks it (an older build's)."""
    values = {}
    for f in frame_log["frames"]:
        if len(f.get("stages_ms") or []) > 1:
            values[f["id"]] = read(f)
    ids = sorted(values)
    if not ids:
        return None, None
    nxt = [v for v in (values[i] for i in ids[1:10]) if v is not None]
    return values[ids[0]], (statistics.median_low(nxt) if nxt else None)


def preprocess_ms(frame_log: dict) -> tuple:
    """The preprocess stage's own time (its span less the gate's hold)."""
    return first_and_next(frame_log, lambda f: f["stages_ms"][1][1] - f["stages_ms"][1][0]
                          - (f.get("held_ms") or 0.0))


def recorded_ms(frame_log: dict) -> tuple:
    """The host's time before the stage's submission (`record_ms`): a
    pipeline built or a plan made in a frame shows here."""
    return first_and_next(frame_log, lambda f: f.get("record_ms"))


def frame_logs(folder: Path) -> dict:
    """The frame logs in a --frame-log folder, by case."""
    logs = {}
    for path in sorted(folder.glob("frames-*.json")):
        try:
            log = json.loads(path.read_text())
            logs[case_key(log)] = log
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
            raise RoundsError(f"{path}: not a frame log: {e}") from None
    return logs


def run_rows(records: list, logs: dict, early_s: float, source: str) -> list:
    """One row per case of a run: the record's figures and its early replacements."""
    rows = []
    for r in records:
        try:
            key = case_key(r)
        except (KeyError, TypeError, ValueError) as e:
            raise RoundsError(f"{source}: a bench record without its case ({e})") from None
        if key not in logs:
            raise RoundsError(f"{source}: no frame log for the case {key}")
        log = logs[key]
        try:
            first, nxt = preprocess_ms(log)
            first_rec, next_rec = recorded_ms(log)
            row = {"case": key, "shown": r["presented"], "dropped": r["dropped"],
                   "replaced early": replaced_early(log, early_s), "late": r["late"],
                   "e2e p50 ms": r["e2e_p50_ms"], "submitted ahead ms": r["ahead_ms"],
                   "first preprocess ms": first, "next 9 preprocess ms": nxt,
                   "first recorded ms": first_rec, "next 9 recorded ms": next_rec,
                   "submitted": r["presented"] + r["dropped"]}
        except (KeyError, TypeError, IndexError) as e:
            raise RoundsError(f"{source}: the record or frame log of {key} lacks {e}") from None
        rows.append(row)
    return rows


def spread(values: list, integer: bool) -> str:
    """min–max (median): a shared machine's bad round moves a mean, not a median."""
    values = [v for v in values if v is not None]
    if not values:
        return "–"
    median, lo, hi = statistics.median(values), min(values), max(values)
    if integer:
        span = f"{lo}" if lo == hi else f"{lo}–{hi}"
        return f"{span} ({median:g})"
    span = f"{lo:.2f}" if lo == hi else f"{lo:.2f}–{hi:.2f}"
    return f"{span} ({median:.2f})"


def table(runs: dict) -> str:
    """runs: build name → list of rounds, each a list of rows. Markdown."""
    cases = []
    for rounds in runs.values():
        for rows in rounds:
            for row in rows:
                if row["case"] not in cases:
                    cases.append(row["case"])
    lines = ["| case | build | rounds | " + " | ".join(COLUMNS) + " |",
             "| --- | --- | ---: | " + " | ".join("---" for _ in COLUMNS) + " |"]
    for case in cases:
        network, path, views, precision = case
        label = f"{network}, {path}, {views} view{'s' if views > 1 else ''}, {precision}"
        for name, rounds in runs.items():
            rows = [row for rows in rounds for row in rows if row["case"] == case]
            if not rows:
                continue
            submitted = sorted({row["submitted"] for row in rows})
            cells = []
            for column in COLUMNS:
                cell = spread([row[column] for row in rows], column in INTEGER)
                if column == "shown":
                    cell += f" of {'/'.join(str(s) for s in submitted)}"
                cells.append(cell)
            lines.append(f"| {label} | {name} | {len(rows)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def run_once(binary: str, bench_args: list, folder: Path, timeout_s: float):
    """One run into `folder`: its JSON lines kept as bench.jsonl beside its frame logs."""
    folder.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.setdefault("XDG_RUNTIME_DIR", "/tmp")
    try:
        done = subprocess.run([binary, *bench_args, "--frame-log", str(folder)], env=env,
                              capture_output=True, text=True, timeout=timeout_s)
    except FileNotFoundError:
        raise RoundsError(f"{binary}: no such program (build it first)") from None
    except subprocess.TimeoutExpired:
        raise RoundsError(f"{binary}: still running after {timeout_s:.0f} s") from None
    if done.returncode != 0:
        tail = "\n".join(done.stderr.strip().splitlines()[-5:])
        raise RoundsError(f"{binary}: exit status {done.returncode}\n{tail}")
    (folder / "bench.jsonl").write_text(
        "".join(line + "\n" for line in done.stdout.splitlines() if line.startswith("{")))


def read_run(folder: Path, early_s: float) -> list:
    path = folder / "bench.jsonl"
    try:
        text = path.read_text()
    except OSError as e:
        raise RoundsError(f"{path}: {e.strerror}") from None
    return run_rows(bench_records(text, str(path)), frame_logs(folder), early_s, str(folder))


def summarise(root: Path, early_s: float) -> dict:
    """Kept runs, ROOT/NAME/ROUND/, back into build name → rounds."""
    if not root.is_dir():
        raise RoundsError(f"{root}: not a folder of kept runs")
    order = root / "builds.txt"
    names = order.read_text().split() if order.is_file() else sorted(
        p.name for p in root.iterdir() if p.is_dir())
    runs = {}
    for build in (root / name for name in names):
        if not build.is_dir():
            raise RoundsError(f"{order}: names {build.name}, which has no folder")
        rounds = sorted((p for p in build.iterdir() if p.is_dir() and p.name.isdigit()),
                        key=lambda p: int(p.name))
        if rounds:
            runs[build.name] = [read_run(p, early_s) for p in rounds]
    if not runs:
        raise RoundsError(f"{root}: no kept runs (NAME/ROUND/bench.jsonl)")
    return runs


def parse_build(text: str) -> tuple:
    name, sep, binary = text.partition("=")
    if not sep or not name or not binary or "/" in name:
        raise argparse.ArgumentTypeError(f"--build {text!r}: expected NAME=PROGRAM (NAME without '/')")
    return name, binary


def main(argv: list) -> int:
    own, bench_args = (argv[:argv.index("--")], argv[argv.index("--") + 1:]) if "--" in argv else (argv, [])
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--build", action="append", type=parse_build, default=[],
                   help="NAME=PROGRAM, a build to run each round (in the order given)")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--early-s", type=float, default=0.35,
                   help="frames submitted before this are the warm-up's (replaced early)")
    p.add_argument("--keep", type=Path, help="keep each run's records in KEEP/NAME/ROUND/")
    p.add_argument("--summarise", type=Path, help="tabulate runs kept with --keep; run nothing")
    p.add_argument("--pause-s", type=float, default=0.0,
                   help="idle this long before each run (a shared machine's CPU slows under long load)")
    p.add_argument("--timeout-s", type=float, default=600.0, help="the longest one run may take")
    a = p.parse_args(own)
    try:
        if a.summarise:
            if a.build or bench_args:
                p.error("--summarise runs nothing: no --build and no bench arguments")
            print(table(summarise(a.summarise, a.early_s)))
            return 0
        if not a.build:
            p.error("at least one --build NAME=PROGRAM")
        if not bench_args or "pipeline" not in bench_args:
            p.error("the `bench pipeline` arguments after `--`")
        if a.rounds < 1:
            p.error("--rounds must be at least 1")
        if a.pause_s < 0:
            p.error("--pause-s must not be negative")
        names = [n for n, _ in a.build]
        if len(set(names)) != len(names):
            p.error("each --build needs a name of its own")
        root = a.keep or Path(tempfile.mkdtemp(prefix="nedrt-rounds-"))
        try:
            root.mkdir(parents=True, exist_ok=True)
            (root / "builds.txt").write_text("".join(n + "\n" for n in names))
            runs = {name: [] for name in names}
            for i in range(1, a.rounds + 1):
                for name, binary in a.build:
                    folder = root / name / str(i)
                    if folder.exists():
                        shutil.rmtree(folder)
                    time.sleep(a.pause_s)
                    run_once(binary, bench_args, folder, a.timeout_s)
                    rows = read_run(folder, a.early_s)
                    runs[name].append(rows)
                    for row in rows:
                        print(f"round {i} {name} {row['case'][0]}: shown {row['shown']} of "
                              f"{row['submitted']}, dropped {row['dropped']}, replaced early "
                              f"{row['replaced early']}, late {row['late']}, e2e p50 "
                              f"{row['e2e p50 ms']:.2f} ms, ahead {row['submitted ahead ms']:.2f} ms",
                              file=sys.stderr, flush=True)
            print(table(runs))
        finally:
            if not a.keep:
                shutil.rmtree(root, ignore_errors=True)
    except RoundsError as e:
        print(f"rounds: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
