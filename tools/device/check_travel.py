"""Here, before a device call: what travels (`--prepare` builds .devcheck/,
`--plan` counts it against the tool's limit) and how the calls fit the
device time a task is lent."""
import hashlib
import json
import subprocess
import sys
import time

from check_runner import (CARRY, DEVICE_TIME_S, ENVELOPE2_S, ENVELOPE_S, GL_PACKAGES, MIB, REPO, START_S,
                          TRAIN_BUDGET_S, TRAVEL_LIMIT, apt_download, git_commit, git_dirty, strip_and_pack)
from check_openxr import prepare_openxr
from check_steps import calls, caps

def prepare() -> int:
    """Builds .devcheck/: the release binary, stripped and compressed, the
    Vulkan loader packages, and a manifest naming the commit."""
    CARRY.mkdir(exist_ok=True)
    subprocess.run(["cargo", "build", "--release", "-p", "nedrt"], cwd=REPO, check=True)
    built = REPO / "target" / "release" / "nedrt"
    stripped = strip_and_pack(built, CARRY / "nedrt.xz")
    digest = hashlib.sha256(stripped.read_bytes()).hexdigest()
    sizes_mib = {"built": round(built.stat().st_size / MIB, 2), "stripped": round(stripped.stat().st_size / MIB, 2),
                 "xz": round((CARRY / "nedrt.xz").stat().st_size / MIB, 2)}
    stripped.unlink()
    gl = CARRY / "gl"
    apt_download(gl, GL_PACKAGES)
    manifest = {"commit": git_commit(), "dirty": git_dirty(), "binary_sha256": digest, "binary_mib": sizes_mib,
                "built": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "gl": sorted(p.name for p in gl.glob("*.deb")), **prepare_openxr()}
    (CARRY / "manifest.json").write_text(json.dumps(manifest, indent=1))
    print(json.dumps(manifest, indent=1))
    return plan()


def travelling() -> list:
    """(path, bytes) of everything a device call sends: tracked files,
    untracked files git does not ignore, and the carried .devcheck/."""
    def files(args):
        p = subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, check=True)
        return [f for f in p.stdout.split("\0") if f]
    paths = files(["ls-files", "-z"]) + files(["ls-files", "-z", "--others", "--exclude-standard"])
    out = [(p, (REPO / p).stat().st_size) for p in paths if (REPO / p).is_file()]
    if CARRY.is_dir():
        out += [(str(p.relative_to(REPO)), p.stat().st_size) for p in sorted(CARRY.rglob("*")) if p.is_file()]
    return out


def plan() -> int:
    items = travelling()
    carried = [(p, n) for p, n in items if p.startswith(".devcheck/")]
    tree = sum(n for p, n in items if not p.startswith(".devcheck/"))
    total = sum(n for _, n in items)
    print("Carried (`carry: [\".devcheck\"]`):")
    for p, n in carried:
        print(f"  {n / MIB:8.2f} MiB  {p}")
    if not carried:
        print("  nothing yet: run `bash scripts/device-check.sh --prepare`")
    print(f"The working tree (tracked and untracked-not-ignored files): {tree / MIB:.2f} MiB")
    print(f"Total that travels: {total / MIB:.2f} MiB (limit {TRAVEL_LIMIT / MIB:.0f} MiB of the tool's 64)")
    total_s = START_S
    for call in calls():
        envelope = ENVELOPE_S if call == 1 else ENVELOPE2_S
        flag = "" if call == 1 else f" --call {call}"
        print(f"\nCall {call} (`bash scripts/device-check.sh{flag}`), each step under its cap, "
              f"in an envelope of {envelope} s = {envelope / 60:.1f} min:")
        steps = caps(call)
        fixed = [(n, w, c) for n, w, c in steps if n != "train"]
        least = envelope - sum(c for _, _, c in fixed)
        for name, what, cap in steps:
            shown = (f"{least}–{cap} s (what is left)" if name == "train" else f"≤ {cap} s")
            print(f"  {name:10} {shown:22} {what}")
        est = min(envelope, sum(c for _, _, c in fixed) + (TRAIN_BUDGET_S if any(n == "train" for n, _, _ in steps)
                                                           else 0))
        total_s += est
        # A minute over the envelope for the command's own start and $OUT.
        timeout = min(600, envelope + 60)
        print(f"  at most {est} s ({est / 60:.1f} min); the tool, timeout_s={timeout}:")
        print(f'  run(command="bash scripts/device-check.sh{flag}", carry=[".devcheck"], timeout_s={timeout})')
    print(f"\nDevice time: ≤ {total_s} s ({total_s / 60:.1f} min) with the machine's start (about {START_S} s) "
          f"of the {DEVICE_TIME_S / 60:.0f} min a task is lent: call 2 right after call 1 on the warm machine, "
          "then give_back at once.")
    if total > TRAVEL_LIMIT:
        print(f"error: {total / MIB:.2f} MiB would travel, over {TRAVEL_LIMIT / MIB:.0f} MiB", file=sys.stderr)
        return 1
    return 0

