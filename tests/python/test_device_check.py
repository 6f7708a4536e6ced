"""tools/device/check.py (scripts/device-check.sh) and its modules without
running their steps (CI runs `--smoke`, which runs them all): the plan
counts what travels as the device tool does and refuses more than the
limit; each call's caps fit its envelope, the first with time left to
train, and both calls fit the device time a task is lent; the report
renders a run whose steps failed or found no figures, and the new tables
(the adapter's cooperative matrices, wall and GPU time, refine:10 per
frame, the tradeoff); a bad --only or --call is refused; the smoke without
the trainer's .venv says how to make it; side-by-side commands run no more
at once than memory holds and a killed one is named; what a call brings
back fits the tool's 8 files; the continued checkpoint that comes back is
checked against its card, and the report says where the training started;
the OpenXR step's runtime and client are unpacked from what travels (the
2026-11-27 device run failed there: a local helper hid `unpack`); a case's
frame timelines come back as one record, column by column, and the report
shows their steady state as timelines.py does."""
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("device_check", REPO / "tools" / "device" / "check.py")
check = importlib.util.module_from_spec(spec)
spec.loader.exec_module(check)
# Loading check.py puts tools/device on the path, so its modules import by name.
import check_report  # noqa: E402
import check_runner  # noqa: E402
import check_steps  # noqa: E402
import check_openxr  # noqa: E402
import check_train  # noqa: E402
import check_travel  # noqa: E402
import timelines  # noqa: E402


def test_the_plan_counts_every_tracked_file():
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, text=True,
                            check=True, timeout=120).stdout.split("\0")
    tracked = sum((REPO / p).stat().st_size for p in listed if p and (REPO / p).is_file())
    items = dict(check_travel.travelling())
    assert sum(n for p, n in items.items() if p in set(listed)) == tracked
    assert all(not p.startswith((".venv/", "target/")) for p in items)


def test_the_plan_refuses_more_than_the_limit(monkeypatch, capsys):
    monkeypatch.setattr(check_travel, "TRAVEL_LIMIT", 1)
    assert check_travel.plan() == 1
    captured = capsys.readouterr()
    assert "over" in captured.err
    # Both calls are named with their commands.
    assert 'run(command="bash scripts/device-check.sh --call 2"' in captured.out


def test_the_caps_fit_the_envelopes_and_leave_time_to_train():
    fixed = sum(c for n, _, c in check_steps.caps(1) if n != "train")
    assert fixed + check_runner.AFTER_TRAIN_S < check_runner.ENVELOPE_S
    # The training gets at least two and a half minutes, whatever the benchmarks take.
    assert check_runner.ENVELOPE_S - fixed >= 150
    # One tool call is at most 600 s, with a minute for its start and $OUT.
    assert check_runner.ENVELOPE_S <= 540 and check_runner.ENVELOPE2_S <= 540
    second = check_steps.caps(2)
    assert [n for n, _, _ in second] == ["setup", "openxr", "tune", "tradeoff"]
    assert sum(c for _, _, c in second) <= check_runner.ENVELOPE2_S
    # Both calls and a machine's start within a task's device time.
    assert check_runner.START_S + check_runner.ENVELOPE_S + check_runner.ENVELOPE2_S < check_runner.DEVICE_TIME_S
    # Every step belongs to a call, and the smoke (all calls) runs each once.
    assert {n for n, *_ in check_steps.STEPS} == {n for n, _, _ in check_steps.caps()}
    assert check_steps.calls() == [1, 2]


def test_the_tensor_core_peak_is_half_the_f16_gemm_rate():
    ceilings = check_runner.Step("ceilings", "", 20)
    ceilings.status = "ok"
    ceilings.records.append({"kind": "ceilings", "copy_gbps": 4179.0, "f32_gemm_tflops": 50.8,
                             "tf32_gemm_tflops": 432.1, "f16_gemm_tflops": 799.2})
    assert check_steps.peaks(ceilings) == {"--peak-gmacs": "25400", "--peak-tensor-gmacs": "399600",
                                           "--peak-gbps": "4179"}
    ceilings.records[0]["f16_gemm_tflops"] = None  # the CPU has no f16 GEMM
    assert "--peak-tensor-gmacs" not in check_steps.peaks(ceilings)
    # A slow CPU's rate (the smoke) is not rounded to zero, which the bench refuses.
    ceilings.records[0]["f32_gemm_tflops"] = 0.0004
    assert check_steps.peaks(ceilings)["--peak-gmacs"] == "0.2"


