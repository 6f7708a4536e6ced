"""Paths a command line names, resolved once at the edge: the argument, or a
default relative to the current directory, checked to exist."""

from pathlib import Path


def resolve_cli_path(arg, default: Path, cwd, *, folder: bool, what: str, flag: str) -> Path:
    """`arg`, or `default` under `cwd` (the current directory) when `arg` is
    None; absolute. Raises FileNotFoundError naming the path (`what` not
    found) when it is not a file (or, with `folder`, not a folder); for the
    default it also says to run from the repository root or pass `flag`."""
    base = Path(cwd) if cwd is not None else Path.cwd()
    path = (base / (Path(arg) if arg is not None else default)).resolve()
    if not (path.is_dir() if folder else path.is_file()):
        how = "" if arg is not None else f" (the default: run from the repository root, or pass {flag})"
        raise FileNotFoundError(f"{path}: {what} not found{how}")
    return path
