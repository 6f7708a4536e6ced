"""Files written whole or not at all: the data goes to a temporary file
beside its destination (same folder, so the rename is atomic), is synced,
and is renamed over the destination; a failure leaves the destination as it
was and no temporary behind."""
import os
import tempfile
from pathlib import Path


def write_beside(path: Path, data: bytes) -> Path:
    """`data` in a synced temporary file beside `path` (removed again if
    writing fails); the caller renames it over `path`."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return Path(tmp)


def atomic_write(path: Path, data: bytes):
    """`path` holds `data`, or what it held before."""
    tmp = write_beside(path, data)
    try:
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