def steps_of_a_run():
    steps = {n: check_runner.Step(n, w, c) for n, w, c in check_steps.caps()}
    steps["setup"].status = "ok"
    steps["setup"].records.append({"kind": "adapter", "describe": "GPU (Vulkan, DiscreteGpu)",
                                   "cooperative_matrix_feature": True,
                                   "cooperative_matrices_text": "16×16×16 f16·f16→f32"})
    steps["wgsl"].status, steps["wgsl"].note = "failed", "exit 1: no | adapter"
    steps["ceilings"].status = "ok"
    steps["ceilings"].records.append({"kind": "ceilings", "copy_gbps": 3000.0, "f32_gemm_tflops": 50.0,
                                      "tf32_gemm_tflops": None, "f16_gemm_tflops": 700.0})
    steps["torch"].records.append({"kind": "dcnn_latency", "model": "half", "backend": "pytorch",
                                   "precision": "f16", "width": 8, "height": 8, "median_s": 1e-3, "min_s": 1e-3,
                                   "gmac_per_s": 1.0})
    return steps


def test_the_report_renders_failed_and_empty_steps():
    steps = steps_of_a_run()
    meta = {"mode": "device", "date": "today", "commit": "abc", "dirty": False, "device": "GPU"}
    md = check_report.report(steps, meta)
    assert "| wgsl | failed |" in md and "no / adapter" in md
    assert "3000 GB/s" in md and "– in TF32" in md
    assert "| half | pytorch | f16 | – | 8×8 |" in md
    assert "cooperative matrices (M×N×K A·B→C): 16×16×16 f16·f16→f32" in md
    json.dumps([s.summary() for s in steps.values()])
    # Nothing but setup: every section without figures is left out.
    md = check_report.report({"setup": check_runner.Step("setup", "", 20)}, meta)
    assert "## " not in md


def test_the_report_shows_wall_and_gpu_time_refine_and_the_tradeoff():
    steps = steps_of_a_run()
    steps["wgsl"].records.append({"kind": "dcnn_latency", "model": "half", "backend": "wgpu", "precision": "f16",
                                  "conv_path": "auto", "width": 8, "height": 8, "median_s": 4e-3, "min_s": 4e-3,
                                  "gpu_median_s": 2e-3, "gmac_per_s": 1.0, "gpu_gmac_per_s": 2.0})
    steps["pipeline"].records.append({"kind": "pipeline", "network": "refine10", "frame_path": "device",
                                      "width": 8, "height": 8, "presented": 5, "dropped": 0, "gpu_p50_ms": 3.25,
                                      "e2e_p50_ms": 12.5})
    steps["pipeline"].records.append({"kind": "pipeline", "network": "admm3", "frame_path": "device",
                                      "width": 8, "height": 8, "presented": 5, "dropped": 0, "gpu_p50_ms": 1.75,
                                      "e2e_p50_ms": 9.5})
    steps["tradeoff"].text = "| configuration | latency ms |\n| --- | --- |\n| refine:10 wgpu | 3.3 |"
    steps["tune"].text = "| 3×3 16→16 | 1920×1080 | 32×16 | 90.0 | 16×8 | 80.0 | 1.12 |"
    steps["tune"].records.append({"kind": "tuning_table", "file": "nvidia-h200.toml"})
    md = check_report.report(steps, {"mode": "device", "date": "today", "commit": "abc", "device": "GPU",
                                     "call_flag": " --call 2"})
    # wall 4 ms and GPU 2 ms against PyTorch's 1 ms.
    assert "| half | wgpu | f16 | auto | 8×8 | 4.00 | 2.00 | 2 | 4.00 | 2.00 |" in md
    assert "GPU p50 3.2 ms a frame" in md and "end to end p50 12.5 ms" in md
    # admm:3, issue 55's time line, in its own section.
    assert "## admm:3 per frame" in md and "GPU p50 1.8 ms a frame" in md
    assert "| refine:10 wgpu | 3.3 |" in md
    assert "## The conv tiles tuned" in md and "commit it as tuning/nvidia-h200.toml" in md
    assert "| 3×3 16→16 | 1920×1080 | 32×16 | 90.0 | 16×8 | 80.0 | 1.12 |" in md
    assert "device-check.sh --call 2`" in md


