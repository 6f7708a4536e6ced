"""The shipping rule, automated and on record (issue 41 item 3;
docs/training.md, "Shipping decisions").

    nedrt-train judge --candidate out/devcheck/dcnn-full.onnx            # score, log, decide
    nedrt-train judge --candidate out/devcheck/dcnn-full.onnx --ship     # and ship it if it passes

One command scores a returned network against its own Wiener and the
shipped network on the validation photographs, with `nedrt eval` (the
candidate and its Wiener in one run, `--methods proposed,doe+wiener`; the
shipped network in another). The table and the verdict go into
docs/training.md's log whether the network ships or not. It ships when it
beats its Wiener on the mean and the worst depth, both vs sharp and vs
target, with no SSIM of the four lower (at the tables' precision: 0.01 dB,
0.001 SSIM). With `--ship`, a network that
passes replaces `models/dcnn.onnx`, its card and its DOE (the DOE its card
names, checked against the card's SHA-256). The new files are written
beside the old ones first and then renamed, so a failure leaves the
shipped network as it was.
"""
import argparse
import datetime
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from .atomic import atomic_write, write_beside

#: The headline numbers the rule looks at, as (eval.json key, row name).
HEADLINES = (("headline_vs_target", "mean", "mean vs target"), ("headline_vs_target", "worst", "worst vs target"),
             ("headline_vs_sharp", "mean", "mean vs sharp"), ("headline_vs_sharp", "worst", "worst vs sharp"))
#: Where the log's entries go in docs/training.md.
LOG_HEADING = "## Shipping decisions (nedrt-train judge)"


class JudgeError(Exception):
    """A clear error: what is wrong and with which file."""


@dataclass
class Scores:
    """One network's (or Wiener's) four headline numbers: name → (PSNR dB, SSIM)."""
    label: str
    numbers: dict

    @staticmethod
    def of(row: dict, label: str, source: str) -> "Scores":
        numbers = {}
        for key, which, name in HEADLINES:
            try:
                x = row[key][which]
                numbers[name] = (float(x["psnr_db"]), float(x["ssim"]))
            except (KeyError, TypeError, ValueError) as e:
                raise JudgeError(f"{source}: the row {row.get('method')!r} has no {key}.{which} ({e})") from e
        return Scores(label, numbers)

    def cell(self, metric: str) -> str:
        """"mean / worst dB (SSIM mean / worst)" for "target" or "sharp"."""
        (m, ms), (w, ws) = self.numbers[f"mean vs {metric}"], self.numbers[f"worst vs {metric}"]
        return f"{m:.2f} / {w:.2f} ({ms:.3f} / {ws:.3f})"


def verdict(candidate: Scores, wiener: Scores) -> list:
    """Why the candidate may not ship (empty: it ships): every headline
    number not above its Wiener's, and every SSIM below it, compared at the
    precision the tables give (0.01 dB, 0.001 SSIM): a difference a table
    cannot show decides nothing."""
    reasons = []
    for _, _, name in HEADLINES:
        (p, s), (pw, sw) = candidate.numbers[name], wiener.numbers[name]
        p, pw, s, sw = round(p, 2), round(pw, 2), round(s, 3), round(sw, 3)
        if not p > pw:
            reasons.append(f"{name} {p:.2f} dB is not above its Wiener's {pw:.2f}")
        if s < sw:
            reasons.append(f"SSIM {name} {s:.3f} is below its Wiener's {sw:.3f}")
    return reasons


#: The unrolled model's rule (issue 55): this much above its Wiener vs sharp, on the mean.
UNROLLED_SHARP_GAIN_DB = 0.5


def unrolled_verdict(candidate: Scores, wiener: Scores) -> list:
    """The unrolled preprocessor's rule (issue 55 item 5), at the tables'
    precision: at least +0.5 dB over its Wiener on the mean vs sharp, and
    not below it vs target on the mean or the worst depth. (Its third line,
    the Pareto front of the tradeoff chart at equal device time, needs the
    device's time: the tradeoff chart's, not this command's.)"""
    r = lambda name: round(candidate.numbers[name][0], 2)
    rw = lambda name: round(wiener.numbers[name][0], 2)
    reasons = []
    if not r("mean vs sharp") >= round(rw("mean vs sharp") + UNROLLED_SHARP_GAIN_DB, 2):
        reasons.append(f"mean vs sharp {r('mean vs sharp'):.2f} dB is not {UNROLLED_SHARP_GAIN_DB} dB above its "
                       f"Wiener's {rw('mean vs sharp'):.2f}")
    for name in ("mean vs target", "worst vs target"):
        if r(name) < rw(name):
            reasons.append(f"{name} {r(name):.2f} dB is below its Wiener's {rw(name):.2f}")
    return reasons


def is_unrolled(path: Path) -> bool:
    return path.name.endswith(".unrolled.toml")


