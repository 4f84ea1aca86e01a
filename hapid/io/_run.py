"""Run files (``.npz``, ``.mat``, ``.csv``): the excitation and measured records of one
experiment, ``fs_hz``, ``period_samples``, ``freq_hz``, ``R_A``, ``R_I``, ``L`` (docs/contracts.md).
"""

from __future__ import annotations

import csv
import io as _io
from pathlib import Path

import numpy as np

from ..experiment import Run, validate_run
from ._common import (
    FileFormatError,
    _atomic_write,
    _fmt,
    _need,
    _numeric,
    _open_text,
    _read_lab_arrays,
    _scalar,
    _write_arrays,
)


def save_run(path, run: Run) -> Path:
    """Write a run file (``.npz``, ``.mat`` or ``.csv``) after validating it."""
    validate_run(run)
    arrays = {
        "fs_hz": np.float64(run.fs_hz),
        "period_samples": np.int64(run.period_samples),
        "freq_hz": np.asarray(run.freq_hz, dtype=np.float64),
        "R_A": run.R_A,
        "R_I": run.R_I,
        "L": run.L,
    }
    if _fmt(path) == "csv":
        return _atomic_write(path, lambda fh: fh.write(_run_csv(run).encode()))
    return _write_arrays(path, arrays)


def load_run(path) -> Run:
    """Read and validate a run file."""
    if _fmt(path) == "csv":
        d = _read_run_csv(path)
    else:
        d = _read_lab_arrays(path, "a run file (fs_hz, period_samples, freq_hz, R_A, R_I, L)")
    _need(d, ("fs_hz", "period_samples", "freq_hz", "R_A", "R_I", "L"), path)
    try:
        sig = {k: _numeric(d, k, path) for k in ("R_A", "R_I", "L")}
        if _fmt(path) == "mat":  # MATLAB drops trailing singleton axes
            sig = {k: v.reshape(v.shape + (1,) * max(0, 3 - v.ndim)) for k, v in sig.items()}
        return Run(
            fs_hz=_scalar(d, "fs_hz", path),
            period_samples=_scalar(d, "period_samples", path, integer=True),
            freq_hz=_numeric(d, "freq_hz", path).ravel(),
            **sig,
        )
    except ValueError as e:
        raise FileFormatError(f"{path}: {e}") from None


def _run_csv(run: Run) -> str:
    E, T, n = run.R_A.shape
    buf = _io.StringIO()
    buf.write(f"# fs_hz={run.fs_hz!r}; period_samples={run.period_samples}; ")
    buf.write("freq_hz=" + " ".join(repr(float(f)) for f in run.freq_hz) + "\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        ["experiment", "sample"] + [f"{k}_{i}" for k in ("R_A", "R_I", "L") for i in range(n)]
    )
    for e in range(E):
        block = np.concatenate([run.R_A[e], run.R_I[e], run.L[e]], axis=1)
        for t in range(T):
            w.writerow([e, t] + [repr(float(v)) for v in block[t]])
    return buf.getvalue()


def _read_run_csv(path) -> dict:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    with _open_text(path) as fh:
        head = fh.readline()
        if not head.startswith("#"):
            raise FileFormatError(
                f"{path}: first line must be '# fs_hz=…; period_samples=…; freq_hz=…'"
            )
        meta = dict(part.strip().split("=", 1) for part in head[1:].split(";") if "=" in part)
        rows = list(csv.reader(fh))
    try:
        header, data = rows[0], np.asarray(rows[1:], dtype=float)
        n = sum(h.startswith("R_A_") for h in header)
        want = ["experiment", "sample"] + [
            f"{k}_{i}" for k in ("R_A", "R_I", "L") for i in range(n)
        ]
        if header != want:
            raise ValueError(f"header {header[:8]}… is not {want[:8]}…")
        E = int(data[:, 0].max()) + 1
        if not 1 <= E <= data.shape[0]:
            raise ValueError(f"experiment column counts {E} experiments in {data.shape[0]} rows")
        T = data.shape[0] // E
        idx = np.stack([np.repeat(np.arange(E), T), np.tile(np.arange(T), E)], axis=1)
        if data.shape[0] != E * T or not np.array_equal(data[:, :2], idx):
            raise ValueError(
                "experiment/sample columns must count 0, 1, … (every experiment the same length)"
            )
        arr = data[:, 2:].reshape(E, T, 3 * n)
        return {
            "fs_hz": float(meta["fs_hz"]),
            "period_samples": int(meta["period_samples"]),
            "freq_hz": np.asarray(meta["freq_hz"].split(), dtype=float),
            "R_A": arr[..., :n],
            "R_I": arr[..., n : 2 * n],
            "L": arr[..., 2 * n :],
        }
    except (KeyError, ValueError, IndexError, ZeroDivisionError, OverflowError) as e:
        raise FileFormatError(f"{path}: malformed run CSV ({e})") from None