def test_the_report_says_case_by_case_whether_the_pacing_target_is_met():
    steps = steps_of_a_run()
    base = {"kind": "pipeline", "frame_path": "device", "path_detail": "device (no read-back)", "width": 1920,
            "height": 1080, "refresh_hz": 90.0, "presented": 200, "dcnn_failures": 0}
    steps["pipeline"].records += [
        {**base, "network": "none", "views": 1, "gpu_p50_ms": 0.0, "e2e_p50_ms": 5.0, "dropped": 0},
        {**base, "network": "wiener", "views": 1, "gpu_p50_ms": 1.4, "e2e_p50_ms": 9.4, "dropped": 1,
         "stages": [{"stage": "preprocess", "count": 200, "p50_ms": 2.95},
                    {"stage": "preprocess-record", "count": 200, "p50_ms": 0.61},
                    {"stage": "encode", "count": 0, "p50_ms": 0.0}]},
        {**base, "network": "model", "views": 1, "precision": "f16", "gpu_p50_ms": 6.0, "e2e_p50_ms": 11.5,
         "dropped": 0},
        # Two eyes of 7.1 ms each: 14.2 ms, over an 11.1 ms refresh.
        {**base, "network": "model", "views": 2, "width": 3840, "gpu_p50_ms": 0.0, "e2e_p50_ms": 39.3,
         "dropped": 4, "eyes": [{"stage": "preprocess view 0", "p50_ms": 7.1},
                                {"stage": "preprocess view 1", "p50_ms": 7.1}]},
        # The network fell back to the frame itself: fast, and not met.
        {**base, "network": "half", "views": 1, "gpu_p50_ms": 0.0, "e2e_p50_ms": 4.0, "dropped": 0,
         "dcnn_failures": 200},
        # Nothing shown: no percentile to meet.
        {**base, "network": "full", "views": 1, "gpu_p50_ms": 0.0, "e2e_p50_ms": 0.0, "dropped": 0,
         "presented": 0},
        # The host path, and a row from a binary without the rate, are left out.
        {**base, "network": "none", "frame_path": "host", "views": 1, "width": 8, "e2e_p50_ms": 1.0,
         "dropped": 0},
        {"kind": "pipeline", "network": "none", "frame_path": "device", "width": 16, "height": 8,
         "e2e_p50_ms": 1.0, "dropped": 0},
    ]
    steps["pipeline"].text = "| network |"
    md = check_report.report(steps, {"mode": "device", "date": "today", "commit": "abc", "device": "GPU"})
    assert "| none | 1 | f32 | 1920×1080 | 11.11 | 0.00 | – | – | 5.00 | 0 | yes |" in md
    assert "| wiener | 1 | f32 | 1920×1080 | 11.11 | 1.40 | 2.95 | 0.61 | 9.40 | 1 | no |" in md
    assert "| model | 1 | f16 | 1920×1080 | 11.11 | 6.00 | – | – | 11.50 | 0 | no |" in md
    assert "| model | 2 | f32 | 3840×1080 | 11.11 | 14.20 | – | – | 39.30 | 4 | – (GPU time over a refresh) |" in md
    assert "| half | 1 | f32 | 1920×1080 | 11.11 | 0.00 | – | – | 4.00 | 0 | no (fell back" in md
    assert "| full | 1 | f32 | 1920×1080 | 11.11 | 0.00 | – | – | 0.00 | 0 | no (nothing shown) |" in md
    assert "| 8×1080 |" not in md and "| 16×8 |" not in md


