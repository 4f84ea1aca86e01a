"""Reports, tables and figures: strict JSON, text, CSV tables and raw bytes, each written
atomically, and the sha256 of a file.
"""

from __future__ import annotations

import csv
import hashlib
import io as _io
import json
from pathlib import Path

import numpy as np

from .._plain import jsonable
from ._common import _atomic_write


def to_json(obj, indent: int | None = 2) -> str:
    """Strict JSON text of ``obj`` (:func:`jsonable`): never ``NaN`` or ``Infinity``."""
    return json.dumps(jsonable(obj), indent=indent, allow_nan=False)


def save_json(path, obj) -> Path:
    """Write ``obj`` as strict JSON (:func:`to_json`), atomically."""
    text = to_json(obj).encode()
    return _atomic_write(path, lambda fh: fh.write(text))


def save_text(path, text: str) -> Path:
    """Write a text file (UTF-8), atomically."""
    data = str(text).encode()
    return _atomic_write(path, lambda fh: fh.write(data))


def _no_negative_zero(cell):
    """A cell with negative zero (``-0.0`` or text such as ``-0``, ``-0.000``) written as 0."""
    if isinstance(cell, float | np.floating) and cell == 0:
        return 0.0
    if isinstance(cell, str) and cell.startswith("-"):
        try:
            if float(cell) == 0:
                return cell[1:]
        except ValueError:
            pass
    return cell


def file_sha256(path) -> str:
    """sha256 (hex) of a file's bytes."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def save_bytes(path, data: bytes) -> Path:
    """Write ``data`` (e.g. a PNG or PDF figure) to ``path``, atomically."""
    data = bytes(data)
    return _atomic_write(path, lambda fh: fh.write(data))


def save_csv(path, header, rows) -> Path:
    """Write a CSV table (``header``: column names; ``rows``: sequences of cells), atomically."""
    buf = _io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(list(header))
    for r in rows:
        w.writerow([_no_negative_zero(c) for c in r])
    data = buf.getvalue().encode()
    return _atomic_write(path, lambda fh: fh.write(data))
