"""FRF files (``.npz``, ``.mat``, ``.csv``; frequencies in Hz).

* The haptic pair: ``freq_hz (N,)``, ``Z_H``, ``Z_T`` ``(N, n, n)`` complex, optional
  ``Z_H_std``, ``Z_T_std``, ``cond_L`` and per-output coherence ``(N, n)``.
* Predictive plant draws (``hapid predict``): ``freq_hz`` and ``(S, N, n, n)`` complex arrays.
* A single impedance (docs/lab-data.md): ``freq_hz (N,)``, ``Z (N, n, n)`` complex, optional
  ``Z_std (N, n, n)``, ``coherence (N, n)``, ``exp_tau_s`` (s) and ``unit`` (text).
"""

from __future__ import annotations

import csv
import io as _io
from pathlib import Path

import numpy as np

from ..frf import FRF, as_frf
from ..impedance_frf import as_impedance_frf
from ._common import (
    FileFormatError,
    _atomic_write,
    _complex,
    _csv_rows,
    _csv_table,
    _fmt,
    _frequency_first,
    _need,
    _numeric,
    _open_text,
    _read_lab_arrays,
    _text,
    _write_arrays,
)

#: optional per-output coherence arrays of an H1 FRF, (N, n) each
COHERENCE_KEYS = ("coherence_H", "coherence_T")


def save_frf(path, frf: FRF) -> Path:
    """Write an FRF file (``.npz``, ``.mat`` or ``.csv``); frequencies in Hz."""
    arrays = {
        "freq_hz": np.asarray(frf.freq_hz, dtype=np.float64),
        "Z_H": np.asarray(frf.Z_H, dtype=np.complex128),
        "Z_T": np.asarray(frf.Z_T, dtype=np.complex128),
    }
    if frf.Z_H_std is not None:
        arrays["Z_H_std"] = np.asarray(frf.Z_H_std, dtype=np.float64)
    if frf.Z_T_std is not None:
        arrays["Z_T_std"] = np.asarray(frf.Z_T_std, dtype=np.float64)
    if frf.cond_L is not None:
        arrays["cond_L"] = np.asarray(frf.cond_L, dtype=np.float64)
    for k in COHERENCE_KEYS:
        if getattr(frf, k, None) is not None:
            arrays[k] = np.asarray(getattr(frf, k), dtype=np.float64)
    as_frf(**{k: v for k, v in arrays.items()})  # validate
    if _fmt(path) == "csv":
        return _atomic_write(path, lambda fh: fh.write(_frf_csv(arrays).encode()))
    return _write_arrays(path, arrays)


def save_draws(path, freq_hz, draws: dict) -> Path:
    """Write predictive plant draws (``hapid predict``): ``freq_hz (N,)`` and each of
    ``draws`` (e.g. ``P``, ``Z_H``, ``Z_T``: ``(S, N, n, n)`` complex; a boolean array, e.g.
    ``established (N,)``, is kept boolean) to an ``.npz``."""
    arrays = {"freq_hz": np.asarray(freq_hz, dtype=np.float64)}
    for k, v in draws.items():
        v = np.asarray(v)
        arrays[k] = v if v.dtype == bool else np.asarray(v, dtype=np.complex128)
    return _write_arrays(path, arrays)


def load_frf(path) -> FRF:
    """Read and validate an FRF file."""
    what = "an FRF file (freq_hz, Z_H, Z_T)"
    d = _read_frf_csv(path) if _fmt(path) == "csv" else _read_lab_arrays(path, what)
    if "Z" in d and "Z_H" not in d:
        raise FileFormatError(
            f"{path}: holds a single impedance Z (from hapid frf on lab records), not the "
            "haptic pair Z_H, Z_T; fit it with hapid fit (hapid.io.load_impedance_frf in Python)"
        )
    _need(d, ("freq_hz", "Z_H", "Z_T"), path)
    for k in ("Z_H", "Z_T", "Z_H_std", "Z_T_std"):  # layout hint for MATLAB's (n, n, N)
        if k in d:
            _frequency_first(d[k], np.size(d["freq_hz"]), k, path)
    try:
        f = _numeric(d, "freq_hz", path).ravel()
        N = f.size

        def mat(k, dt):
            if k not in d:
                return None
            a = _numeric(d, k, path, complex_ok=dt is np.complex128)
            if a.ndim == 2 and N == 1:
                a = a[None]
            return a

        ZH = mat("Z_H", np.complex128)
        if ZH.ndim != 3 or ZH.shape[1] != ZH.shape[2] or ZH.shape[1] == 0 or N == 0:
            raise ValueError(f"Z_H must be (N, n, n) with N, n ≥ 1, got shape {ZH.shape}")
        coh = {k: None if k not in d else _numeric(d, k, path) for k in COHERENCE_KEYS}
        coh = {k: g[None] if g is not None and g.ndim == 1 and N == 1 else g
               for k, g in coh.items()}  # fmt: skip
        return as_frf(f, ZH, mat("Z_T", np.complex128), mat("Z_H_std", np.float64),
                      mat("Z_T_std", np.float64), mat("cond_L", np.float64), **coh)  # fmt: skip
    except ValueError as e:
        raise FileFormatError(f"{path}: {e}") from None