def test_the_report_puts_the_frame_budget_beside_the_fixed_cases():
    steps = steps_of_a_run()
    base = {"kind": "pipeline", "frame_path": "device", "width": 1920, "height": 1080, "refresh_hz": 90.0,
            "views": 1, "presented": 200, "dropped": 0, "late": 0, "e2e_p50_ms": 8.0, "e2e_p99_ms": 9.5}
    budget = {"budget_ms": 9.41, "levels": [
        {"name": "none", "frames": 10, "left_late": 0},
        {"name": "wiener", "frames": 180, "left_late": 1},
        {"name": "refine:10", "frames": 10, "left_late": 0}], "dropped": ["refine:1", "dcnn"]}
    steps["pipeline"].records += [
        {**base, "network": "auto", "quality_db": 21.6123, "frame_budget": budget},
        {**base, "network": "model", "presented": 190, "dropped": 10, "late": 3, "quality_db": 21.6},
        # Random weights: no quality.
        {**base, "network": "full", "quality_db": None},
        # The host path, and a row without the quality (an older binary), are left out.
        {**base, "network": "none", "frame_path": "host", "quality_db": 20.5},
        {**base, "network": "wiener"},
    ]
    steps["pipeline"].text = "| network |"
    md = check_report.report(steps, {"mode": "device", "date": "today", "commit": "abc", "device": "GPU"})
    assert "| auto | 1 | 200 | 0 | 0 | 8.00 | 9.50 | 21.61 |" in md
    assert "| model | 1 | 190 | 10 | 3 | 8.00 | 9.50 | 21.60 |" in md
    assert "| full | 1 | 200 | 0 | 0 | 8.00 | 9.50 | – |" in md
    assert "- auto, 1 view(s): budget 9.41 ms; none 10, wiener 180 (1 left late), refine:10 10; left out: " \
           "refine:1, dcnn" in md
    table = md[md.index("The frame budget, side by side"):]
    assert "| none |" not in table and "| wiener |" not in table


def test_the_report_compares_each_case_s_first_frame_with_the_settled_ones():
    steps = steps_of_a_run()
    # Twelve frames of a case: the first 60 ms (8 of them on the GPU), the
    # others 9 ms (7 on the GPU); two replaced, one in the first second.
    n = 12
    stage = [60.0] + [9.0] * (n - 1)
    frames = {"id": list(range(n)), "outcome": ["shown"] * n, "submitted_ms": [10.0 + 100 * i for i in range(n)],
              "held_ms": [0.0] * n, "gpu_ms": [8.0] + [7.0] * (n - 1),
              "stages_ms": [[[0, 0], [10.0 + 100 * i, 10.0 + 100 * i + stage[i]], [0, 0]] for i in range(n)]}
    frames["outcome"][3] = frames["outcome"][11] = "replaced"
    log = {"kind": "frame_log", "network": "model", "views": 1, "precision": "f32", "frames": frames}
    # An older binary's log: no GPU column.
    old = {**log, "network": "none", "frames": {k: v for k, v in frames.items() if k != "gpu_ms"}}
    steps["pipeline"].records += [log, old]
    steps["pipeline"].text = "| network |"
    md = check_report.report(steps, {"mode": "device", "date": "today", "commit": "abc", "device": "GPU"})
    assert "| model | 1 | f32 | 60.00 | 8.00 | 9.00 | 7.00 | 1 | 1 |" in md
    assert "| none | 1 | f32 | 60.00 | – | 9.00 | – | 1 | 1 |" in md


