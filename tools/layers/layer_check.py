"""What the checkers of tools/layers share (scripts/check-layers.sh runs
them): the repository, its library crates, how a path is shown, and the
command line of a checker that looks at each library crate in turn
(string_errors.py, flag_names.py).

Standard library only.
"""
import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
RUST_CRATES = ("core", "gpu", "protocol", "openxr", "optics", "infer", "service", "stages",
               "command", "run", "app", "studies")


def display(path: Path, root: Path) -> str:
    try:
        return str(path.resolve().relative_to(root.resolve()))
    except ValueError:
        return str(path)


def crate_check_main(argv, doc, name, crates, check_crate, failure, success) -> int:
    """The command line of a per-crate checker (string_errors, flag_names):
    `--root` or `--rust SRC`...; runs `check_crate(src, root)` → (lines,
    files) on each, prints `failure` and the lines (exit 1) or
    `success(crates, files)` (exit 0); 2 for a missing directory."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", type=Path, default=REPO,
                        help="repository whose crates to check (default: this one)")
    parser.add_argument("--rust", type=Path, action="append", default=[], metavar="SRC",
                        help="a crate's src/ directory to check instead (repeatable)")
    args = parser.parse_args(argv)
    root = args.root
    rust = args.rust or [root / "runtime" / c / "src" for c in crates]
    missing = [p for p in rust if not p.is_dir()]
    if missing:
        for p in missing:
            print(f"{name}: {p} is not a directory", file=sys.stderr)
        return 2
    lines, files = [], 0
    for src in rust:
        found, n = check_crate(src, root)
        lines += found
        files += n
    if lines:
        print(failure)
        print("\n".join(lines))
        return 1
    print(success(len(rust), files))
    return 0
