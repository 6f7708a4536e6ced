"""The device check (issue 29; scripts/device-check.sh is its entry point,
docs/benchmarks.md "On a lent accelerator" its results): in one call of the
device tool, every figure a lent NVIDIA GPU can give, written under $OUT.

Modes:
  (none)     on the accelerator machine: every step at full size, within a
             9-minute envelope (each step has a cap; the D-CNN training takes
             what the steps before it left, at most its budget);
  --smoke    the same steps at tiny sizes on this machine's CPU (lavapipe,
             torch on the CPU, a few training steps): CI runs it;
  --prepare  here, before a call: builds what travels into .devcheck/ (the
             release binary, stripped and xz-compressed; the Vulkan loader
             packages; a manifest naming the commit);
  --plan     what would travel (the tracked tree, untracked files, .devcheck/)
             against the 64 MiB limit, and each step's cap.

What comes back (at most 8 files, 16 MiB each): summary.json (each step
with its status, time, cap and figures), report.md (the tables for
docs/benchmarks.md), log.txt (every command's output), metrics.csv (the
training's per-step log), and the trained network as the runtime's model:
dcnn-full.onnx, dcnn-full.card.json, dcnn-full.doe.safetensors.
"""
import argparse
import hashlib
import json
import lzma
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CARRY = REPO / ".devcheck"
MIB = 1 << 20
#: What may travel: the device tool's limit is 64 MiB; 4 MiB stay spare.
TRAVEL_LIMIT = 60 * MIB
#: The whole run on the device: one tool call is at most 10 minutes; this
#: leaves a minute for the machine's own start of the command and the
#: transfer of $OUT.
ENVELOPE_S = 540
#: The D-CNN training's budget on the device (the rest of the envelope, at
#: most this), and what the steps after it need.
TRAIN_BUDGET_S = 300
AFTER_TRAIN_S = 30
#: The Vulkan loader and GL libraries the device image lacks (the device
#: tool's README recipe); wgpu needs libvulkan1, the rest lets it probe GL.
GL_PACKAGES = ["libvulkan1", "libegl1", "libglvnd0", "libopengl0", "libgl1", "libglx0", "libgles2"]
NVIDIA_ICD = "/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json"
NVIDIA_EGL = "/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json"


@dataclass
class Step:
    name: str
    what: str
    cap_s: float
    records: list = field(default_factory=list)
    status: str = "not run"
    seconds: float = 0.0
    note: str = ""
    commands: list = field(default_factory=list)
    text: str = ""

    def summary(self) -> dict:
        out = {"name": self.name, "what": self.what, "status": self.status, "seconds": round(self.seconds, 1),
               "cap_s": self.cap_s, "note": self.note, "files": STEP_FILES.get(self.name, []),
               "commands": self.commands, "records": self.records}
        if self.text:
            out["text"] = self.text
        return out


#: The files under $OUT each step writes (every step's output is also in
#: log.txt, and its figures in summary.json and report.md).
STEP_FILES = {"train": ["metrics.csv"],
              "export": ["dcnn-full.onnx", "dcnn-full.card.json", "dcnn-full.doe.safetensors"]}


class Failed(Exception):
    """A step's command failed; the step says why and the run goes on."""