def test_the_timelines_give_each_case_s_stage_holds_and_bounds(tmp_path, capsys):
    # 30 frames submitted 11 ms apart, an upload of 1 ms and a stage of 4;
    # from the 16th on each is held 2 ms, and the next waits that long behind it.
    n = 30
    held = [2.0 if i >= 15 else 0.0 for i in range(n)]
    start = [11.0 * i + 1.0 + (2.0 if i >= 16 else 0.0) for i in range(n)]
    frames = {"id": list(range(n)), "outcome": ["shown"] * n, "held_ms": held,
              "submitted_ms": [11.0 * i for i in range(n)], "predicted_ms": [11.0 * i + 20 for i in range(n)],
              "stages_ms": [[[11.0 * i, 11.0 * i + 1], [start[i], start[i] + 4 + held[i]], [0, 0]] for i in range(n)],
              "ready_ms": [start[i] + 4 + held[i] for i in range(n)], "taken_ms": [11.0 * i + 9 for i in range(n)],
              "shown_ms": [11.0 * i + 20 for i in range(n)], "replaced_ms": [None] * n}
    c = timelines.case({"network": "model", "views": 1, "precision": "f32", "frames": frames})
    assert (c["own_p50"], c["held"], c["of"], c["held_p50"], c["held_max"]) == (4.0, 10, 10, 2.0, 2.0)
    assert c["gap_p50"] == pytest.approx(11.0) and c["ahead_p50"] == 20.0
    # Own work 5 ms (the upload's 1 ms in); submission to ready less the
    # hold 5 ms, or 7 ms behind a hold unless that wait is left out too.
    assert c["bound_own_work"] == pytest.approx(5.0, abs=0.05)
    assert c["bound_less_hold_and_behind"] == pytest.approx(5.0, abs=0.05)
    assert c["bound_less_hold"] > 6.0
    summary = tmp_path / "summary.json"
    log = {"kind": "frame_log", "network": "model", "views": 1, "precision": "f32", "frames": frames,
           "refreshes": {"refresh_ms": [20.0], "wake_ms": [9.0], "frame": [0], "presented_ms": [10.0],
                         "taken_ms": [9.0]}}
    # 24 more refreshes, long after, each woken for 1.5 ms before it: the
    # present's lead after the 20th.
    for k in range(24):
        for key, v in (("refresh_ms", 1000.0 + 11 * k), ("wake_ms", 998.5 + 11 * k), ("frame", None),
                       ("presented_ms", None), ("taken_ms", None)):
            log["refreshes"][key].append(v)
    summary.write_text(json.dumps({"steps": [{"name": "pipeline", "records": [log]}]}))
    assert timelines.main(["timelines.py", str(summary)]) == 0
    row = "| model 1 f32 | 4.00 | 4.00 | 6.00 | 10 of 10 | 2.00 / 2.00 | 20.00 | 11.00 / 11.00 / 11.00 | 1.50 |"
    out = capsys.readouterr().out
    # No refresh rate in the log: no plan to set against it.
    assert row in out and out.rstrip().endswith("| – |")
    # The plan's lead: the bound (5 ms), the present's lead (1.5 ms) and a
    # 32nd of the refresh; within 11.11 ms at 90 Hz, not within 6.25 at 160.
    at_90 = timelines.case({**log, "refresh_hz": 90.0})
    assert at_90["plan_ms"] == pytest.approx(5.0 + 1.5 + 1000 / 90 / 32, abs=0.05)
    assert at_90["refresh_ms"] == pytest.approx(1000 / 90)
    assert "(yes: 11.11) |" in timelines.table([{**log, "refresh_hz": 90.0}])[2]
    assert "(no: 6.25) |" in timelines.table([{**log, "refresh_hz": 160.0}])[2]
    # The device check's report shows the same table; a log without the
    # columns it reads (an older binary's) is left out of it.
    steps = steps_of_a_run()
    old = {**log, "network": "none", "frames": {k: v for k, v in frames.items() if k != "ready_ms"}}
    steps["pipeline"].records += [log, old]
    steps["pipeline"].text = "| network |"
    md = check_report.report(steps, {"mode": "device", "date": "today", "commit": "abc", "device": "GPU"})
    assert "The steady state (GPU, commit abc)" in md and row in md and "| none 1 f32 |" not in md
    assert timelines.main(["timelines.py", str(summary), "--frames", "model 1 f32", "0", "1"]) == 0
    out = capsys.readouterr().out
    assert "| 0 | shown | 0.00 | 20.00 | 4.00 | 0.00 | 5.00 | 20.00 | 1.00 | – |" in out
    assert "| 20.00 | 9.00 | 11.00 | 0 | 10.00 |" in out
    # `auto`: the levels the frames ran, by the log's names.
    auto = {**log, "network": "auto", "levels": ["none", "wiener", "refine:10"],
            "frames": {**frames, "level": [2] * 25 + [1] * 5}}
    assert timelines.table([auto])[2].endswith("| wiener 5, refine:10 5 |")
    summary.write_text(json.dumps({"steps": [{"name": "pipeline", "records": [auto]}]}))
    assert timelines.main(["timelines.py", str(summary), "--frames", "auto 1 f32", "27", "1"]) == 0
    assert "| 27 | shown |" in (out := capsys.readouterr().out) and out.rstrip().splitlines()[2].endswith("| wiener |")
    summary.write_text(json.dumps({"steps": [{"name": "pipeline", "records": [log]}]}))
    # Bad input: a named reason and a non-zero exit.
    assert timelines.main(["timelines.py", str(summary), "--frames", "half 1 f32"]) == 1
    assert "no case 'half 1 f32'; there are: model 1 f32" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text("[1]")
    assert timelines.main(["timelines.py", str(tmp_path / "bad.json")]) == 1
    assert "not a device check's summary.json" in capsys.readouterr().err
    assert timelines.main(["timelines.py"]) == 2
    (tmp_path / "old.json").write_text(json.dumps({"steps": [{"name": "pipeline", "records": [old]}]}))
    assert timelines.main(["timelines.py", str(tmp_path / "old.json")]) == 1
    assert "no case's timelines have every column" in capsys.readouterr().err


