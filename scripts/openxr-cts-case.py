#!/usr/bin/env python3
"""One OpenXR-CTS case's outcome, for scripts/openxr-cts.sh.

    openxr-cts-case.py NAME RC JUNIT_XML OUTPUT      -> one TSV row
    openxr-cts-case.py --table RESULTS_TSV CTS_COMMIT NEDRT_COMMIT PLUGIN
                                                     -> the Markdown table
    openxr-cts-case.py --merge LABEL=RESULTS_TSV...  -> one table, a column a run

A case is `passed`, `failed` or `skipped` as Catch2's JUnit report says;
`hung` when the deadline killed it (timeout's 124/137); `crashed` when the
process ended without a whole report (a signal, an abort). A failure's first
line is the first failed assertion's expression and message, as Catch2 gives
it; a crash's is the last line the process printed.
"""
import re
import sys
import xml.etree.ElementTree as ET


def one_line(text: str) -> str:
    text = re.sub(r"\x1b\[[0-9;]*m", "", text or "")
    for line in text.splitlines():
        line = line.strip()
        if line:
            return line.replace("\t", " ").replace("|", "\\|")[:200]
    return ""


def last_line(path: str) -> str:
    try:
        with open(path, errors="replace") as f:
            lines = [l for l in f.read().splitlines() if l.strip()]
    except OSError:
        return ""
    return one_line(lines[-1]) if lines else ""


BOILERPLATE = (
    "FAILED:",
    "explicitly with message",
    "with message",
    "due to unexpected exception",
    "{Unknown expression",
)


def describe(tc, f) -> str:
    """A failure in one line: the section, then the assertion and what it got,
    or the first line of its message."""
    lines = [l.strip() for l in (f.text or "").splitlines() if l.strip()]
    lines = [l for l in lines if not l.startswith("at ")]
    text = ""
    if "with expansion:" in lines:
        k = lines.index("with expansion:")
        got = []
        for l in lines[k + 1:]:
            if l.startswith(BOILERPLATE) or ":=" in l:
                break
            got.append(l)
        text = f"{f.get('message', '')}: got {' '.join(got)}"
    else:
        body = [l for l in lines if not l.startswith(BOILERPLATE)]
        text = body[0] if body else f.get("message", "")
    name = tc.get("name", "")
    section = name.split("/", 1)[1] if "/" in name else ""
    return one_line(f"{section}: {text}" if section else text)


def case(name: str, rc: int, xml_path: str, out_path: str) -> tuple[str, str]:
    if rc in (124, 137):
        return "hung", f"killed by the deadline; last output: {last_line(out_path)}"
    try:
        root = ET.parse(xml_path).getroot()
    except (OSError, ET.ParseError):
        return "crashed", f"exit {rc}, no report; last output: {last_line(out_path)}"
    failures, skipped, cases = [], None, 0
    for tc in root.iter("testcase"):
        cases += 1
        for f in list(tc.findall("failure")) + list(tc.findall("error")):
            failures.append((tc, f))
        if skipped is None and tc.find("skipped") is not None:
            skipped = tc.find("skipped")
    # Catch2 reports a fatal signal as the failure of the assertion it was
    # in: that is a crash, whatever the report says.
    for tc, f in failures:
        for line in (f.text or "").splitlines():
            if "signal" in line.lower() and line.strip().startswith("SIG"):
                return "crashed", one_line(f"{line.strip()} (after {tc.get('name', name)})")
    if failures:
        more = f" (and {len(failures) - 1} more)" if len(failures) > 1 else ""
        return "failed", describe(*failures[0])[:300 - len(more)] + more
    if rc not in (0, 1):
        return "crashed", f"exit {rc}; last output: {last_line(out_path)}"
    if skipped is not None:
        lines = [l.strip() for l in (skipped.text or "").splitlines() if l.strip()]
        lines = [l for l in lines if not l.startswith(("SKIPPED", "at "))]
        return "skipped", one_line("\n".join([skipped.get("message") or ""] + lines))
    if cases == 0 and rc != 0:
        return "crashed", f"exit {rc}, an empty report; last output: {last_line(out_path)}"
    # Catch2's JUnit report leaves out a case with no assertions (it only
    # describes the environment): exit 0 is its pass.
    return "passed", "" if cases else "(no assertions)"


def table(tsv: str, cts_commit: str, nedrt_commit: str, plugin: str) -> None:
    rows = []
    with open(tsv) as f:
        next(f)
        for line in f:
            name, status, first = (line.rstrip("\n").split("\t") + ["", ""])[:3]
            rows.append((name, status, first))
    counts = {}
    for _, status, _ in rows:
        counts[status] = counts.get(status, 0) + 1
    order = ["passed", "failed", "skipped", "crashed", "hung"]
    summary = ", ".join(f"{counts[s]} {s}" for s in order if s in counts)
    print(f"OpenXR-CTS {cts_commit}, plugin {plugin}, API 1.0, nedrt {nedrt_commit}: "
          f"{len(rows)} automated cases: {summary}.")
    print()
    print("| case | result | first line |")
    print("| --- | --- | --- |")
    for name, status, first in rows:
        cell = name.replace("|", "\\|")
        print(f"| {cell} | {status} | {first} |")


def read_tsv(path: str) -> list[tuple[str, str, str]]:
    with open(path) as f:
        next(f)
        return [tuple((line.rstrip("\n").split("\t") + ["", ""])[:3]) for line in f]


def merge(runs: list[str]) -> None:
    """Several runs' results (LABEL=results.tsv) as one table: a column a
    run, and the first line of whatever did not pass in some run."""
    labelled = [(r.split("=", 1)[0], read_tsv(r.split("=", 1)[1])) for r in runs]
    names = [name for name, _, _ in labelled[0][1]]
    by_run = [{n: (st, first) for n, st, first in rows} for _, rows in labelled]
    print("| case | " + " | ".join(label for label, _ in labelled) + " | why not passed |")
    print("| --- | " + " | ".join("---" for _ in labelled) + " | --- |")
    for name in names:
        cells = [run.get(name, ("absent", ""))[0] for run in by_run]
        why = next(
            (run[name][1] for run in by_run if name in run and run[name][0] != "passed"), ""
        )
        cell = name.replace("|", "\\|")
        print(f"| {cell} | " + " | ".join(cells) + f" | {why} |")
    counts = [f"{label}: " + ", ".join(
        f"{sum(1 for s, _ in run.values() if s == k)} {k}"
        for k in ("passed", "failed", "skipped", "crashed", "hung")
        if any(s == k for s, _ in run.values())) for (label, _), run in zip(labelled, by_run)]
    print()
    print("; ".join(counts) + ".")


def main() -> None:
    if len(sys.argv) > 2 and sys.argv[1] == "--merge":
        merge(sys.argv[2:])
        return
    if len(sys.argv) == 6 and sys.argv[1] == "--table":
        table(*sys.argv[2:6])
        return
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    name, rc, xml_path, out_path = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
    status, first = case(name, rc, xml_path, out_path)
    print(f"{name}\t{status}\t{first}")


if __name__ == "__main__":
    main()