def _frf_csv(arrays: dict) -> str:
    N, n, _ = arrays["Z_H"].shape
    cols, names = [arrays["freq_hz"][:, None]], ["freq_hz"]
    for k in ("Z_H", "Z_T", "Z_H_std", "Z_T_std"):
        if k not in arrays:
            continue
        a = arrays[k].reshape(N, n * n)
        idx = [f"{i}_{j}" for i in range(n) for j in range(n)]
        if np.iscomplexobj(a):
            cols += [a.real, a.imag]
            names += [f"{k}_re_{s}" for s in idx] + [f"{k}_im_{s}" for s in idx]
        else:
            cols.append(a)
            names += [f"{k}_{s}" for s in idx]
    for k in COHERENCE_KEYS:
        if k in arrays:
            cols.append(arrays[k])
            names += [f"{k}_{i}" for i in range(n)]
    data = np.concatenate(cols, axis=1)
    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    for row in data:
        w.writerow([repr(float(v)) for v in row])
    return buf.getvalue()


def _read_frf_csv(path) -> dict:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    with _open_text(path) as fh:
        rows = list(csv.reader(fh))
    try:
        header, data = rows[0], np.asarray(rows[1:], dtype=float)
        col = {h: i for i, h in enumerate(header)}
        n = int(round(np.sqrt(sum(h.startswith("Z_H_re_") for h in header))))
        idx = [f"{i}_{j}" for i in range(n) for j in range(n)]
        out = {"freq_hz": data[:, col["freq_hz"]]}
        for k in ("Z_H", "Z_T"):
            re = data[:, [col[f"{k}_re_{s}"] for s in idx]]
            im = data[:, [col[f"{k}_im_{s}"] for s in idx]]
            out[k] = _complex(re, im).reshape(-1, n, n)
        for k in ("Z_H_std", "Z_T_std"):
            if f"{k}_0_0" in col:
                out[k] = data[:, [col[f"{k}_{s}"] for s in idx]].reshape(-1, n, n)
        for k in COHERENCE_KEYS:
            if f"{k}_0" in col:
                out[k] = data[:, [col[f"{k}_{i}"] for i in range(n)]]
        return out
    except (KeyError, ValueError, IndexError, ZeroDivisionError, OverflowError) as e:
        raise FileFormatError(f"{path}: malformed FRF CSV ({e})") from None


IMPEDANCE_CSV_LAYOUT = (
    "expected an impedance-FRF CSV: header 'freq_hz,Z_re_0_0,…,Z_im_0_0,…[,Z_std_0_0,…]' "
    "(row-major i_j), one row per frequency"
)


def load_impedance_frf(path):
    """Read and validate an impedance FRF file (``freq_hz``, ``Z``, optional ``Z_std``, ``unit``)."""
    d = _read_impedance_csv(path) if _fmt(path) == "csv" else _read_lab_arrays(path)
    if "Z_H" in d and "Z" not in d:
        raise FileFormatError(
            f"{path}: holds the haptic pair Z_H, Z_T, not a single impedance Z; fit it with "
            "hapid fit (hapid.io.load_frf in Python)"
        )
    _need(d, ("freq_hz", "Z"), path)
    f = np.asarray(d["freq_hz"], dtype=np.float64).ravel()
    Z = _frequency_first(d["Z"], f.size, "Z", path)
    std = None if "Z_std" not in d else _frequency_first(d["Z_std"], f.size, "Z_std", path)
    coh = None if "coherence" not in d else np.asarray(d["coherence"], dtype=np.float64)
    tau = float(np.asarray(d.get("exp_tau_s", 0.0), dtype=np.float64).reshape(-1)[0])
    try:
        return as_impedance_frf(f, Z.astype(np.complex128),
                                None if std is None else std.astype(np.float64),
                                unit=_text(d, "unit", "N/m"), coherence=coh, exp_tau_s=tau)  # fmt: skip
    except (ValueError, TypeError) as e:
        raise FileFormatError(f"{path}: {e}") from None