def test_the_stage_s_own_time_splits_into_record_device_and_fence(tmp_path, capsys):
    # 30 frames, each preprocess stage 9 ms of which 1 ms held: 8 ms own,
    # 1.5 ms recorded, 5.5 ms on the device of which 4 ms its stages; the
    # rest, 1 ms, the submission's and the fence's latency.
    n = 30
    frames = {"id": list(range(n)), "outcome": ["shown"] * n, "held_ms": [1.0] * n,
              "submitted_ms": [11.0 * i for i in range(n)], "predicted_ms": [11.0 * i + 20 for i in range(n)],
              "stages_ms": [[[11.0 * i, 11.0 * i + 1], [11.0 * i + 1, 11.0 * i + 10], [0, 0]] for i in range(n)],
              "ready_ms": [11.0 * i + 10 for i in range(n)], "taken_ms": [11.0 * i + 12 for i in range(n)],
              "shown_ms": [11.0 * i + 20 for i in range(n)], "replaced_ms": [None] * n,
              "gpu_ms": [4.0] * n, "record_ms": [1.5] * n, "frame_gpu_ms": [5.5] * n}
    log = {"kind": "frame_log", "network": "model", "views": 1, "precision": "f16", "frames": frames,
           "refreshes": {}}
    # No network: no stage on the device, the whole submission its overhead.
    none = {**log, "network": "none", "frames": {**frames, "gpu_ms": [None] * n}}
    rows = timelines.overhead([log, none])
    assert rows[2] == "| model 1 f16 | 8.00 | 4.00 | 1.50 | 1.50 | 1.00 | 10 |"
    assert rows[3] == "| none 1 f16 | 8.00 | 0.00 | 1.50 | 5.50 | 1.00 | 10 |"
    # A log from before the whole submission was timed is left out.
    old = {**log, "frames": {k: v for k, v in frames.items() if k != "frame_gpu_ms"}}
    assert timelines.overhead([old]) == []
    # A short case (the smoke's): no frame after the 20th, every figure "–".
    short = {**log, "frames": {k: v[:20] for k, v in frames.items()}}
    assert timelines.overhead([short])[2] == "| model 1 f16 | – | – | – | – | – | 0 |"
    summary = tmp_path / "summary.json"
    summary.write_text(json.dumps({"steps": [{"name": "pipeline", "records": [log]}]}))
    assert timelines.main(["timelines.py", str(summary)]) == 0
    assert rows[2] in capsys.readouterr().out
    steps = steps_of_a_run()
    steps["pipeline"].records += [log]
    steps["pipeline"].text = "| network |"
    md = check_report.report(steps, {"mode": "device", "date": "today", "commit": "abc", "device": "GPU"})
    assert "Where the preprocess stage's own time goes beyond its stages (GPU, commit abc" in md and rows[2] in md


def test_a_bad_only_or_call_is_refused(capsys):
    assert check.main(["--only", "setup,warp"]) == 2
    assert "no step warp" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        check.main(["--call", "3"])
    assert e.value.code == 2


def test_the_smoke_without_the_trainers_venv_says_how_to_make_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(check, "missing_modules", lambda python, env: ["torch", "nedrt_train"])
    assert check.check(tmp_path / "out", smoke=True) == 2
    err = capsys.readouterr().err
    assert "cannot import torch, nedrt_train" in err and "bash scripts/test.sh" in err
    assert not (tmp_path / "out").exists()
    # The probe itself: a module that exists is not missing, one that does not is.
    monkeypatch.setattr(check_runner, "NEEDED_MODULES", ["json", "no_such_module_of_nedrt"])
    assert check_runner.missing_modules(sys.executable, {}) == ["no_such_module_of_nedrt"]


