"""The device check's machinery (tools/device/check.py is the entry point):
the limits it keeps, a step and its outcome, and the runner that runs each
step's commands under its cap and the envelope of one device-tool call,
logging their output and collecting their JSON lines."""
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
#: What may come back from one call: the device tool's limit is 8 files
#: (summary.json, report.md, log.txt and the steps' STEP_FILES).
FILES_BACK = 8
#: The whole run on the device: one tool call is at most 10 minutes; this
#: leaves a minute for the machine's own start of the command and the
#: transfer of $OUT.
ENVELOPE_S = 540
#: The second call (`--call 2`, the steps the first leaves no room for),
#: right after the first on the warm machine: with the machine's start,
#: both fit the 15 minutes of device time a task is lent.
ENVELOPE2_S = 210
#: A task's device time, all calls and the machine's start together.
DEVICE_TIME_S = 900
#: What a machine's start costs of it (1 to 2 minutes).
START_S = 120
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
STEP_FILES = {"train": ["metrics.csv", "checkpoint/card.json", "checkpoint/tensors-<sha256[:16]>.safetensors"],
              "export": ["dcnn-full.onnx", "dcnn-full.card.json"],
              "tune": ["<adapter-driver>.toml"],
              "tradeoff": ["tradeoff.md", "tradeoff.json", "tradeoff.svg", "tradeoff.png"]}


class Failed(Exception):
    """A step's command failed; the step says why and the run goes on."""


class Runner:
    def __init__(self, out: Path, smoke: bool, only: set | None = None, envelope: float = ENVELOPE_S):
        self.out = out
        self.envelope = envelope
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
        self.teacher_set = "train"
        # The commit the run is of (the session's note in the carried checkpoint).
        self.commit = "unknown"
        self.adapter = None
        # The adapter's cooperative-matrix shapes, as the bench names them.
        self.coop = None

    def need_gpu_adapter(self):
        """On the device, the wgpu steps run only on the GPU's adapter."""
        if not self.smoke and (self.adapter is None or "Cpu" in self.adapter or "NVIDIA" not in self.adapter):
            raise Failed(f"wgpu's adapter is {self.adapter!r}, not the NVIDIA GPU (see setup in log.txt)")

    def left(self) -> float:
        return self.envelope - (time.monotonic() - self.start)

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



#: What the smoke's Python side imports: PyTorch and the trainer's needs.
NEEDED_MODULES = ["torch", "numpy", "scipy", "PIL", "safetensors", "onnx", "nedrt_train"]


def missing_modules(python: str, env: dict) -> list:
    """The modules of NEEDED_MODULES that `python` cannot import with `env`."""
    probe = ("import importlib.util, sys\n"
             "print(' '.join(m for m in sys.argv[1:] if importlib.util.find_spec(m) is None))")
    p = subprocess.run([python, "-c", probe, *NEEDED_MODULES], env=env, capture_output=True, text=True)
    if p.returncode != 0:
        return list(NEEDED_MODULES)
    return p.stdout.split()


def no_venv_message(python: str, missing: list) -> str:
    """What a new user is told when the smoke's Python lacks the trainer's modules."""
    return (f"error: {python} cannot import {', '.join(missing)}: the smoke runs PyTorch and the trainer "
            "from the trainer's virtual environment .venv, which `bash scripts/test.sh` makes (it installs "
            "tests/python/requirements.txt and models/requirements.txt, then the trainer with "
            "`.venv/bin/pip install --no-build-isolation -e models`); make it, then run the smoke again")


def strip_and_pack(built: Path, packed: Path) -> Path:
    """Strips a copy of `built` beside `packed` and xz-compresses it to
    `packed` (written whole or not at all); the stripped copy is returned
    for the caller to measure, then to delete."""
    stripped = packed.with_name(packed.name + ".stripped")
    shutil.copyfile(built, stripped)
    subprocess.run(["strip", stripped], check=True)
    part = packed.with_name(packed.name + ".part")
    with open(stripped, "rb") as src, lzma.open(part, "wb", preset=9) as dst:
        shutil.copyfileobj(src, dst)
    part.replace(packed)
    return stripped


def unpack(packed: Path, target: Path) -> Path:
    """The executable `strip_and_pack` made, decompressed to `target` (on
    the device machine), or Failed if it was not carried."""
    if not packed.is_file():
        raise Failed(f"{packed}: not here; run `bash scripts/device-check.sh --prepare` here and carry .devcheck")
    with lzma.open(packed) as src, open(target, "wb") as dst:
        shutil.copyfileobj(src, dst)
    target.chmod(0o755)
    return target


def apt_download(dest: Path, packages: list):
    """Debian's amd64 `packages` as .deb files into `dest`, unless some are
    there already (apt's own lists kept apart, in a temporary folder)."""
    dest.mkdir(parents=True, exist_ok=True)
    if list(dest.glob("*.deb")):
        return
    lists = Path(tempfile.mkdtemp(prefix="apt-amd64-"))
    (lists / "partial").mkdir()
    opts = ["-oAPT::Architecture=amd64", "-oAPT::Architectures=amd64", f"-oDir::State::Lists={lists}"]
    subprocess.run(["apt-get", *opts, "update"], check=True, stdout=subprocess.DEVNULL)
    subprocess.run(["apt-get", *opts, "download", *packages], cwd=dest, check=True)
