"""tools/bench/rounds.py without a GPU or a build: a stand-in program writes
the bench's JSON line and a frame log as `nedrt bench pipeline` does; the
rounds run interleaved, the table spreads each build's figures over its
rounds, replaced-early counts only replacements submitted before the cut,
the first frame's preprocess time and the next nine's median leave out the
gate's hold, the host's recording time is read where it is logged,
kept runs tabulate again alike, and a failed run, a missing frame log or a
bad argument is named, with a non-zero exit."""
import importlib.util
import json
import os
import stat
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("rounds", REPO / "tools" / "bench" / "rounds.py")
rounds = importlib.util.module_from_spec(spec)
spec.loader.exec_module(rounds)


def frame(id_, submitted_ms, outcome, preprocess_ms=None, held_ms=0.0, record_ms=None):
    f = {"id": id_, "submitted_ms": submitted_ms, "outcome": outcome, "held_ms": held_ms,
         "record_ms": record_ms}
    if preprocess_ms is not None:
        start = submitted_ms + 0.1
        f["stages_ms"] = [[submitted_ms, start], [start, start + preprocess_ms], [0.0, 0.0]]
    return f


def write_run(folder: Path, presented, dropped, late, e2e, ahead, frames):
    folder.mkdir(parents=True)
    record = {"kind": "pipeline", "network": "none", "frame_path": "device", "views": 1,
              "precision": "f32", "presented": presented, "dropped": dropped, "late": late,
              "e2e_p50_ms": e2e, "ahead_ms": ahead}
    (folder / "bench.jsonl").write_text(json.dumps(record) + "\n")
    log = {"network": "none", "frame_path": "device", "views": 1, "precision": "f32",
           "refresh_hz": 90.0, "frames": frames, "refreshes": []}
    (folder / "frames-none-device-f32.json").write_text(json.dumps(log))


def test_replaced_early_counts_only_replacements_before_the_cut():
    log = {"frames": [frame(0, 10.0, "replaced"), frame(1, 349.9, "replaced"),
                      frame(2, 350.0, "replaced"), frame(3, 20.0, "shown")]}
    assert rounds.replaced_early(log, 0.35) == 2
    assert rounds.replaced_early(log, 1.0) == 3


def test_the_preprocess_time_leaves_out_the_hold():
    log = {"frames": [frame(3, 40.0, "shown", 9.0, held_ms=4.0, record_ms=1.5),
                      frame(0, 0.0, "shown", 40.0, held_ms=30.0, record_ms=20.0),
                      frame(1, 20.0, "dropped"), frame(2, 30.0, "shown", 7.0, record_ms=0.5)]}
    first, nxt = rounds.preprocess_ms(log)
    assert first == pytest.approx(10.0) and nxt == pytest.approx(5.0)
    assert rounds.recorded_ms(log) == (20.0, 0.5)
    # An older build's log has no record_ms.
    assert rounds.recorded_ms({"frames": [frame(0, 0.0, "shown", 4.0)]}) == (None, None)
    assert rounds.preprocess_ms({"frames": [frame(0, 0.0, "dropped")]}) == (None, None)


def test_the_spread_is_the_range_and_the_median():
    assert rounds.spread([5, 1, 60], True) == "1–60 (5)"
    assert rounds.spread([3, 1, 4, 2], True) == "1–4 (2.5)"
    assert rounds.spread([2.0, None, 1.0, 9.0], False) == "1.00–9.00 (2.00)"
    assert rounds.spread([None], False) == "–"


def test_kept_runs_are_spread_per_build(tmp_path):
    # Run 1: frame 0 took 50 ms, the next nine 4–12 ms (median 8); one
    # frame held 3 ms of its 11 (own 8). Run 2: frame 0 took 30, frame 1 6.
    first = [frame(0, 5.0, "replaced", 50.0)] + [frame(i, 10.0 * i, "shown", 4.0 + i - 1)
                                                   for i in range(1, 10)]
    first += [frame(10, 100.0, "shown", 11.0, held_ms=3.0), frame(11, 900.0, "replaced", 99.0)]
    write_run(tmp_path / "before" / "1", 195, 5, 8, 8.0, 10.0, first)
    write_run(tmp_path / "before" / "2", 190, 10, 4, 7.0, 12.0,
              [frame(0, 5.0, "replaced", 30.0), frame(1, 6.0, "replaced", 6.0), frame(2, 7.0, "shown")])
    write_run(tmp_path / "after" / "1", 198, 2, 6, 7.5, 8.0, [frame(0, 5.0, "shown")])
    runs = rounds.summarise(tmp_path, 0.35)
    assert sorted(runs) == ["after", "before"]
    text = rounds.table(runs)
    before = next(l for l in text.splitlines() if "| before |" in l)
    cells = [c.strip() for c in before.strip("|").split("|")]
    assert cells == ["none, device, 1 view, f32", "before", "2", "190–195 (192.5) of 200",
                     "5–10 (7.5)", "1–2 (1.5)", "4–8 (6)", "7.00–8.00 (7.50)",
                     "10.00–12.00 (11.00)", "30.00–50.00 (40.00)", "6.00–8.00 (7.00)", "–", "–"]
    after = next(l for l in text.splitlines() if "| after |" in l)
    assert "| 198 (198) of 200 | 2 (2) | 0 (0) |" in after
    assert after.endswith("| – | – | – | – |")


