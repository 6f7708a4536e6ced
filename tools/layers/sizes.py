#!/usr/bin/env python3
"""Sizes a newcomer can read (issue 32; scripts/check-layers.sh runs it):
exit 0 when no Rust source file under runtime/*/src holds more than 550
lines outside its tests and no crate holds more than 25 % of the
workspace's Rust lines outside tests; 1 naming each file or crate over.

Test code does not count: files named `tests.rs` or `*_tests.rs`,
anything under a `tests/` directory, and everything from a file's first
`#[cfg(test)]` module on (tests sit at the end of a file, as this project
keeps them; a `#[cfg(test)] use` line above does not end the count).

    python3 tools/layers/sizes.py                 # the repository
    python3 tools/layers/sizes.py --root DIR      # DIR/*/src instead of runtime/*/src

Standard library only.
"""
import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from import_cycles import REPO, is_test_file, without_tests  # noqa: E402

MAX_FILE_LINES = 550
MAX_CRATE_SHARE = 0.25


def code_lines(path: Path) -> int:
    """Lines of `path` before its first `#[cfg(test)]` module."""
    return without_tests(path.read_text(encoding="utf-8", errors="replace")).count("\n")


def measure(root: Path):
    """{crate: {file: lines}} over root/*/src, test code left out."""
    crates = {}
    for src in sorted(root.glob("*/src")):
        files = {}
        for f in sorted(src.rglob("*.rs")):
            rel = f.relative_to(src)
            if not is_test_file(rel):
                files[f] = code_lines(f)
        crates[src.parent.name] = files
    return crates


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", type=Path, default=REPO / "runtime")
    args = ap.parse_args(argv)
    crates = measure(args.root)
    total = sum(sum(f.values()) for f in crates.values())
    problems = []
    for crate, files in crates.items():
        for f, n in files.items():
            if n > MAX_FILE_LINES:
                shown = f.relative_to(REPO) if f.is_relative_to(REPO) else f
                problems.append(f"{shown}: {n} lines outside tests (at most {MAX_FILE_LINES})")
        lines = sum(files.values())
        if total and lines / total > MAX_CRATE_SHARE:
            problems.append(f"crate {crate}: {lines} of the workspace's {total} Rust lines outside tests, "
                            f"{100 * lines / total:.1f} % (at most {100 * MAX_CRATE_SHARE:.0f} %)")
    for p in problems:
        print(p)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
