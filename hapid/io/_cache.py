"""Stage-cache entries (:mod:`hapid._stages`): arrays by name plus one JSON string, never
pickle.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from ._common import _atomic_write


def save_cache_entry(path, arrays: dict, meta: str) -> Path:
    """Write a stage-cache entry atomically: ``arrays`` by name plus the JSON string ``meta``."""
    return _atomic_write(path, lambda fh: np.savez(fh, __meta__=np.asarray(meta), **arrays))


class CacheEntry(NamedTuple):
    """A stage-cache entry (:func:`load_cache_entry`): ``arrays`` (name → array) and ``meta``
    (the JSON string the stage stored with them)."""

    arrays: dict
    meta: str


def load_cache_entry(path) -> CacheEntry:
    """:class:`CacheEntry` ``(arrays, meta)`` of a stage-cache entry (``allow_pickle=False``)."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != "__meta__"}
        return CacheEntry(arrays, str(z["__meta__"]))
