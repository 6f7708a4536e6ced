#!/usr/bin/env python3
"""Sizes a newcomer can read (issues 32 and 39; scripts/check-layers.sh
runs it): exit 0 when no Rust source file under runtime/*/src holds more
than 550 lines outside its tests, no crate holds more than 25 % of the
workspace's Rust lines outside tests, no other Rust source file of the
repository (examples, benchmark harnesses such as bench/burn, build
scripts, fuzz targets) holds more than 550 lines outside its tests, and
no Python source file of the repository (the trainer in models/, tools/,
scripts/, bench/, …) holds more than 550 lines; 1 naming each file or
crate over.

Test code does not count. Rust: files named `tests.rs` or `*_tests.rs`,
anything under a `tests/` directory, and everything from a file's first
`#[cfg(test)]` module on (tests sit at the end of a file, as this project
keeps them; a `#[cfg(test)] use` line above does not end the count).
Python: files named `test_*.py`, `*_test.py` or `conftest.py`, and
anything under a `tests/` directory; a source file counts whole. The
Python walk skips what is not the repository's source: `.git`, virtual
environments (`.venv`, or any folder with a `pyvenv.cfg`), Cargo's
`target` folders, `__pycache__`, `node_modules` and `.devcheck`.

    python3 tools/layers/sizes.py                 # the repository
    python3 tools/layers/sizes.py --root DIR      # only DIR/*/src's Rust, instead of runtime/*/src
    python3 tools/layers/sizes.py --python DIR    # only the Python files under DIR
    python3 tools/layers/sizes.py --rust-rest DIR # only the Rust files under DIR outside its runtime/*/src
    python3 tools/layers/sizes.py --root DIR --python DIR2   # both, those

Standard library only.
"""
import argparse
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from layer_check import REPO  # noqa: E402
from rust_source import is_test_file, without_tests  # noqa: E402

MAX_FILE_LINES = 550
MAX_CRATE_SHARE = 0.25
#: Folders the Python walk does not enter (build outputs, environments, caches).
SKIPPED_DIRS = {".git", ".venv", "target", "__pycache__", "node_modules", ".devcheck"}


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


def is_python_test(rel: Path) -> bool:
    """`rel` relative to the walk's root: a test file or under a `tests/` folder."""
    name = rel.name
    return (name.startswith("test_") or name.endswith("_test.py") or name == "conftest.py"
            or "tests" in rel.parts[:-1])


def python_lines(path: Path) -> int:
    """The lines of `path`, a last line without its newline included."""
    text = path.read_text(encoding="utf-8", errors="replace")
    return text.count("\n") + (1 if text and not text.endswith("\n") else 0)


def python_sources(root: Path):
    """{file: lines} of the Python source files under `root`, test code and
    the skipped folders left out, in path order."""
    files = {}
    for folder, dirs, names in os.walk(root):
        dirs[:] = sorted(d for d in dirs
                         if d not in SKIPPED_DIRS and not (Path(folder) / d / "pyvenv.cfg").is_file())
        for name in sorted(names):
            path = Path(folder) / name
            if name.endswith(".py") and not is_python_test(path.relative_to(root)):
                files[path] = python_lines(path)
    return dict(sorted(files.items()))


def other_rust_sources(root: Path):
    """{file: lines outside tests} of the Rust files under `root` that the
    crate check does not see (outside root/runtime/*/src): examples,
    harnesses, build scripts, fuzz targets. Test files, `tests/` folders
    and the skipped folders are left out."""
    crates = {src.resolve() for src in root.glob("runtime/*/src")}
    files = {}
    for folder, dirs, names in os.walk(root):
        here = Path(folder)
        dirs[:] = sorted(d for d in dirs
                         if d not in SKIPPED_DIRS and d != "tests"
                         and (here / d).resolve() not in crates
                         and not (here / d / "pyvenv.cfg").is_file())
        for name in sorted(names):
            path = here / name
            if name.endswith(".rs") and not is_test_file(path.relative_to(root)):
                files[path] = code_lines(path)
    return dict(sorted(files.items()))


def other_rust_problems(root: Path) -> list:
    return [f"{f.relative_to(root)}: {n} lines outside tests (at most {MAX_FILE_LINES})"
            for f, n in other_rust_sources(root).items() if n > MAX_FILE_LINES]


def rust_problems(root: Path) -> list:
    crates = measure(root)
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
    return problems


def python_problems(root: Path) -> list:
    return [f"{f.relative_to(root)}: {n} lines (at most {MAX_FILE_LINES})"
            for f, n in python_sources(root).items() if n > MAX_FILE_LINES]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", type=Path, help="check the Rust crates DIR/*/src (default: runtime/*/src)")
    ap.add_argument("--python", type=Path, metavar="DIR",
                    help="check the Python files under DIR (default: the repository)")
    ap.add_argument("--rust-rest", type=Path, metavar="DIR",
                    help="check the other Rust files under DIR: examples, harnesses, build scripts "
                         "(default: the repository)")
    args = ap.parse_args(argv)
    if args.root is None and args.python is None and args.rust_rest is None:
        args.root, args.python, args.rust_rest = REPO / "runtime", REPO, REPO
    problems = []
    if args.root is not None:
        problems += rust_problems(args.root)
    if args.rust_rest is not None:
        problems += other_rust_problems(args.rust_rest)
    if args.python is not None:
        problems += python_problems(args.python)
    for p in problems:
        print(p)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
