"""Plain, strict-JSON-ready Python values: the form every result's ``summary()`` returns."""

from __future__ import annotations

import numpy as np


def jsonable(obj):
    """``obj`` as strict-JSON-ready Python values: numpy/JAX scalars and arrays → numbers and
    lists, NaN and ±inf → ``None`` (JSON ``null``), tuples → lists, dict keys → ``str``, a
    string enum member → its plain string value; anything else (e.g. a complex number) → its
    ``str``."""
    if obj is None or isinstance(obj, bool):
        return obj
    if isinstance(obj, str):
        return str(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray) or hasattr(obj, "__array__"):
        a = np.asarray(obj)
        if a.dtype.kind in "biuf":
            return jsonable(a.tolist())
    return str(obj)


def enum_members(values, enum_cls):
    """``enum_cls`` member of a scalar (or 0-d array) value, else an object array of members
    of the same shape — a batched result's ``status``: elementwise ``== "stable"`` works."""
    values = np.asarray(values)
    flat = np.empty(values.size, dtype=object)
    for i, v in enumerate(values.ravel().tolist()):
        flat[i] = enum_cls(v)
    return flat[0] if values.ndim == 0 else flat.reshape(values.shape)
