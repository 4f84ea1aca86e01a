"""Atomic file writes, shared by :mod:`hapid.io` and the export cache (:mod:`hapid._aot`).

Kept out of :mod:`hapid.io` so that low-level modules can write files without importing the
readers and writers of every file format."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def _umask() -> int:
    """The process umask (read without changing it for longer than the two calls)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write(path, write) -> Path:
    """Write ``path`` through ``write(fh)`` on a temporary file in the same directory, then
    rename it over ``path``: readers see the old file or the new one, never half of one. The
    file gets the mode an ordinary ``open(path, "w")`` would give (``0o666 & ~umask``), not
    ``mkstemp``'s 0600."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
