#!/usr/bin/env python3
"""Flag names only in the binary (issue 32; scripts/check-layers.sh runs it):
exit 0 when no string literal in the code of the crates below the commands'
wiring (runtime/{core,gpu,protocol,openxr,optics,infer,service,stages}/src)
names a command-line flag (`--backend`, `--sink`, …); 1 naming each
(file:line and the literal).

A library is called from the binary, the trainer's tools, tests and other
programs; a flag in its message is wrong for all but one of them. The
library returns a typed error and the binary (cli/src/main.rs `hint`) or the
commands' wiring (nedrt-command, nedrt-run, nedrt-app, nedrt-studies, whose
options are the flags) adds what to type. Test code does not count (the cut of
rust_source.without_tests), nor attributes (`#[ignore = "… --include-ignored"]`).

    python3 tools/layers/flag_names.py            # the repository
    python3 tools/layers/flag_names.py --rust DIR # those crates' src/ only

Standard library only.
"""
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from layer_check import crate_check_main, display  # noqa: E402
from rust_source import is_test_file, without_tests  # noqa: E402

LIBRARIES = ("core", "gpu", "protocol", "openxr", "optics", "infer", "service", "stages")
FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9]*(?:-[a-z0-9]+)*")


def literals(text: str):
    """[(line, literal, in_attribute)] of the Rust string literals in `text`
    (plain, byte and raw), comments skipped."""
    out, i, n, line = [], 0, len(text), 1
    attr_depth = None  # bracket depth inside `#[…]`, or None outside one
    while i < n:
        c = text[i]
        if c == "\n":
            line += 1
            i += 1
        elif text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            line += text.count("\n", i, j)
            i = j
        elif c == "#" and text.startswith("[", i + 1) or c == "#" and text.startswith("![", i + 1):
            attr_depth = 0
            i += 1
        elif c == "[" and attr_depth is not None:
            attr_depth += 1
            i += 1
        elif c == "]" and attr_depth is not None:
            attr_depth -= 1
            if attr_depth == 0:
                attr_depth = None
            i += 1
        elif c == "r" and re.match(r'r#*"', text[i:i + 258]) and not (i and (text[i - 1].isalnum() or text[i - 1] == "_")):
            hashes = re.match(r'r(#*)"', text[i:]).group(1)
            start = i + 2 + len(hashes)
            end = text.find('"' + hashes, start)
            end = n if end < 0 else end
            out.append((line, text[start:end], attr_depth is not None))
            line += text.count("\n", i, end)
            i = end + 1 + len(hashes)
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append((line, text[i + 1:j], attr_depth is not None))
            line += text.count("\n", i, j)
            i = j + 1
        elif c == "'":
            # A char literal ('x', '\n', '"'), or a lifetime ('a).
            if text.startswith("\\", i + 1):
                j = text.find("'", i + 2)
                i = n if j < 0 else j + 1
            elif i + 2 < n and text[i + 2] == "'":
                i += 3
            else:
                i += 1
        else:
            i += 1
    return out


def check_crate(src: Path, root: Path):
    """([report line], files checked) for one crate's src/."""
    found, files = [], 0
    for path in sorted(src.rglob("*.rs")):
        rel = path.relative_to(src)
        if is_test_file(rel):
            continue
        files += 1
        for line, lit, in_attr in literals(without_tests(path.read_text(encoding="utf-8"))):
            if in_attr:
                continue
            flags = FLAG.findall(lit)
            if flags:
                shown = lit if len(lit) <= 100 else lit[:97] + "…"
                found.append(f"  {display(path, root)}:{line}: {', '.join(flags)} in \"{shown}\"")
    return found, files


def main(argv=None) -> int:
    return crate_check_main(
        argv, __doc__, "flag names", LIBRARIES, check_crate,
        "a library crate names a command-line flag (return a typed error; the binary "
        "or the command's wiring adds the hint):",
        lambda crates, files: f"flag names: no string literal of {crates} library crate(s) "
        f"names a command-line flag ({files} files, test code and attributes excluded)")


if __name__ == "__main__":
    sys.exit(main())