def test_parallel_runs_no_more_at_once_than_memory_holds_and_names_a_killed_child(tmp_path, monkeypatch):
    import time

    r = check_runner.Runner(tmp_path, smoke=True)
    r.step = check_runner.Step("teacher", "test", 60)
    # Each child holds a lock file while it runs; a second holder means two at once.
    script = ("import os,sys,time; p=sys.argv[1]; fd=os.open(p,os.O_CREAT|os.O_EXCL); time.sleep(0.3); "
              "os.close(fd); os.remove(p)")
    lock = tmp_path / "lock"
    monkeypatch.setattr(check_runner, "available_gib", lambda: 9.0)
    r.parallel([[sys.executable, "-c", script, lock] for _ in range(3)], time.monotonic() + 30, mem_gib=5)
    assert len(r.step.commands) == 3
    # Unbounded, the three overlap and two of them find the lock taken.
    with pytest.raises(check_runner.Failed, match="exit 1"):
        r.parallel([[sys.executable, "-c", script, lock] for _ in range(3)], time.monotonic() + 30)
    time.sleep(0.5)
    with pytest.raises(check_runner.Failed, match="killed by SIGKILL"):
        r.parallel([[sys.executable, "-c", "import os,signal; os.kill(os.getpid(), signal.SIGKILL)"]],
                   time.monotonic() + 30)
    with pytest.raises(check_runner.Failed, match="timed out"):
        r.parallel([[sys.executable, "-c", "import time; time.sleep(30)"]], time.monotonic() + 0.5)


def test_what_a_call_brings_back_fits_the_tools_file_limit():
    """summary.json, report.md, log.txt and the steps' files: at most 8 a
    call (the device tool's limit), none more than two folders down."""
    for call in check_steps.calls():
        files = ["summary.json", "report.md", "log.txt"]
        files += [f for n, _, _ in check_steps.caps(call) for f in check_runner.STEP_FILES.get(n, [])]
        assert len(files) <= check_runner.FILES_BACK == 8, (call, files)
        assert all(f.count("/") <= 2 for f in files)
    assert any(f.startswith(check_train.RETURNED + "/") for f in check_runner.STEP_FILES["train"])