class Runner:
    def __init__(self, out: Path, smoke: bool, only: set | None = None):
        self.out = out
        self.smoke = smoke
        self.only = only
        self.start = time.monotonic()
        self.log = open(out / "log.txt", "w")
        self.env = dict(os.environ)
        self.env["PYTHONPATH"] = str(REPO / "models") + os.pathsep + self.env.get("PYTHONPATH", "")
        self.env["PYTHONUNBUFFERED"] = "1"
        self.env.setdefault("XDG_RUNTIME_DIR", "/tmp")
        self.work = Path(tempfile.mkdtemp(prefix="nedrt-devcheck-"))
        self.python = sys.executable
        self.nedrt = None
        self.step: Step | None = None
        # What one step leaves for the next: the teacher, the images, the run.
        self.teacher = self.images = self.run_dir = None
        self.teacher_set = "train-ceiling"
        self.adapter = None

    def need_gpu_adapter(self):
        """On the device, the wgpu steps run only on the GPU's adapter."""
        if not self.smoke and (self.adapter is None or "Cpu" in self.adapter or "NVIDIA" not in self.adapter):
            raise Failed(f"wgpu's adapter is {self.adapter!r}, not the NVIDIA GPU (see setup in log.txt)")

    def left(self) -> float:
        return ENVELOPE_S - (time.monotonic() - self.start)

    def say(self, text: str):
        print(text, flush=True)
        self.log.write(text + "\n")
        self.log.flush()

    def sh(self, args: list, timeout: float, env: dict | None = None, parse_json=True) -> str:
        """Runs one command of the current step under `timeout` (and the
        envelope), logs its output, collects its JSON lines as records."""
        args = [str(a) for a in args]
        if not self.smoke:
            timeout = min(timeout, max(self.left() - AFTER_TRAIN_S / 3, 1))
        self.step.commands.append(" ".join(args))
        self.say(f"$ {' '.join(args)}")
        try:
            p = subprocess.run(args, cwd=REPO, env={**self.env, **(env or {})}, capture_output=True, text=True,
                               timeout=timeout)
        except subprocess.TimeoutExpired as e:
            out = (e.stdout or b"").decode() if isinstance(e.stdout, bytes) else (e.stdout or "")
            err = (e.stderr or b"").decode() if isinstance(e.stderr, bytes) else (e.stderr or "")
            self.log.write(out + err)
            raise Failed(f"timed out after {timeout:.0f} s: {args[0]} {args[1] if len(args) > 1 else ''}")
        self.log.write(p.stdout)
        self.log.write(p.stderr)
        self.log.flush()
        if parse_json:
            for line in p.stdout.splitlines():
                line = line.strip()
                if line.startswith("{"):
                    try:
                        self.step.records.append(json.loads(line))
                    except json.JSONDecodeError:
                        pass
        if p.returncode != 0:
            tail = (p.stderr or p.stdout).strip().splitlines()[-3:]
            raise Failed(f"{exit_status(p.returncode)}: " + " / ".join(tail))
        return p.stdout

    def parallel(self, commands: list, deadline: float, mem_gib: float | None = None):
        """Runs the commands side by side until `deadline`; every one must
        succeed. With `mem_gib` (one command's peak), no more run at once
        than the machine's available memory holds."""
        at_once = len(commands)
        if mem_gib:
            at_once = max(1, min(at_once, int(available_gib() // mem_gib)))
        queue = [[str(a) for a in c] for c in commands]
        running, failed = [], []  # (process, its output file)
        try:
            while queue or running:
                while queue and len(running) < at_once:
                    args = queue.pop(0)
                    self.step.commands.append(" ".join(args))
                    self.say(f"$ {' '.join(args)} &")
                    out = tempfile.TemporaryFile("w+")
                    running.append((subprocess.Popen(args, cwd=REPO, env=self.env, stdout=out,
                                                     stderr=subprocess.STDOUT, text=True), out))
                if time.monotonic() > deadline:
                    raise Failed(f"timed out: {' '.join(running[0][0].args[:3])}")
                done = [(p, out) for p, out in running if p.poll() is not None]
                if not done:
                    time.sleep(0.1)
                for p, out in done:
                    running.remove((p, out))
                    out.seek(0)
                    text = out.read()
                    out.close()
                    self.log.write(text)
                    if p.returncode:
                        failed.append(f"{' '.join(p.args[:4])}: {exit_status(p.returncode)}: "
                                      + " / ".join(text.strip().splitlines()[-2:]))
        finally:
            for p, out in running:
                p.kill()
                p.wait()
                # What it got through before the deadline: the next run's cap comes from it.
                out.seek(0)
                tail = out.read().strip().splitlines()[-5:]
                self.log.write(f"[stopped: {' '.join(p.args[:4])} ... {' '.join(p.args[-2:])}; its last lines:]\n"
                               + "".join(f"  {line}\n" for line in tail))
                out.close()
        self.log.flush()
        if failed:
            raise Failed("; ".join(failed))

    def run(self, step: Step, body, needs: list = ()):
        self.step = step
        if self.only and step.name not in self.only:
            step.status, step.note = "skipped", "not asked for (--only)"
            return
        for other in needs:
            if other.status != "ok":
                step.status, step.note = "skipped", f"needs step {other.name} ({other.status})"
                self.say(f"== {step.name}: skipped ({step.note})")
                return
        if not self.smoke and self.left() < 5:
            step.status, step.note = "skipped", "the envelope is spent"
            self.say(f"== {step.name}: skipped ({step.note})")
            return
        self.say(f"== {step.name}: {step.what} (cap {step.cap_s:.0f} s)")
        t = time.monotonic()
        try:
            body(step)
            step.status = "ok"
        except Failed as e:
            step.status, step.note = ("timeout" if "timed out" in str(e) else "failed"), str(e)
        except Exception as e:  # a bug of this script must not lose the others' results
            step.status, step.note = "failed", f"{type(e).__name__}: {e}"
        step.seconds = time.monotonic() - t
        self.say(f"== {step.name}: {step.status} in {step.seconds:.1f} s {step.note}")


def sizes(smoke: bool) -> dict:
    """Every size the steps use, full or smoke."""
    if smoke:
        return {"frame": "64x64", "layer_frame": "32x32", "panel": "128x72", "frames": 5, "repeat": 1,
                "torch_repeat": 2, "pipeline_s": 20, "train_images": 2, "val_images": 1, "crop": 64, "val_crop": 48,
                "patch": 32, "width": 4, "levels": 2, "ceiling_iterations": 3, "ceiling_shards": 2,
                "steps": 3, "validate_every": 2, "max_batch": 2, "budget_s": 60, "copy_mb": 16, "gemm": 256}
    return {"frame": "1920x1080", "layer_frame": "1920x1080", "panel": "1920x1080", "frames": 200, "repeat": 10,
            "torch_repeat": 20, "pipeline_s": 8, "train_images": None, "val_images": None, "crop": None,
            "val_crop": None, "patch": 128, "width": 32, "levels": 4, "ceiling_iterations": 200, "ceiling_shards": 16,
            "steps": 1_000_000, "validate_every": 500, "max_batch": 64, "budget_s": TRAIN_BUDGET_S,
            "copy_mb": 2048, "gemm": 8192}


def caps() -> list:
    """(step, what, cap s) of the full run; the training's is its budget."""
    return [
        ("setup", "the binary unpacked, the Vulkan loader, the adapter named", 20),
        ("ceilings", "the GPU's copy bandwidth and GEMM rates through PyTorch (the floors' peaks)", 20),
        ("wgsl", "the D-CNN at 1920×1080 through nedrt's WGSL: full and half, f32 and f16", 30),
        ("per-layer", "each layer's device time and its floor (timestamp queries)", 30),
        ("torch", "the same networks in PyTorch: f32 (TF32 off), TF32, f16 channels-last; cuDNN benchmark", 40),
        ("fft", "the prefilters' transform at 1920×1080: nedrt's DCT filter, the CPU's, torch.fft (cuFFT)", 30),
        ("pipeline", "nedrt bench pipeline at 1920×1080 on the device path: none, the Wiener, refine:10, "
                     "half, full, the shipped model", 90),
        ("teacher", "the D-CNN's teacher: nedrt prefilter on the CPU, the training ceiling on CUDA", 105),
        ("train", "the full-width D-CNN on CUDA (bf16 autocast, the largest batch that fits)", TRAIN_BUDGET_S),
        ("export", "the network as the runtime's ONNX with its card", 20),
    ]


# ---------------------------------------------------------------- the steps

def step_setup(r: Runner, s: Step, z: dict):
    if r.smoke:
        binary = REPO / "target" / "release" / "nedrt"
        if not binary.is_file():
            r.sh(["cargo", "build", "--release", "-p", "nedrt"], 1800, parse_json=False)
        r.nedrt = binary
    else:
        packed = CARRY / "nedrt.xz"
        if not packed.is_file():
            raise Failed(f"{packed}: not here; run `bash scripts/device-check.sh --prepare` here and carry .devcheck")
        binary = r.work / "nedrt"
        with lzma.open(packed) as src, open(binary, "wb") as dst:
            shutil.copyfileobj(src, dst)
        binary.chmod(0o755)
        r.nedrt = binary
        libs = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True).stdout
        if "libvulkan.so.1" not in libs:
            debs = sorted((CARRY / "gl").glob("*.deb"))
            if not debs:
                raise Failed(f"{CARRY / 'gl'}: no loader packages, and the machine has no libvulkan")
            for deb in debs:
                r.sh(["dpkg", "-x", deb, "/"], 30, parse_json=False)
            r.sh(["ldconfig"], 30, parse_json=False)
        icds = [p for d in ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d") for p in Path(d).glob("*.json")]
        if not any("nvidia" in p.name for p in icds) and Path(NVIDIA_ICD).is_file():
            r.env["VK_DRIVER_FILES"] = NVIDIA_ICD
            r.env["__EGL_VENDOR_LIBRARY_FILENAMES"] = NVIDIA_EGL
        if shutil.which("nvidia-smi"):
            s.text = r.sh(["nvidia-smi", "--query-gpu=name,driver_version,memory.total,clocks.max.sm",
                           "--format=csv,noheader"], 20, parse_json=False).strip()
    r.sh([r.nedrt, "--version"], 20, parse_json=False)
    # Which adapter wgpu takes: on the device it must be the GPU, not a
    # software one (a 1080p network on llvmpipe would eat the envelope).
    out = r.sh([r.nedrt, "bench", "inference", "--backends", "wgpu", "--sizes", "16x16", "--repeat", "1"], 60)
    adapter = next((x["device"] for x in s.records if x.get("kind") == "dcnn_latency"), "none")
    s.records[:] = [x for x in s.records if x.get("kind") != "dcnn_latency"]
    s.records.append({"kind": "adapter", "describe": adapter})
    r.adapter = adapter
    del out
    manifest = CARRY / "manifest.json"
    s.records.append({"kind": "build", **(json.loads(manifest.read_text()) if manifest.is_file() and not r.smoke
                                          else {"commit": git_commit()})})


def step_ceilings(r: Runner, s: Step, z: dict):
    r.sh([r.python, REPO / "tools/bench/torch_dcnn.py", "--ceilings", "--copy-mb", z["copy_mb"],
          "--gemm", z["gemm"]], 60)


def peaks(ceilings: Step) -> dict:
    """The floors' flags from the measured ceilings: {"--peak-gmacs": …,
    "--peak-gbps": …}, or nothing where they were not measured."""
    rec = next((x for x in ceilings.records if x.get("kind") == "ceilings"), None)
    if ceilings.status != "ok" or rec is None:
        return {}
    # The WGSL kernels run on the CUDA cores, not the tensor cores: their
    # peak is the f32 FMA rate, which a cuBLAS SGEMM with TF32 off reaches.
    return {"--peak-gmacs": f"{rec['f32_gemm_tflops'] * 1e3 / 2:.0f}", "--peak-gbps": f"{rec['copy_gbps']:.0f}"}


def flags(pairs: dict) -> list:
    return [v for kv in pairs.items() for v in kv]


def step_wgsl(r: Runner, s: Step, z: dict):
    r.need_gpu_adapter()
    r.sh([r.nedrt, "bench", "inference", "--backends", "wgpu", "--sizes", z["frame"], "--repeat", z["repeat"],
          "--max-seconds", 60], s.cap_s)


def step_per_layer(r: Runner, s: Step, z: dict, ceilings: Step):
    r.need_gpu_adapter()
    s.text = r.sh([r.nedrt, "bench", "inference", "--per-layer", "--sizes", z["layer_frame"], "--repeat",
                   z["repeat"], *flags(peaks(ceilings))], s.cap_s, parse_json=False)


def step_torch(r: Runner, s: Step, z: dict):
    r.sh([r.python, REPO / "tools/bench/torch_dcnn.py", "--sizes", z["frame"], "--repeat", z["torch_repeat"]],
         s.cap_s)


def step_fft(r: Runner, s: Step, z: dict, ceilings: Step):
    r.need_gpu_adapter()
    bw = flags({k: v for k, v in peaks(ceilings).items() if k == "--peak-gbps"})
    out = r.sh([r.nedrt, "bench", "fft", "--sizes", z["frame"], "--repeat", z["torch_repeat"], "--per-layer", *bw],
               s.cap_s)
    s.text = "\n".join(line for line in out.splitlines() if not line.startswith("{"))
    r.sh([r.python, REPO / "tools/bench/torch_dcnn.py", "--fft", "--sizes", z["frame"], "--repeat",
          z["torch_repeat"]], s.cap_s)


def step_pipeline(r: Runner, s: Step, z: dict):
    r.need_gpu_adapter()
    out = r.sh([r.nedrt, "--design", "multifocal", "bench", "pipeline", "--networks",
                "none,wiener,refine10,half,full,model", "--frame-paths", "device",
                "--panel", z["panel"], "--frames", z["frames"], "--max-seconds", z["pipeline_s"]], s.cap_s)
    s.text = "\n".join(line for line in out.splitlines() if not line.startswith("{"))


def step_teacher(r: Runner, s: Step, z: dict, device: str):
    """The teacher folders of docs/training.md (the v10 recipe) under the
    work folder; in smoke, of a tiny image set cut from the training photos."""
    images = REPO / "data" / "images"
    if r.smoke:
        images = tiny_images(r.work / "images", z)
    t = r.work / "teacher"
    # The kernels at the patch size (the loss), the training photographs'
    # size (their ceiling) and the validation photographs' (validation).
    ops = ",".join(f"{n}x{n}" for n in sorted({z["patch"], square(images / "train"), square(images / "val")}))
    cores = os.cpu_count() or 2
    # Seven independent commands side by side, the cores shared among them:
    # each spends seconds on its PSFs before its parallel solves.
    design = [r.nedrt, "--threads", max(cores // 7, 1), "--design", "multifocal", "prefilter"]
    deadline = deadline_after(r, s)
    # The first command alone computes the design's PSFs and caches them
    # for the others. Each command peaks at 3.8 GB (the design's PSFs and
    # its plans, whatever the image size): seven at once overran a 24 GiB CI
    # machine and were killed, so they run as many at once as memory holds.
    r.parallel([[*design, "--images", images / "val", "--out-dir", t / "val-wiener", "--prefilter", "native"]],
               deadline)
    r.parallel([
        [*design, "--images", images / "train", "--out-dir", t / "train", "--operator", ops],
        [*design, "--images", images / "val", "--out-dir", t / "val"],
        [*design, "--images", images / "train", "--out-dir", t / "train-wiener", "--prefilter", "native"],
        [*design, "--images", images / "train", "--out-dir", t / "train-sharp", "--prefilter", "optimal@sharp",
         "--operator", ops],
        *[[*design, "--images", images / split, "--out-dir", t / f"{split}-wiener-raw", "--prefilter", "native",
           "--unclamped"] for split in ("train", "val")],
    ], deadline, mem_gib=4.5)
    # The ceiling of the training photographs, in shares side by side (the
    # solver is scipy's, on the CPU; its objective on the device).
    n = z["ceiling_shards"]
    cmd = [r.python, "-m", "nedrt_train", "ceiling", "--teacher", t, "--images", images, "--split", "train",
           "--sharp-weight", "1", "--iterations", z["ceiling_iterations"], "--write", t / "train-ceiling",
           "--device", device]
    r.teacher, r.images = t, images
    try:
        r.parallel([cmd + ["--shard", f"{k}/{n}"] for k in range(1, n + 1)], deadline)
    except Failed as e:
        # Better a network distilled from the summed optimum than none.
        r.teacher_set = "train"
        s.note = f"the training ceiling failed ({e}); the training distils optimal@target (teacher set train)"
        r.say(f"   {s.note}")


def available_gib() -> float:
    """MemAvailable of /proc/meminfo (the machine's total where that is
    unreadable), or less where a cgroup v2 limit leaves less."""
    gib = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                gib = int(line.split()[1]) / 2**20
    except OSError:
        pass
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            used = int(Path("/sys/fs/cgroup/memory.current").read_text())
            gib = min(gib, (int(limit) - used) / 2**30)
    except (OSError, ValueError):
        pass
    return gib


def exit_status(code: int) -> str:
    """A child's exit, naming the signal that killed it (SIGKILL: often the OOM killer)."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit {code}"


def deadline_after(r: Runner, s: Step) -> float:
    """The monotonic time by which the step must end: its cap, within the envelope."""
    cap = s.cap_s if r.smoke else max(min(s.cap_s, r.left() - AFTER_TRAIN_S), 1)
    return time.monotonic() + cap


def step_train(r: Runner, s: Step, z: dict, device: str):
    budget = z["budget_s"] if r.smoke else max(min(TRAIN_BUDGET_S, r.left() - AFTER_TRAIN_S - 30), 10)
    s.cap_s = round(budget)
    run = r.work / "run"
    r.sh([r.python, "-m", "nedrt_train", "dcnn", "--teacher", r.teacher, "--images", r.images, "--out", run,
          "--width", z["width"], "--levels", z["levels"], "--patch", z["patch"], "--input", "wiener-raw",
          "--clamp-grad", "straight", "--teacher-set", r.teacher_set, "--distill", "1000",
          "--distill-metric", "perceived", "--loss", "psnr", "--sharp-weight", "1", "--lr", "1e-3",
          "--steps", z["steps"], "--time-budget", f"{budget:.0f}", "--validate-every", z["validate_every"],
          "--checkpoint-every", 1000, "--device", device, "--amp", "bf16" if device == "cuda" else "off",
          "--batch", 0, "--max-batch", z["max_batch"]], budget + 120, parse_json=False)
    result = json.loads((run / "result.json").read_text())
    s.records.append({"kind": "train", "steps": result["steps"], "seconds": result["seconds"],
                      "batch": result["config"]["batch"], "device": result.get("device"),
                      "validation": result["validation"][-1:] if result["validation"] else []})
    shutil.copyfile(run / "metrics.csv", r.out / "metrics.csv")
    r.run_dir = run


def step_export(r: Runner, s: Step, z: dict):
    r.sh([r.python, "-m", "nedrt_train", "dcnn", "export", "--run", r.run_dir, "--out", r.out, "--name",
          "dcnn-full", "--doe", REPO / "designs" / "multifocal" / "doe-fabrication.safetensors"], s.cap_s,
         parse_json=False)
    card = json.loads((r.out / "dcnn-full.card.json").read_text())
    s.records.append({"kind": "export", "files": card["files"], "steps": card["steps"],
                      "finished": card["finished"], "trained_on": card.get("trained_on")})


def square(folder: Path) -> int:
    """The side of the folder's (square, equal) photographs."""
    from PIL import Image
    found = {Image.open(p).size for p in sorted(folder.glob("*.png"))}
    if len(found) != 1 or len({*next(iter(found))}) != 1:
        raise Failed(f"{folder}: photographs of one square size expected, found {sorted(found)}")
    return next(iter(found))[0]


def tiny_images(root: Path, z: dict) -> Path:
    """Smoke: the first training and validation photographs, centre crops."""
    from PIL import Image
    for split, count, size in (("train", z["train_images"], z["crop"]), ("val", z["val_images"], z["val_crop"])):
        (root / split).mkdir(parents=True, exist_ok=True)
        for path in sorted((REPO / "data" / "images" / split).glob("*.png"))[:count]:
            im = Image.open(path).convert("RGB")
            x, y = (im.width - size) // 2, (im.height - size) // 2
            im.crop((x, y, x + size, y + size)).save(root / split / path.name)
    return root


# ---------------------------------------------------------------- the report

def report(steps: dict, meta: dict) -> str:
    head = f"{meta['device']}, commit {meta['commit']}{' (+ local changes)' if meta.get('dirty') else ''}"
    md = [f"# Device check: {head}", "",
          f"Mode {meta['mode']}, {meta['date']}; `bash scripts/device-check.sh"
          f"{' --smoke' if meta['mode'] == 'smoke' else ''}`. Steps:", "",
          "| step | status | seconds | cap s | note |", "| --- | --- | --- | --- | --- |"]
    for s in steps.values():
        md.append(f"| {s.name} | {s.status} | {s.seconds:.1f} | {s.cap_s:.0f} | {s.note.replace('|', '/')} |")
    ceil = next((x for x in steps["ceilings"].records if x.get("kind") == "ceilings"), None)
    if ceil:
        rate = lambda k: "–" if ceil.get(k) is None else f"{ceil[k]:.1f}"
        md += ["", f"Ceilings ({head}): device copy {ceil['copy_gbps']:.0f} GB/s (read + write), GEMM "
                   f"{rate('f32_gemm_tflops')} TFLOP/s in f32 (TF32 off), {rate('tf32_gemm_tflops')} in TF32, "
                   f"{rate('f16_gemm_tflops')} in f16."]
    wgsl = [x for x in steps["wgsl"].records if x.get("kind") == "dcnn_latency"]
    torch_rows = [x for x in steps["torch"].records if x.get("kind") == "dcnn_latency"]
    if wgsl or torch_rows:
        md += ["", f"## The D-CNN, nedrt's WGSL against PyTorch ({head})", "",
               "| model | backend | precision | frame | median ms | min ms | GMAC/s | WGSL ÷ PyTorch (same precision) |",
               "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for x in wgsl + torch_rows:
            ratio = ""
            if x["backend"] == "wgpu":
                twin = "f32" if x["precision"] == "f32" else "f16"
                t = next((y for y in torch_rows if y["model"] == x["model"] and y["precision"] == twin
                          and (y["width"], y["height"]) == (x["width"], x["height"])), None)
                ratio = f"{x['median_s'] / t['median_s']:.2f}" if t else ""
            md.append(f"| {x['model']} | {x['backend']} | {x['precision']} | {x['width']}×{x['height']} | "
                      f"{x['median_s'] * 1e3:.2f} | {x['min_s'] * 1e3:.2f} | {x['gmac_per_s']:.0f} | {ratio} |")
    if steps["per-layer"].text:
        md += ["", f"## Per layer ({head})", steps["per-layer"].text]
    if steps["fft"].text:
        md += ["", f"## The prefilters' transform ({head})", "", steps["fft"].text]
        for x in steps["fft"].records:
            if x.get("backend") == "torch.fft":
                md.append(f"\ntorch.fft (mirror, rfft2, gain, irfft2) {x['width']}×{x['height']}: "
                          f"{x['median_s'] * 1e3:.3f} ms median on {x['device']}.")
    if steps["pipeline"].text:
        md += ["", f"## The pipeline end to end ({head})", "", steps["pipeline"].text]
    tr = next((x for x in steps["train"].records if x.get("kind") == "train"), None)
    if tr:
        v = tr["validation"][0] if tr["validation"] else {}
        fmt = lambda k: f"{v[k]:.2f}" if isinstance(v.get(k), (int, float)) else "–"
        md += ["", f"## The full-width D-CNN trained on the device ({head})", "",
               f"{tr['steps']} steps of batch {tr['batch']} in {tr['seconds']:.0f} s on {tr['device']}. "
               "Validation (the trainer's, on data/images/val):", "",
               "| | mean / worst vs target dB | mean / worst vs sharp dB |", "| --- | --- | --- |",
               f"| D-CNN | {fmt('dcnn_mean_db')} / {fmt('dcnn_worst_db')} | "
               f"{fmt('dcnn_sharp_mean_db')} / {fmt('dcnn_sharp_worst_db')} |",
               f"| its Wiener | {fmt('wiener_mean_db')} / {fmt('wiener_worst_db')} | "
               f"{fmt('wiener_sharp_mean_db')} / {fmt('wiener_sharp_worst_db')} |"]
    return "\n".join(md) + "\n"


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=REPO, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def git_dirty() -> bool:
    try:
        return bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO,
                                   capture_output=True, text=True, check=True).stdout.strip())
    except (OSError, subprocess.CalledProcessError):
        return False


def check(out: Path, smoke: bool, only: set | None = None) -> int:
    out.mkdir(parents=True, exist_ok=True)
    r = Runner(out, smoke, only)
    z = sizes(smoke)
    device = "cpu" if smoke else "cuda"
    steps = {name: Step(name, what, cap) for name, what, cap in caps()}
    if smoke:
        for s in steps.values():
            s.cap_s = max(s.cap_s, 300)  # lavapipe and the 2-core CPU: generous, tiny sizes
    manifest = CARRY / "manifest.json"
    built = json.loads(manifest.read_text()) if manifest.is_file() and not smoke else {}
    meta = {"mode": "smoke" if smoke else "device", "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "commit": built.get("commit") or git_commit(), "dirty": built.get("dirty", git_dirty()),
            "device": "this machine's CPU and lavapipe" if smoke else "unknown", "envelope_s": ENVELOPE_S}
    r.run(steps["setup"], lambda s: step_setup(r, s, z))
    if steps["setup"].text:
        meta["device"] = steps["setup"].text.splitlines()[0]
    r.run(steps["ceilings"], lambda s: step_ceilings(r, s, z))
    r.run(steps["wgsl"], lambda s: step_wgsl(r, s, z), [steps["setup"]])
    r.run(steps["per-layer"], lambda s: step_per_layer(r, s, z, steps["ceilings"]), [steps["setup"]])
    r.run(steps["torch"], lambda s: step_torch(r, s, z))
    r.run(steps["fft"], lambda s: step_fft(r, s, z, steps["ceilings"]), [steps["setup"]])
    r.run(steps["pipeline"], lambda s: step_pipeline(r, s, z), [steps["setup"]])
    r.run(steps["teacher"], lambda s: step_teacher(r, s, z, device), [steps["setup"]])
    r.run(steps["train"], lambda s: step_train(r, s, z, device), [steps["teacher"]])
    r.run(steps["export"], lambda s: step_export(r, s, z), [steps["train"]])
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


# ------------------------------------------------------- here: prepare, plan

def prepare() -> int:
    """Builds .devcheck/: the release binary, stripped and compressed, the
    Vulkan loader packages, and a manifest naming the commit."""
    CARRY.mkdir(exist_ok=True)
    subprocess.run(["cargo", "build", "--release", "-p", "nedrt"], cwd=REPO, check=True)
    built = REPO / "target" / "release" / "nedrt"
    stripped = CARRY / "nedrt.stripped"
    shutil.copyfile(built, stripped)
    subprocess.run(["strip", stripped], check=True)
    with open(stripped, "rb") as src, lzma.open(CARRY / "nedrt.xz.tmp", "wb", preset=9) as dst:
        shutil.copyfileobj(src, dst)
    (CARRY / "nedrt.xz.tmp").replace(CARRY / "nedrt.xz")
    digest = hashlib.sha256(stripped.read_bytes()).hexdigest()
    sizes_mib = {"built": round(built.stat().st_size / MIB, 2), "stripped": round(stripped.stat().st_size / MIB, 2),
                 "xz": round((CARRY / "nedrt.xz").stat().st_size / MIB, 2)}
    stripped.unlink()
    gl = CARRY / "gl"
    gl.mkdir(exist_ok=True)
    if not list(gl.glob("*.deb")):
        lists = Path(tempfile.mkdtemp(prefix="apt-amd64-"))
        (lists / "partial").mkdir()
        opts = ["-oAPT::Architecture=amd64", "-oAPT::Architectures=amd64", f"-oDir::State::Lists={lists}"]
        subprocess.run(["apt-get", *opts, "update"], check=True, stdout=subprocess.DEVNULL)
        subprocess.run(["apt-get", *opts, "download", *GL_PACKAGES], cwd=gl, check=True)
    manifest = {"commit": git_commit(), "dirty": git_dirty(), "binary_sha256": digest, "binary_mib": sizes_mib,
                "built": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                "gl": sorted(p.name for p in gl.glob("*.deb"))}
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
    print(f"\nSteps on the device, each under its cap (the envelope is {ENVELOPE_S} s = {ENVELOPE_S / 60:.0f} min):")
    fixed = [(n, w, c) for n, w, c in caps() if n != "train"]
    least = ENVELOPE_S - sum(c for _, _, c in fixed)
    for name, what, cap in caps():
        shown = (f"{least}–{cap} s (what is left)" if name == "train" else f"≤ {cap} s")
        print(f"  {name:10} {shown:22} {what}")
    est = min(ENVELOPE_S, sum(c for _, _, c in fixed) + TRAIN_BUDGET_S)
    print(f"Estimated device time: ≤ {est} s ({est / 60:.1f} min) of the command, plus the machine's start; "
          "call the tool with timeout_s=600:")
    print('  run(command="bash scripts/device-check.sh", carry=[".devcheck"], timeout_s=600)')
    if total > TRAVEL_LIMIT:
        print(f"error: {total / MIB:.2f} MiB would travel, over {TRAVEL_LIMIT / MIB:.0f} MiB", file=sys.stderr)
        return 1
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="scripts/device-check.sh", description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--smoke", action="store_true", help="every step at tiny sizes on this machine's CPU")
    mode.add_argument("--prepare", action="store_true", help="build .devcheck/ (what travels), then --plan")
    mode.add_argument("--plan", action="store_true", help="what travels, its size, each step's cap")
    ap.add_argument("--only", metavar="STEPS", help="only these steps, comma-separated (a rerun of some): "
                    + ",".join(n for n, _, _ in caps()))
    args = ap.parse_args(argv)
    only = None
    if args.only:
        only = {v.strip() for v in args.only.split(",") if v.strip()}
        unknown = only - {n for n, _, _ in caps()}
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
    return check(Path(out), args.smoke, only)


if __name__ == "__main__":
    sys.exit(main())
