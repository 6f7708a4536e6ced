"""tools/device/check.py (scripts/device-check.sh) without running its steps
(CI runs `--smoke`, which runs them all): the plan counts what travels as
the device tool does and refuses more than the limit; the steps' caps fit
the envelope with time left to train; the report renders a run whose steps
failed or found no figures; a bad --only is refused; side-by-side commands
run no more at once than memory holds and a killed one is named."""
import importlib.util
import json
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("device_check", REPO / "tools" / "device" / "check.py")
check = importlib.util.module_from_spec(spec)
spec.loader.exec_module(check)


def test_the_plan_counts_every_tracked_file():
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, text=True,
                            check=True).stdout.split("\0")
    tracked = sum((REPO / p).stat().st_size for p in listed if p and (REPO / p).is_file())
    items = dict(check.travelling())
    assert sum(n for p, n in items.items() if p in set(listed)) == tracked
    assert all(not p.startswith((".venv/", "target/")) for p in items)


def test_the_plan_refuses_more_than_the_limit(monkeypatch, capsys):
    monkeypatch.setattr(check, "TRAVEL_LIMIT", 1)
    assert check.plan() == 1
    assert "over" in capsys.readouterr().err


def test_the_caps_fit_the_envelope_and_leave_time_to_train():
    fixed = sum(c for n, _, c in check.caps() if n != "train")
    assert fixed + check.AFTER_TRAIN_S < check.ENVELOPE_S
    # The training gets at least two and a half minutes, whatever the benchmarks take.
    assert check.ENVELOPE_S - fixed >= 150
    # One tool call is at most 600 s.
    assert check.ENVELOPE_S <= 540


def test_the_report_renders_failed_and_empty_steps():
    steps = {n: check.Step(n, w, c) for n, w, c in check.caps()}
    steps["setup"].status = "ok"
    steps["wgsl"].status, steps["wgsl"].note = "failed", "exit 1: no | adapter"
    steps["ceilings"].status = "ok"
    steps["ceilings"].records.append({"kind": "ceilings", "copy_gbps": 3000.0, "f32_gemm_tflops": 50.0,
                                      "tf32_gemm_tflops": None, "f16_gemm_tflops": 700.0})
    steps["torch"].records.append({"kind": "dcnn_latency", "model": "half", "backend": "pytorch",
                                   "precision": "f32", "width": 8, "height": 8, "median_s": 1e-3, "min_s": 1e-3,
                                   "gmac_per_s": 1.0})
    meta = {"mode": "device", "date": "today", "commit": "abc", "dirty": False, "device": "GPU"}
    md = check.report(steps, meta)
    assert "| wgsl | failed |" in md and "no / adapter" in md
    assert "3000 GB/s" in md and "– in TF32" in md
    assert "| half | pytorch | f32 | 8×8 |" in md
    json.dumps([s.summary() for s in steps.values()])


def test_a_bad_only_is_refused(capsys):
    assert check.main(["--only", "setup,warp"]) == 2
    assert "no step warp" in capsys.readouterr().err


def test_parallel_runs_no_more_at_once_than_memory_holds_and_names_a_killed_child(tmp_path, monkeypatch):
    import sys
    import time

    r = check.Runner(tmp_path, smoke=True)
    r.step = check.Step("teacher", "test", 60)
    # Each child holds a lock file while it runs; a second holder means two at once.
    script = ("import os,sys,time; p=sys.argv[1]; fd=os.open(p,os.O_CREAT|os.O_EXCL); time.sleep(0.3); "
              "os.close(fd); os.remove(p)")
    lock = tmp_path / "lock"
    monkeypatch.setattr(check, "available_gib", lambda: 9.0)
    r.parallel([[sys.executable, "-c", script, lock] for _ in range(3)], time.monotonic() + 30, mem_gib=5)
    assert len(r.step.commands) == 3
    # Unbounded, the three overlap and two of them find the lock taken.
    with pytest.raises(check.Failed, match="exit 1"):
        r.parallel([[sys.executable, "-c", script, lock] for _ in range(3)], time.monotonic() + 30)
    time.sleep(0.5)
    with pytest.raises(check.Failed, match="killed by SIGKILL"):
        r.parallel([[sys.executable, "-c", "import os,signal; os.kill(os.getpid(), signal.SIGKILL)"]],
                   time.monotonic() + 30)
    with pytest.raises(check.Failed, match="timed out"):
        r.parallel([[sys.executable, "-c", "import time; time.sleep(30)"]], time.monotonic() + 0.5)