def manifest_line(path: Path) -> str:
    """The unrolled model's facts, from its manifest."""
    import tomllib
    try:
        m = tomllib.loads(path.read_text())
        steps = m["step"]
        rho = ", ".join(f"{s['rho']:.3f}" for s in steps)
        alpha = ", ".join(f"{s['relaxation']:.2f}" for s in steps)
        nets = sum("network" in s for s in steps)
        return (f"Manifest: {len(steps)} split-solver steps @{m['objective']} ({nets} with a learned correction), "
                f"ρ/L {rho}, α {alpha}, trained at {m['trained_size'][0]}×{m['trained_size'][1]}.")
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise JudgeError(f"{path}: not an unrolled model's manifest ({e})") from e


def table(candidate: Scores, wiener: Scores, shipped: Scores | None) -> str:
    rows = ["| network | mean / worst vs target dB (SSIM) | mean / worst vs sharp dB (SSIM) |",
            "| --- | --- | --- |"]
    for s in [candidate, wiener] + ([shipped] if shipped else []):
        rows.append(f"| {s.label} | {s.cell('target')} | {s.cell('sharp')} |")
    return "\n".join(rows)


def entry(date: str, candidate_path: str, card_line: str, candidate: Scores, wiener: Scores,
          shipped: Scores | None, reasons: list, shipped_now: bool, images: str, note: str,
          rule: str = "dcnn") -> str:
    """One log entry: the candidate, the table, the verdict."""
    if rule == "unrolled":
        decision = ("**does not pass the unrolled rule**: " + "; ".join(reasons) + "." if reasons else
                    f"**passes the unrolled rule's quality lines** (≥ +{UNROLLED_SHARP_GAIN_DB} dB mean vs sharp, "
                    "not below its Wiener vs target on the mean or the worst depth); its Pareto line is the tradeoff "
                    "chart's.")
    elif reasons:
        decision = "**does not ship**: " + "; ".join(reasons) + "."
    elif shipped_now:
        decision = "**ships**: above its Wiener on all four headline numbers, no SSIM lower; now `models/dcnn.onnx`."
    else:
        decision = ("**passes the rule** (above its Wiener on all four, no SSIM lower); not shipped by this run "
                    "(`--ship` ships it).")
    lines = [f"### {date}: `{candidate_path}`", ""]
    if card_line:
        lines += [card_line, ""]
    if note:
        lines += [note, ""]
    lines += [f"`nedrt eval` on `{images}`:", "", table(candidate, wiener, shipped), "", decision, ""]
    return "\n".join(lines)


def append_log(log: Path, text: str):
    """Appends `text` under the log's heading (made at the end if missing), atomically."""
    try:
        old = log.read_text()
    except OSError as e:
        raise JudgeError(f"{log}: cannot read the log ({e.strerror or e})") from e
    if LOG_HEADING not in old:
        old = old.rstrip("\n") + "\n\n" + LOG_HEADING + "\n\n"
        old += ("Every network a lent GPU returned, scored by `nedrt-train judge` against its own Wiener and the "
                "shipped network on the validation photographs; it ships only above its Wiener on the mean and "
                "the worst depth, vs sharp and vs target, with no SSIM lower.\n\n")
    atomic_write(log, (old.rstrip("\n") + "\n\n" + text).encode())


def card_of(model: Path) -> dict:
    """The model's card (`NAME.card.json` beside `NAME.onnx`)."""
    path = model.with_suffix(".card.json")
    try:
        card = json.loads(path.read_text())
    except OSError as e:
        raise JudgeError(f"{path}: cannot read the model card ({e.strerror or e})") from e
    except json.JSONDecodeError as e:
        raise JudgeError(f"{path}: not a model card (JSON): {e}") from e
    if not isinstance(card, dict):
        raise JudgeError(f"{path}: not a model card (a JSON object)")
    return card


def card_line(card: dict) -> str:
    config = card.get("config", {}) if isinstance(card.get("config"), dict) else {}
    parts = [f"width {config['width']}" if "width" in config else None,
             f"{card['steps']} steps" if "steps" in card else None,
             f"{card['wall_time_s']:.0f} s" if isinstance(card.get("wall_time_s"), (int, float)) else None,
             f"teacher set {config['teacher_set']}" if "teacher_set" in config else None]
    parts = [p for p in parts if p]
    return "Card: " + ", ".join(parts) + "." if parts else ""


def ship(candidate: Path, card: dict, repo: Path, models: Path):
    """Replaces models/dcnn.{onnx,card.json,doe.safetensors} with the
    candidate's: all written beside the old ones, then renamed."""
    doe = card.get("doe") if isinstance(card.get("doe"), dict) else None
    if not doe or "source" not in doe or "sha256" not in doe:
        raise JudgeError(f"{candidate.with_suffix('.card.json')}: the card names no DOE (doe.source, doe.sha256)")
    doe_path = (repo / doe["source"]) if not Path(doe["source"]).is_absolute() else Path(doe["source"])
    try:
        doe_bytes = doe_path.read_bytes()
    except OSError as e:
        raise JudgeError(f"{doe_path}: the card's DOE cannot be read ({e.strerror or e})") from e
    if hashlib.sha256(doe_bytes).hexdigest() != doe["sha256"]:
        raise JudgeError(f"{doe_path}: its SHA-256 is not the card's doe.sha256; not shipped")
    files = {"dcnn.onnx": candidate.read_bytes(),
             "dcnn.card.json": candidate.with_suffix(".card.json").read_bytes(),
             "dcnn.doe.safetensors": doe_bytes}
    staged = []
    try:
        for name, data in files.items():
            staged.append((write_beside(models / name, data), models / name))
    except BaseException:
        for tmp, _ in staged:
            tmp.unlink(missing_ok=True)
        raise
    for tmp, final in staged:
        os.replace(tmp, final)