def save_impedance_frf(path, zfrf) -> Path:
    """Write an impedance FRF (``.npz``, ``.mat`` or ``.csv``); frequencies in Hz."""
    arrays = {"freq_hz": np.asarray(zfrf.freq_hz, dtype=np.float64),
              "Z": np.asarray(zfrf.Z, dtype=np.complex128), "unit": np.asarray(zfrf.unit)}  # fmt: skip
    if zfrf.Z_std is not None:
        arrays["Z_std"] = np.asarray(zfrf.Z_std, dtype=np.float64)
    if getattr(zfrf, "coherence", None) is not None:
        arrays["coherence"] = np.asarray(zfrf.coherence, dtype=np.float64)
    if getattr(zfrf, "exp_tau_s", 0.0):
        arrays["exp_tau_s"] = np.float64(zfrf.exp_tau_s)
    if _fmt(path) == "csv":
        return _atomic_write(path, lambda fh: fh.write(_impedance_csv(arrays).encode()))
    return _write_arrays(path, arrays)


def _impedance_csv(arrays: dict) -> str:
    N, n, _ = arrays["Z"].shape
    idx = [f"{i}_{j}" for i in range(n) for j in range(n)]
    Z = arrays["Z"].reshape(N, n * n)
    cols = [arrays["freq_hz"][:, None], Z.real, Z.imag]
    names = ["freq_hz"] + [f"Z_re_{s}" for s in idx] + [f"Z_im_{s}" for s in idx]
    if "Z_std" in arrays:
        cols.append(arrays["Z_std"].reshape(N, n * n))
        names += [f"Z_std_{s}" for s in idx]
    if "coherence" in arrays:
        cols.append(arrays["coherence"])
        names += [f"coherence_{i}" for i in range(n)]
    buf = _io.StringIO()
    tau = f"; exp_tau_s={float(arrays['exp_tau_s'])!r}" if "exp_tau_s" in arrays else ""
    buf.write(f"# unit={arrays['unit']}{tau}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    for row in np.concatenate(cols, axis=1):
        w.writerow([repr(float(v)) for v in row])
    return buf.getvalue()


def _read_impedance_csv(path) -> dict:
    path = Path(path)
    meta, header, rows = _csv_table(path, IMPEDANCE_CSV_LAYOUT)
    col = {h: i for i, h in enumerate(header)}
    n = int(round(np.sqrt(sum(h.startswith("Z_re_") for h in header))))
    idx = [f"{i}_{j}" for i in range(n) for j in range(n)]
    need = ["freq_hz"] + [f"Z_{p}_{s}" for p in ("re", "im") for s in idx]
    missing = [k for k in need if k not in col]
    if n == 0 or missing:
        raise FileFormatError(
            f"{path}: missing columns {missing[:4] or ['Z_re_0_0']}; {IMPEDANCE_CSV_LAYOUT}"
        )
    data = _csv_rows(path, rows, header, IMPEDANCE_CSV_LAYOUT)
    pick = lambda names: data[:, [col[k] for k in names]].reshape(-1, n, n)  # noqa: E731
    out = {"freq_hz": data[:, col["freq_hz"]],
           "Z": _complex(pick([f"Z_re_{s}" for s in idx]), pick([f"Z_im_{s}" for s in idx]))}  # fmt: skip
    if f"Z_std_{idx[0]}" in col:
        out["Z_std"] = pick([f"Z_std_{s}" for s in idx])
    if "coherence_0" in col:
        out["coherence"] = data[:, [col[f"coherence_{i}"] for i in range(n)]]
    if "exp_tau_s" in meta:
        out["exp_tau_s"] = float(meta["exp_tau_s"])
    if "unit" in meta:
        out["unit"] = np.asarray(meta["unit"])
    return out
