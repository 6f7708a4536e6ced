"""The device check (issues 29 and 38; scripts/device-check.sh is its entry
point, docs/benchmarks.md "On a lent accelerator" its results): in two calls
of the device tool, every figure a lent NVIDIA GPU can give, written under
$OUT. The machinery is in check_runner.py, the steps in check_steps.py and
check_train.py, the report in check_report.py, --prepare and --plan in
check_travel.py.

Modes:
  (none)     on the accelerator machine: call 1's steps at full size, within
             a 9-minute envelope (each step has a cap; the D-CNN training
             takes what the steps before it left, at most its budget);
  --call 2   on the accelerator machine, right after call 1: the steps call 1
             leaves no room for (the OpenXR runtime's copy-out, the
             speed-against-accuracy chart with the GPU's rows), within a
             4-minute envelope;
  --smoke    every call's steps at tiny sizes on this machine's CPU
             (lavapipe, torch on the CPU, a few training steps): CI runs it;
             it needs the trainer's .venv, which `bash scripts/test.sh` makes;
  --prepare  here, before a call: builds what travels into .devcheck/ (the
             release binary, stripped and xz-compressed; the Vulkan loader
             packages; the OpenXR runtime, its client and the OpenXR loader
             packages; a manifest naming the commit);
  --plan     what would travel (the tracked tree, untracked files, .devcheck/)
             against the 64 MiB limit, and each call's steps and caps.

What comes back (at most 8 files a call, 16 MiB each): summary.json (each
step with its status, time, cap and figures), report.md (the tables for
docs/benchmarks.md), log.txt (every command's output); from call 1 also
metrics.csv (the training's per-step log), checkpoint/ (the continued
carried checkpoint: card.json and its tensors file, docs/training.md) and
the trained network as the runtime's model: dcnn-full.onnx and its card;
from call 2 tradeoff.md, .json, .svg and .png, and the adapter's conv
tiles table (`nedrt bench tune`, to commit under tuning/, docs/tuning.md).
"""
import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

# The modules beside this file, however it is loaded (script or test).
sys.path.insert(0, str(Path(__file__).resolve().parent))

from check_report import report  # noqa: E402
from check_runner import (CARRY, ENVELOPE2_S, ENVELOPE_S, REPO, Runner, Step, git_commit, git_dirty,  # noqa: E402
                          missing_modules, no_venv_message)
from check_steps import (STEPS, calls, sizes, step_ceilings, step_fft, step_per_layer, step_pipeline,  # noqa: E402
                         step_setup, step_torch, step_tradeoff, step_tune, step_wgsl)
from check_openxr import step_openxr  # noqa: E402
from check_train import step_export, step_teacher, step_train  # noqa: E402
from check_travel import plan, prepare  # noqa: E402


def bodies(r: Runner, z: dict, steps: dict, device: str) -> dict:
    """Each step's body and the steps it needs, by name."""
    ceilings = steps.get("ceilings") or Step("ceilings", "", 0)
    setup = [steps["setup"]]
    return {
        "setup": (lambda s: step_setup(r, s, z), []),
        "ceilings": (lambda s: step_ceilings(r, s, z), []),
        "wgsl": (lambda s: step_wgsl(r, s, z), setup),
        "per-layer": (lambda s: step_per_layer(r, s, z, ceilings), setup),
        "torch": (lambda s: step_torch(r, s, z), []),
        "fft": (lambda s: step_fft(r, s, z, ceilings), setup),
        "pipeline": (lambda s: step_pipeline(r, s, z), setup),
        "teacher": (lambda s: step_teacher(r, s, z), setup),
        "train": (lambda s: step_train(r, s, z, device), [steps.get("teacher") or Step("teacher", "", 0)]),
        "export": (lambda s: step_export(r, s, z), [steps.get("train") or Step("train", "", 0)]),
        "openxr": (lambda s: step_openxr(r, s, z), setup),
        "tune": (lambda s: step_tune(r, s, z), setup),
        "tradeoff": (lambda s: step_tradeoff(r, s, z), setup),
    }