def stand_in(tmp_path: Path, presented: int) -> Path:
    """A program that answers `--frame-log DIR` as the bench does and notes its calls."""
    program = tmp_path / f"nedrt-{presented}"
    program.write_text(textwrap.dedent(f"""\
        #!{sys.executable}
        import json, sys
        from pathlib import Path
        args = sys.argv[1:]
        folder = Path(args[args.index("--frame-log") + 1])
        with open({str(tmp_path / "calls")!r}, "a") as calls:
            calls.write("{presented} " + " ".join(args[:3]) + "\\n")
        print("a table line")
        print(json.dumps({{"kind": "pipeline", "network": "none", "frame_path": "device",
                          "views": 1, "precision": "f32", "presented": {presented},
                          "dropped": {200 - presented}, "late": 3, "e2e_p50_ms": 7.25,
                          "ahead_ms": 9.5}}))
        (folder / "frames-none-device-f32.json").write_text(json.dumps({{
            "network": "none", "frame_path": "device", "views": 1, "precision": "f32",
            "frames": [{{"id": 0, "submitted_ms": 1.0, "outcome": "replaced"}}]}}))
        """))
    program.chmod(program.stat().st_mode | stat.S_IEXEC)
    return program


def test_rounds_interleave_the_builds_and_keep_what_they_ran(tmp_path, capsys):
    old, new = stand_in(tmp_path, 190), stand_in(tmp_path, 199)
    keep = tmp_path / "kept"
    code = rounds.main(["--rounds", "2", "--build", f"old={old}", "--build", f"new={new}",
                        "--keep", str(keep), "--", "bench", "pipeline", "--networks", "none"])
    assert code == 0
    calls = (tmp_path / "calls").read_text().splitlines()
    assert calls == ["190 bench pipeline --networks", "199 bench pipeline --networks"] * 2
    out = capsys.readouterr().out
    assert "| none, device, 1 view, f32 | old | 2 | 190 (190) of 200 | 10 (10) |" in out
    assert "| new | 2 | 199 (199) of 200 | 1 (1) | 1 (1) |" in out
    assert sorted(p.name for p in (keep / "new").iterdir()) == ["1", "2"]
    again = rounds.table(rounds.summarise(keep, 0.35))
    assert again.strip() in out


def test_a_failed_run_is_named(tmp_path, capsys):
    bad = tmp_path / "bad"
    bad.write_text("#!/bin/sh\necho 'error: --panel: expected WxH' >&2\nexit 2\n")
    bad.chmod(0o755)
    code = rounds.main(["--build", f"x={bad}", "--", "bench", "pipeline"])
    err = capsys.readouterr().err
    assert code == 1 and f"{bad}: exit status 2" in err and "expected WxH" in err
    code = rounds.main(["--build", f"x={tmp_path / 'missing'}", "--", "bench", "pipeline"])
    assert code == 1 and "no such program" in capsys.readouterr().err


def test_a_kept_run_without_its_frame_log_is_named(tmp_path, capsys):
    write_run(tmp_path / "a" / "1", 195, 5, 8, 8.0, 10.0, [])
    os.remove(tmp_path / "a" / "1" / "frames-none-device-f32.json")
    assert rounds.main(["--summarise", str(tmp_path)]) == 1
    assert "no frame log for the case ('none', 'device', 1, 'f32')" in capsys.readouterr().err
    # A record without its case, and one without a figure.
    (tmp_path / "a" / "1" / "bench.jsonl").write_text('{"kind": "pipeline", "presented": 1}\n')
    assert rounds.main(["--summarise", str(tmp_path)]) == 1
    assert "a bench record without its case ('network')" in capsys.readouterr().err
    other = tmp_path / "other"
    write_run(other / "b" / "1", 195, 5, 8, 8.0, 10.0, [])
    record = json.loads((other / "b" / "1" / "bench.jsonl").read_text())
    del record["ahead_ms"]
    (other / "b" / "1" / "bench.jsonl").write_text(json.dumps(record) + "\n")
    assert rounds.main(["--summarise", str(other)]) == 1
    assert "lacks 'ahead_ms'" in capsys.readouterr().err
    assert rounds.main(["--summarise", str(tmp_path / "nothing")]) == 1
    assert "not a folder of kept runs" in capsys.readouterr().err


@pytest.mark.parametrize("args", [
    ["--", "bench", "pipeline"],
    ["--build", "noequals", "--", "bench", "pipeline"],
    ["--build", "a=x", "--build", "a=y", "--", "bench", "pipeline"],
    ["--build", "a=x", "--rounds", "0", "--", "bench", "pipeline"],
    ["--build", "a=x", "--", "bench", "fft"],
    ["--summarise", "somewhere", "--build", "a=x"],
    ["--build", "a=x", "--pause-s", "-1", "--", "bench", "pipeline"],
])
def test_bad_arguments_are_refused(args):
    with pytest.raises(SystemExit) as e:
        rounds.main(args)
    assert e.value.code == 2