def test_the_returned_checkpoint_is_checked_against_its_card(tmp_path):
    import hashlib
    folder = tmp_path / check_train.RETURNED
    folder.mkdir()
    data = b"tensors"
    name = f"tensors-{hashlib.sha256(data).hexdigest()[:16]}.safetensors"
    (folder / name).write_bytes(data)
    card = {"step": 12, "seconds": 30.0, "moments": "none", "sessions": [{}, {}],
            "tensors": {"file": name, "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}}
    (folder / "card.json").write_text(json.dumps(card))
    got = check_train.returned_checkpoint(folder)
    assert got == {"step": 12, "seconds": 30.0, "moments": "none", "mib": 0.0, "file": f"checkpoint/{name}",
                   "sessions": 2}
    (folder / "stray.tmp").write_bytes(b"")
    with pytest.raises(check_runner.Failed, match="does not name: stray.tmp"):
        check_train.returned_checkpoint(folder)
    (folder / "stray.tmp").unlink()
    (folder / name).write_bytes(b"tampered")
    with pytest.raises(check_runner.Failed, match="its card says"):
        check_train.returned_checkpoint(folder)
    with pytest.raises(check_runner.Failed, match="was not written"):
        check_train.returned_checkpoint(tmp_path / "none")


def test_the_report_says_where_the_training_started_and_what_came_back():
    meta = {"mode": "device", "date": "today", "commit": "abc", "device": "GPU"}
    steps = {"train": check_runner.Step("train", "", 300)}
    record = {"kind": "train", "steps": 20000, "seconds": 580.0, "batch": 64, "device": "NVIDIA H100",
              "validation": [{"dcnn_mean_db": 29.5}],
              "started": {"checkpoint": "models/checkpoints/dcnn-full", "step": 10248, "sessions": 1},
              "checkpoint": {"step": 20000, "seconds": 580.0, "moments": "none", "mib": 7.35,
                             "file": "checkpoint/tensors-0123456789abcdef.safetensors", "sessions": 2}}
    steps["train"].records.append(record)
    md = check_report.report(steps, meta)
    assert ("Continued `models/checkpoints/dcnn-full` from step 10248 (1 session before this one): step 20000 now"
            in md)
    assert "`checkpoint/tensors-0123456789abcdef.safetensors`" in md and "7.35 MiB" in md
    assert "| D-CNN | 29.50 / – |" in md
    record["started"] = {"fresh": "checkpoint models/checkpoints/dcnn-full: network.width 32 ≠ this run's 16"}
    md = check_report.report(steps, meta)
    assert "Started fresh (checkpoint models/checkpoints/dcnn-full: network.width 32" in md


def test_the_openxr_runtime_and_client_are_unpacked_from_what_travels(tmp_path, monkeypatch):
    carry = tmp_path / "carry"
    (carry / "openxr").mkdir(parents=True)
    for _, name in check_openxr.XR_FILES:
        check_runner.strip_and_pack(Path("/bin/true"), carry / "openxr" / name).unlink()
    monkeypatch.setattr(check_openxr, "CARRY", carry)
    # The loader: found by ldconfig here, or extracted from the carried .deb (none here, so named).
    monkeypatch.setattr(check_openxr.subprocess, "run", lambda *a, **k: subprocess.CompletedProcess(
        a, 0, stdout="libopenxr_loader.so.1 (libc6,x86-64) => /lib/libopenxr_loader.so.1", stderr=""))

    class Device:
        smoke = False
        work = tmp_path / "work"
        env = {}

    Device.work.mkdir()
    lib, client, env = check_openxr.runtime_files(Device())
    assert (lib.name, client.name) == ("libnedrt_openxr.so", "openxr_client")
    assert lib.read_bytes()[:4] == b"\x7fELF" and client.stat().st_mode & 0o111 and env == {}


def test_a_cases_frame_timelines_become_one_record_column_by_column(tmp_path):
    """`bench pipeline --frame-log` writes a file a case; the step brings each
    back in summary.json (the call's eight files are taken), each key once."""
    frames = [{"id": i, "outcome": "shown", "submitted_ms": 1.0 * i, "stages_ms": [[0.0, 1.0]] * 3} for i in range(3)]
    refreshes = [{"refresh_ms": 11.1, "wake_ms": 9.9, "frame": 0}]
    log = {"network": "model", "frame_path": "device", "views": 2, "refresh_hz": 90.0, "precision": "f16",
           "frames": frames, "refreshes": refreshes}
    path = tmp_path / "frames-model-device-stereo-f16.json"
    path.write_text(json.dumps(log))
    got = check_steps.frame_log(path)
    assert got["kind"] == "frame_log" and got["file"] == path.name
    assert (got["network"], got["views"], got["precision"]) == ("model", 2, "f16")
    assert got["frames"]["id"] == [0, 1, 2] and got["frames"]["submitted_ms"] == [0.0, 1.0, 2.0]
    assert got["frames"]["stages_ms"][1] == [[0.0, 1.0]] * 3
    assert got["refreshes"] == {"refresh_ms": [11.1], "wake_ms": [9.9], "frame": [0]}
    assert got["levels"] is None
    path.write_text(json.dumps({**log, "levels": ["none", "wiener"]}))
    assert check_steps.frame_log(path)["levels"] == ["none", "wiener"]
    # A case that showed nothing has empty columns, not an error.
    path.write_text(json.dumps({**log, "frames": [], "refreshes": []}))
    assert check_steps.frame_log(path)["frames"] == {}


def test_clock_samples_are_parsed_and_summed_up():
    import check_steps
    text = "1980, 97\n345, 3\n[N/A], 0\nnot a line\n1755, 40\n"
    samples = check_steps.parse_clocks(text)
    assert samples == [[1980.0, 97.0], [345.0, 3.0], [1755.0, 40.0]]
    line = check_steps.clocks_line("the f16 cases", samples)
    assert "3 samples" in line and "min 345" in line and "median 1755" in line and "max 1980" in line
    assert check_steps.clocks_line("x", []) == ""
