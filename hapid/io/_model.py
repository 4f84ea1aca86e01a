"""Model and design files (``.npz``/``.mat``).

* Hand/total model: ``M_H B_H K_H M_T B_T K_T`` ``(n, n)`` plus metadata arrays/scalars.
* Single-impedance model (docs/lab-data.md): ``M``, ``B``, ``K`` ``(n, n)`` plus metadata
  (method, status, quality_*, …).
* Design file (``hapid tune``): the compensator fields plus the strict-JSON text ``json``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..control._compensator import FIELDS as COMPENSATOR_FIELDS
from ..control._compensator import POSITIVE_FIELDS, Compensator
from ..impedance import ImpedanceModel, SecondOrder
from ._common import (
    FileFormatError,
    _atomic_write,
    _need,
    _numeric,
    _read_arrays,
    _read_lab_arrays,
    _write_with_metadata,
)
from ._reports import to_json

MODEL_KEYS = ("M_H", "B_H", "K_H", "M_T", "B_T", "K_T")


def save_model(path, model: ImpedanceModel, **metadata) -> Path:
    """Write a model file: ``M_H B_H K_H M_T B_T K_T`` ``(n, n)`` plus metadata arrays/scalars
    (e.g. method, status, cost, covariance)."""
    arrays = {
        "M_H": model.hand.M, "B_H": model.hand.B, "K_H": model.hand.K,
        "M_T": model.total.M, "B_T": model.total.B, "K_T": model.total.K,
    }  # fmt: skip
    arrays = {k: np.asarray(v, dtype=np.float64) for k, v in arrays.items()}
    for k, v in arrays.items():
        if not np.all(np.isfinite(v)):
            raise ValueError(f"model matrix {k} contains NaN or inf; not writing {path}")
    return _write_with_metadata(path, arrays, metadata)


def load_model(path) -> ImpedanceModel:
    """Read a model file into an ``ImpedanceModel`` (metadata: ``load_model_metadata``)."""
    d = _read_arrays(path, "a model file (M_H, B_H, K_H, M_T, B_T, K_T)")
    _need(d, MODEL_KEYS, path)
    mats = {k: _numeric(d, k, path) for k in MODEL_KEYS}
    shapes = {v.shape for v in mats.values()}
    if len(shapes) != 1 or len(s := next(iter(shapes))) != 2 or s[0] != s[1] or s[0] == 0:
        raise FileFormatError(
            f"{path}: model matrices must all be (n, n) with n ≥ 1, got {sorted(shapes)}"
        )
    for k, v in mats.items():
        if not np.all(np.isfinite(v)):
            raise FileFormatError(f"{path}: {k} contains NaN or inf")
    return ImpedanceModel(
        SecondOrder(mats["M_H"], mats["B_H"], mats["K_H"]),
        SecondOrder(mats["M_T"], mats["B_T"], mats["K_T"]),
    )


def load_model_metadata(path) -> dict:
    """The entries of a model file other than the matrices (name → array): what the writer
    stored beside the model (fit band, method, units). Raises ``ValueError`` naming the file
    when it cannot be read."""
    d = _read_arrays(path, "a model file (M_H, B_H, K_H, M_T, B_T, K_T)")
    return {k: v for k, v in d.items() if k not in MODEL_KEYS}


IMPEDANCE_MODEL_KEYS = ("M", "B", "K")


def save_impedance_model(path, model: SecondOrder, **metadata) -> Path:
    """Write a single-impedance model file: ``M``, ``B``, ``K`` ``(n, n)`` plus metadata."""
    arrays = {k: np.asarray(getattr(model, k), dtype=np.float64) for k in IMPEDANCE_MODEL_KEYS}
    for k, v in arrays.items():
        if v.ndim != 2 or not np.all(np.isfinite(v)):
            raise ValueError(f"model matrix {k} is not a finite (n, n) matrix; not writing {path}")
    return _write_with_metadata(path, arrays, metadata)


def load_impedance_model(path) -> SecondOrder:
    """Read a single-impedance model file into a :class:`SecondOrder` (M, B, K)."""
    d = _read_lab_arrays(path)
    _need(d, IMPEDANCE_MODEL_KEYS, path)
    mats = {k: np.asarray(d[k], dtype=np.float64) for k in IMPEDANCE_MODEL_KEYS}
    shapes = {v.shape for v in mats.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise FileFormatError(f"{path}: M, B, K must all be (n, n), got {sorted(shapes)}")
    return SecondOrder(mats["M"], mats["B"], mats["K"])


def save_design(path, g, **info) -> Path:
    """Write a design file (``.npz``): the fields of the compensator ``g``
    (:class:`hapid.control.Compensator`: ``k``, ``lag_zeros``, ``lag_poles``, ``notch_omega``,
    ``notch_zeta_num``, ``notch_zeta_den``, ``lowpass``; rad/s and dimensionless) plus ``json``,
    the strict-JSON text of ``info``."""
    arrays = {f: np.asarray(getattr(g, f), dtype=np.float64) for f in COMPENSATOR_FIELDS}
    for f, v in arrays.items():
        if not np.all(np.isfinite(v)):
            raise ValueError(f"compensator field {f} contains NaN or inf; not writing {path}")
    arrays["json"] = np.asarray(to_json(info, indent=None))
    return _atomic_write(path, lambda fh: np.savez(fh, **arrays))


class DesignFile(NamedTuple):
    """A design file's content (:func:`load_design`).

    - ``g``: the compensator.
    - ``info``: the decoded ``json`` entry (``{}`` when absent): the tuner's summary, decision
      and re-check table as written by :func:`save_design` (plain JSON data).
    """

    g: Compensator
    info: dict


def load_design(path) -> DesignFile:
    """:class:`DesignFile` ``(g, info)`` from a design file (:func:`save_design`). Raises ``FileNotFoundError`` or
    ``ValueError`` naming the file and the field that is missing or out of range."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such design file")
    z = _read_arrays(path, "a design file (hapid tune)")
    missing = [f for f in COMPENSATOR_FIELDS if f not in z]
    if missing:
        raise ValueError(f"{path}: not a design file (missing {', '.join(missing)})")
    arrays = {f: _numeric(z, f, path) for f in COMPENSATOR_FIELDS}
    for f, a in arrays.items():
        positive = f in POSITIVE_FIELDS
        if not np.all(np.isfinite(a)) or np.any(a <= 0 if positive else a < 0):
            raise ValueError(
                f"{path}: {f} = {a.tolist()}; expected finite values {'> 0' if positive else '≥ 0'}"
            )
    try:
        g = Compensator(**arrays)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    try:
        info = json.loads(str(z["json"])) if "json" in z else {}
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: its 'json' entry is not valid JSON ({e})") from None
    return DesignFile(g, info)