def run_eval(nedrt: str, design: str, images: Path, model: Path, methods: str, out: Path) -> dict:
    """`nedrt --design DESIGN eval` of `model`; its eval.json."""
    cmd = [nedrt, "--design", design, "eval", "--images", str(images), "--methods", methods, "--dcnn", str(model),
           "--out-dir", str(out)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        tail = (p.stderr or p.stdout).strip().splitlines()[-3:]
        raise JudgeError(f"nedrt eval of {model} failed (exit {p.returncode}): " + " | ".join(tail))
    try:
        return json.loads((out / "eval.json").read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise JudgeError(f"{out / 'eval.json'}: nedrt eval left no readable result ({e})") from e


def row(result: dict, method: str, source: str) -> dict:
    for r in result.get("methods", []):
        if r.get("method") == method:
            return r
    raise JudgeError(f"{source}: no row {method!r} (rows: {[r.get('method') for r in result.get('methods', [])]})")


def judge(args, evaluate=run_eval) -> int:
    """Scores, logs and (with --ship) ships; 0 whether it ships or not."""
    candidate = Path(args.candidate)
    unrolled = is_unrolled(candidate)
    if not (candidate.suffix == ".onnx" or unrolled) or not candidate.is_file():
        raise JudgeError(f"{candidate}: not an ONNX file (--candidate takes NAME.onnx, its card beside it, "
                         "or an unrolled model's NAME.unrolled.toml)")
    if unrolled and args.ship:
        raise JudgeError(f"{candidate}: an unrolled model is judged, not shipped yet: nedrt run and the service "
                         "do not take it until its device composition exists (docs/unrolled.md)")
    card = {} if unrolled else card_of(candidate)
    line = manifest_line(candidate) if unrolled else card_line(card)
    with tempfile.TemporaryDirectory(prefix="nedrt-judge-") as tmp:
        tmp = Path(tmp)
        result = evaluate(args.nedrt, args.design, Path(args.images), candidate, "proposed,doe+wiener",
                          tmp / "candidate")
        cand = Scores.of(row(result, "proposed", "the candidate's eval"), "candidate", "the candidate's eval")
        wiener = Scores.of(row(result, "doe+wiener", "the candidate's eval"), "its Wiener (`doe+wiener`)",
                           "the candidate's eval")
        shipped = None
        if args.shipped != "none":
            shipped_path = Path(args.shipped)
            if not shipped_path.is_file():
                raise JudgeError(f"{shipped_path}: no shipped network here (--shipped none leaves it out)")
            res = evaluate(args.nedrt, args.design, Path(args.images), shipped_path, "proposed", tmp / "shipped")
            shipped = Scores.of(row(res, "proposed", "the shipped network's eval"),
                                f"shipped (`{shipped_path}`)", "the shipped network's eval")
    reasons = unrolled_verdict(cand, wiener) if unrolled else verdict(cand, wiener)
    shipped_now = False
    if args.ship and not reasons:
        ship(candidate, card, Path(args.repo), Path(args.models))
        shipped_now = True
    date = args.date or datetime.date.today().isoformat()
    text = entry(date, str(candidate), line, cand, wiener, shipped, reasons, shipped_now, args.images,
                 args.note, rule="unrolled" if unrolled else "dcnn")
    if args.log != "none":
        append_log(Path(args.log), text)
    sys.stdout.write(text)
    return 0


def main(argv=None, prog="nedrt-train judge"):
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--candidate", required=True,
                    help="the returned network, NAME.onnx (its card beside it), or NAME.unrolled.toml")
    ap.add_argument("--shipped", default="models/dcnn.onnx", help="the shipped network to score beside it, or none")
    ap.add_argument("--images", default="data/images/val", help="the validation photographs")
    ap.add_argument("--design", default="multifocal", help="the design the network was trained on")
    ap.add_argument("--nedrt", default="target/release/nedrt", help="the nedrt binary")
    ap.add_argument("--log", default="docs/training.md", help="where the entry goes (none: only printed)")
    ap.add_argument("--ship", action="store_true", help="ship it if it passes the rule")
    ap.add_argument("--note", default="", help="a line for the entry (the session, the machine)")
    ap.add_argument("--date", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--repo", default=".", help=argparse.SUPPRESS)
    ap.add_argument("--models", default="models", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    try:
        return judge(args)
    except JudgeError as e:
        sys.stderr.write(f"{prog}: error: {e}\n")
        sys.exit(1)


if __name__ == "__main__":
    sys.exit(main())