def check(out: Path, smoke: bool, only: set | None = None, call: int | None = None) -> int:
    """Runs one call's steps (the smoke: every call's unless `call` says),
    or those of `only`; writes summary.json, report.md and log.txt."""
    if smoke:
        env = {**os.environ, "PYTHONPATH": str(REPO / "models") + os.pathsep + os.environ.get("PYTHONPATH", "")}
        missing = missing_modules(sys.executable, env)
        if missing:
            print(no_venv_message(sys.executable, missing), file=sys.stderr)
            return 2
    out.mkdir(parents=True, exist_ok=True)
    if call is None and not smoke:
        call = 1
    envelope = ENVELOPE2_S if call == 2 and not only else ENVELOPE_S
    r = Runner(out, smoke, only, envelope)
    z = sizes(smoke)
    device = "cpu" if smoke else "cuda"
    steps = {n: Step(n, w, c) for n, w, c, k in STEPS if only or call is None or k in (0, call)}
    if smoke:
        for s in steps.values():
            s.cap_s = max(s.cap_s, 300)  # lavapipe and the 2-core CPU: generous, tiny sizes
    manifest = CARRY / "manifest.json"
    built = json.loads(manifest.read_text()) if manifest.is_file() and not smoke else {}
    meta = {"mode": "smoke" if smoke else "device", "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "commit": built.get("commit") or git_commit(), "dirty": built.get("dirty", git_dirty()),
            "device": "this machine's CPU and lavapipe" if smoke else "unknown", "envelope_s": envelope,
            "call": call or "all", "call_flag": f" --call {call}" if call and call != 1 else ""}
    r.commit = meta["commit"]
    run = bodies(r, z, steps, device)
    for name, s in steps.items():
        body, needs = run[name]
        r.run(s, body, needs)
        if name == "setup" and s.text:
            meta["device"] = s.text.splitlines()[0]
    meta["seconds"] = round(time.monotonic() - r.start, 1)
    summary = {**meta, "steps": [s.summary() for s in steps.values()]}
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1))
    tmp.replace(out / "summary.json")
    (out / "report.md").write_text(report(steps, meta))
    r.log.close()
    shutil.rmtree(r.work, ignore_errors=True)
    asked = [s for s in steps.values() if not s.note.startswith("not asked")]
    bad = [s.name for s in asked if s.status != "ok"]
    print(f"device check: {len(asked) - len(bad)} of {len(asked)} steps ok in {meta['seconds']:.0f} s"
          + (f"; not ok: {', '.join(bad)}" if bad else "") + f"; results in {out}")
    print(f"files: {sorted(p.name for p in out.iterdir())}")
    return 1 if bad else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="scripts/device-check.sh", description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--smoke", action="store_true", help="every call's steps at tiny sizes on this machine's CPU")
    mode.add_argument("--prepare", action="store_true", help="build .devcheck/ (what travels), then --plan")
    mode.add_argument("--plan", action="store_true", help="what travels, its size, each call's steps and caps")
    ap.add_argument("--call", type=int, choices=calls(), help="which call of the device tool this is (default 1; "
                    "the smoke: all)")
    ap.add_argument("--only", metavar="STEPS", help="only these steps, of any call, comma-separated (a rerun of "
                    "some): " + ",".join(n for n, *_ in STEPS))
    args = ap.parse_args(argv)
    only = None
    if args.only:
        only = {v.strip() for v in args.only.split(",") if v.strip()}
        unknown = only - {n for n, *_ in STEPS}
        if unknown:
            print(f"error: --only {args.only}: no step {', '.join(sorted(unknown))}", file=sys.stderr)
            return 2
    if args.prepare:
        return prepare()
    if args.plan:
        return plan()
    out = os.environ.get("OUT")
    if not out:
        print("error: OUT is not set: the folder the results go to (the device tool sets it; "
              "here: OUT=$(mktemp -d) bash scripts/device-check.sh --smoke)", file=sys.stderr)
        return 2
    return check(Path(out), args.smoke, only, args.call)


if __name__ == "__main__":
    sys.exit(main())
