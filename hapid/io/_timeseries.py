"""Lab time-series files (docs/lab-data.md): ``fs_hz`` (scalar), ``force`` and ``response``
``(T, n)`` or ``(E, T, n)``, optional text ``force_unit``, ``length_unit``. In a CSV the first line
is ``# fs_hz=…`` (or a ``time_s`` column), then columns ``[experiment,] force_0 … force_{n-1},
response_0 … response_{n-1}``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..experiment import TimeSeries
from ..experiment._impedance import validate_timeseries
from ._common import (
    FileFormatError,
    _csv_rows,
    _csv_table,
    _fmt,
    _read_lab_arrays,
    _text,
    _write_arrays,
)

TIMESERIES_CSV_LAYOUT = (
    "expected a time-series CSV: first line '# fs_hz=<Hz>' (or a time_s column), a header row "
    "'[experiment,] [time_s,] force_0,…,force_{n-1},response_0,…,response_{n-1}', then one row "
    "per sample"
)


def _records(a: np.ndarray, name: str, path) -> np.ndarray:
    """``(T, n)`` or ``(E, T, n)`` → ``(E, T, n)``, with a hint for transposed MATLAB records."""
    a = np.asarray(a)
    if a.dtype.kind not in "biuf":
        raise FileFormatError(f"{path}: {name} has dtype {a.dtype}; expected real numbers")
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3:
        raise FileFormatError(f"{path}: {name} must be (T, n) or (E, T, n), got shape {a.shape}")
    if a.shape[-2] < a.shape[-1]:
        raise FileFormatError(
            f"{path}: {name} has shape {a.shape}: fewer samples than channels — it looks like "
            f"(n, T) (MATLAB rows per channel); store it as (T, n), e.g. {name}.' in MATLAB"
        )
    return a.astype(np.float64)


def load_timeseries(
    paths,
    *,
    fs_hz: float | None = None,
    force_key: str = "force",
    response_key: str = "response",
    force_unit: str | None = None,
    length_unit: str | None = None,
):
    """Read lab records into a :class:`hapid.experiment.TimeSeries`.

    ``paths``: one file or a list (each file one or more experiments, stacked along E; all
    records must have the same length). ``fs_hz`` overrides/supplies the file's ``fs_hz``;
    ``force_key``/``response_key`` name the arrays (e.g. ``inputvalues``/``outputvalues``).
    """
    paths = [paths] if isinstance(paths, str | Path) else list(paths)
    F, Y, fs, units = [], [], [], {}
    for p in paths:
        if _fmt(p) == "csv":
            d = _read_timeseries_csv(p)
            fk, rk = "force", "response"
        else:
            d = _read_lab_arrays(p)
            fk, rk = force_key, response_key
            if fk not in d or rk not in d:
                raise FileFormatError(
                    f"{p}: missing arrays {[k for k in (fk, rk) if k not in d]} (has {sorted(d)}); "
                    "a time-series file holds fs_hz, force (T, n) and response (T, n) — name "
                    "other arrays with --force-key/--response-key"
                )
        F.append(_records(d[fk], fk, p))
        Y.append(_records(d[rk], rk, p))
        if F[-1].shape != Y[-1].shape:
            raise FileFormatError(f"{p}: {fk} has shape {F[-1].shape} but {rk} has {Y[-1].shape}")
        if "fs_hz" in d:
            fs.append(float(np.asarray(d["fs_hz"], dtype=float).reshape(-1)[0]))
        for k in ("force_unit", "length_unit"):
            units.setdefault(k, _text(d, k, ""))
    if fs_hz is None:
        if not fs:
            raise FileFormatError(
                f"{paths[0]}: no fs_hz in the file; give the sampling rate (--fs-hz)"
            )
        if len(set(fs)) > 1:
            raise FileFormatError(f"files disagree on fs_hz: {sorted(set(fs))}")
        fs_hz = fs[0]
    lengths = sorted({a.shape[1] for a in F})
    if len(lengths) > 1:
        raise FileFormatError(f"records have different lengths {lengths}; trim them to one length")
    chans = sorted({a.shape[2] for a in F})
    if len(chans) > 1:
        raise FileFormatError(f"records have different channel counts {chans}")
    try:
        return TimeSeries(
            fs_hz=float(fs_hz),
            force=np.concatenate(F),
            response=np.concatenate(Y),
            force_unit=force_unit or units.get("force_unit") or "N",
            length_unit=length_unit or units.get("length_unit") or "m",
        )
    except ValueError as e:
        raise FileFormatError(f"{paths[0]}: {e}") from None


def _read_timeseries_csv(path) -> dict:
    path = Path(path)
    meta, header, rows = _csv_table(path, TIMESERIES_CSV_LAYOUT)
    fcols = [i for i, h in enumerate(header) if h.startswith("force_")]
    rcols = [i for i, h in enumerate(header) if h.startswith("response_")]
    if not fcols or len(fcols) != len(rcols):
        raise FileFormatError(
            f"{path}: header {header[:6]}… has {len(fcols)} force_ and {len(rcols)} response_ "
            f"columns; {TIMESERIES_CSV_LAYOUT}"
        )
    data = _csv_rows(path, rows, header, TIMESERIES_CSV_LAYOUT)
    out = {}
    if "fs_hz" in meta:
        out["fs_hz"] = float(meta["fs_hz"])
    elif "time_s" in header:
        t = data[:, header.index("time_s")]
        dt = np.diff(t)
        if dt.size == 0 or not np.all(dt > 0) or np.ptp(dt) > 1e-6 * np.mean(dt):
            raise FileFormatError(f"{path}: time_s is not uniformly increasing; give fs_hz instead")
        out["fs_hz"] = 1.0 / float(np.mean(dt))
    exp = data[:, header.index("experiment")].astype(int) if "experiment" in header else None
    F, Y = data[:, fcols], data[:, rcols]
    if exp is not None:
        ids = np.unique(exp)
        counts = {int(np.sum(exp == i)) for i in ids}
        if len(counts) != 1:
            raise FileFormatError(f"{path}: experiments have different lengths {sorted(counts)}")
        F = np.stack([F[exp == i] for i in ids])
        Y = np.stack([Y[exp == i] for i in ids])
    out["force"], out["response"] = F, Y
    for k in ("force_unit", "length_unit"):
        if k in meta:
            out[k] = np.asarray(meta[k])
    return out


def save_timeseries(path, ts) -> Path:
    """Write a time-series file (``.npz``/``.mat``) after validating it."""
    validate_timeseries(ts)
    arrays = {"fs_hz": np.float64(ts.fs_hz), "force": np.asarray(ts.force, dtype=np.float64),
              "response": np.asarray(ts.response, dtype=np.float64),
              "force_unit": np.asarray(ts.force_unit), "length_unit": np.asarray(ts.length_unit)}  # fmt: skip
    return _write_arrays(path, arrays)
