"""The only file I/O: run, FRF and model files (npz contract of DESIGN.md), CSV and MATLAB .mat.

Every writer validates before it writes and writes atomically (temporary file + rename), so a
bad input never leaves a half-written file. Every reader validates what it read and names the
file and the problem in its error.
"""

from __future__ import annotations

import csv
import io as _io
import os
import tempfile
from pathlib import Path

import numpy as np

from .experiment import Run, validate_run
from .frf import FRF, as_frf
from .impedance import ImpedanceModel, SecondOrder

MODEL_KEYS = ("M_H", "B_H", "K_H", "M_T", "B_T", "K_T")


class FileFormatError(ValueError):
    """A file does not follow hapid's file contract."""


def _fmt(path) -> str:
    ext = Path(path).suffix.lower()
    if ext in (".npz", ".csv", ".mat"):
        return ext[1:]
    raise FileFormatError(f"{path}: unknown file type {ext!r}; use .npz, .csv or .mat")


def _atomic_write(path, write) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _write_arrays(path, arrays: dict) -> Path:
    kind = _fmt(path)
    if kind == "npz":
        return _atomic_write(path, lambda fh: np.savez(fh, **arrays))
    if kind == "mat":
        from scipy.io import savemat

        return _atomic_write(path, lambda fh: savemat(fh, arrays))
    raise FileFormatError(f"{path}: this writer supports .npz and .mat")


_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


def _read_arrays(path, what: str = "a hapid .npz or .mat file") -> dict:
    """Every array of a ``.npz``/``.mat`` file as numpy arrays. Anything unreadable (a folder,
    an empty, truncated or non-zip file, text under a ``.npz`` name, pickled object arrays,
    MATLAB cells/structs, v7.3 HDF5 MAT-files) is a :class:`FileFormatError` naming the file
    and what was expected (``what``); the file handle is always closed."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise FileFormatError(f"{path}: is a folder; expected {what}")
    kind = _fmt(path)
    if kind == "csv":
        raise FileFormatError(f"{path}: use the CSV reader for .csv")
    try:
        with open(path, "rb") as fh:
            head = fh.read(128)
            if not head:
                raise FileFormatError(f"{path}: empty file (0 bytes); expected {what}")
            fh.seek(0)
            read = _read_npz if kind == "npz" else _read_mat
            return read(fh, head, path, what)
    except FileFormatError:
        raise
    except PermissionError:
        raise FileFormatError(f"{path}: permission denied; cannot read {what}") from None
    except Exception as e:  # a damaged file can raise nearly anything inside zipfile/zlib/scipy
        raise FileFormatError(
            f"{path}: unreadable ({type(e).__name__}: {e}); expected {what}"
        ) from None


def _describe_head(head: bytes) -> str:
    if head.startswith(b"\x93NUMPY"):
        return "a single-array .npy file"
    if head.startswith(b"\x89HDF") or b"MATLAB 7.3" in head:
        return "an HDF5 file"
    if head.startswith(b"MATLAB"):
        return "a MATLAB .mat file"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        return "binary data of an unknown kind"
    first = text.strip().splitlines()[0][:40] if text.strip() else ""
    return f"text ({first!r}…)"


def _read_npz(fh, head: bytes, path, what: str) -> dict:
    if not head.startswith(_ZIP_MAGIC):
        raise FileFormatError(
            f"{path}: not a .npz (zip) archive: it holds {_describe_head(head)}; expected {what}"
        )
    with np.load(fh, allow_pickle=False) as z:
        out = {}
        for k in z.files:
            try:
                out[k] = z[k]
            except ValueError as e:
                if "allow_pickle" in str(e) or "pickle" in str(e):
                    raise FileFormatError(
                        f"{path}: array {k!r} holds pickled Python objects, which hapid never "
                        f"loads; expected {what} of numeric arrays"
                    ) from None
                raise
        return out


def _read_mat(fh, head: bytes, path, what: str) -> dict:
    if b"MATLAB 7.3" in head or head.startswith(b"\x89HDF"):
        raise FileFormatError(
            f"{path}: a MATLAB v7.3 (HDF5) MAT-file, which this reader does not open; save it "
            f"with save(..., '-v7') (expected {what})"
        )
    if not head.startswith(b"MATLAB") and b"\x00" not in head[:4]:
        raise FileFormatError(
            f"{path}: not a MAT-file: it holds {_describe_head(head)}; expected {what}"
        )
    from scipy.io import loadmat

    raw = loadmat(fh, squeeze_me=False)
    out = {}
    for k, v in raw.items():
        if k.startswith("__"):
            continue
        v = np.asarray(v)
        if v.dtype.kind in "OV":
            raise FileFormatError(
                f"{path}: variable {k!r} is a MATLAB cell array or struct; expected {what} "
                "of numeric matrices"
            )
        out[k] = v
    return out


def _numeric(d: dict, key: str, path, *, complex_ok: bool = False) -> np.ndarray:
    """``d[key]`` as float64 (complex128 with ``complex_ok``), or a FileFormatError naming the
    file, the array and its dtype (strings, objects, or complex where real is expected)."""
    a = np.asarray(d[key])
    kinds = "iufc" if complex_ok else "iuf"
    if a.dtype.kind not in kinds:
        want = "real or complex numbers" if complex_ok else "real numbers"
        raise FileFormatError(f"{path}: array {key!r} has dtype {a.dtype}; expected {want}")
    return a.astype(np.complex128 if complex_ok else np.float64)


def _scalar(d: dict, key: str, path, *, integer: bool = False):
    """``d[key]`` as one Python float (or int with ``integer``), or a FileFormatError."""
    a = _numeric(d, key, path)
    if a.size != 1:
        raise FileFormatError(
            f"{path}: {key!r} must be one number, got an array of shape {a.shape}"
        )
    v = float(a.reshape(()))
    if integer:
        if not np.isfinite(v) or v != int(v):
            raise FileFormatError(f"{path}: {key!r} must be an integer, got {v:g}")
        return int(v)
    return v


def _need(d: dict, keys, path) -> None:
    missing = [k for k in keys if k not in d]
    if missing:
        raise FileFormatError(f"{path}: missing arrays {missing} (has {sorted(d)})")


# ---- run files ------------------------------------------------------------------------------
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
        d = _read_arrays(path, "a run file (fs_hz, period_samples, freq_hz, R_A, R_I, L)")
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
    w.writerow(["experiment", "sample"] + [f"{k}_{i}" for k in ("R_A", "R_I", "L") for i in range(n)])
    for e in range(E):
        block = np.concatenate([run.R_A[e], run.R_I[e], run.L[e]], axis=1)
        for t in range(T):
            w.writerow([e, t] + [repr(float(v)) for v in block[t]])
    return buf.getvalue()


def _read_run_csv(path) -> dict:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    with open(path) as fh:
        head = fh.readline()
        if not head.startswith("#"):
            raise FileFormatError(f"{path}: first line must be '# fs_hz=…; period_samples=…; freq_hz=…'")
        meta = dict(part.strip().split("=", 1) for part in head[1:].split(";") if "=" in part)
        rows = list(csv.reader(fh))
    try:
        header, data = rows[0], np.asarray(rows[1:], dtype=float)
        n = sum(h.startswith("R_A_") for h in header)
        E = int(data[:, 0].max()) + 1
        T = data.shape[0] // E
        arr = data[:, 2:].reshape(E, T, 3 * n)
        return {
            "fs_hz": float(meta["fs_hz"]),
            "period_samples": int(meta["period_samples"]),
            "freq_hz": np.asarray(meta["freq_hz"].split(), dtype=float),
            "R_A": arr[..., :n],
            "R_I": arr[..., n : 2 * n],
            "L": arr[..., 2 * n :],
        }
    except (KeyError, ValueError, IndexError) as e:
        raise FileFormatError(f"{path}: malformed run CSV ({e})") from None


# ---- FRF files ------------------------------------------------------------------------------
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
    as_frf(**{k: v for k, v in arrays.items()})  # validate
    if _fmt(path) == "csv":
        return _atomic_write(path, lambda fh: fh.write(_frf_csv(arrays).encode()))
    return _write_arrays(path, arrays)


def load_frf(path) -> FRF:
    """Read and validate an FRF file."""
    what = "an FRF file (freq_hz, Z_H, Z_T)"
    d = _read_frf_csv(path) if _fmt(path) == "csv" else _read_arrays(path, what)
    _need(d, ("freq_hz", "Z_H", "Z_T"), path)
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
        return as_frf(f, ZH, mat("Z_T", np.complex128), mat("Z_H_std", np.float64),
                      mat("Z_T_std", np.float64), mat("cond_L", np.float64))  # fmt: skip
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
    with open(path) as fh:
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
            out[k] = (re + 1j * im).reshape(-1, n, n)
        for k in ("Z_H_std", "Z_T_std"):
            if f"{k}_0_0" in col:
                out[k] = data[:, [col[f"{k}_{s}"] for s in idx]].reshape(-1, n, n)
        return out
    except (KeyError, ValueError, IndexError) as e:
        raise FileFormatError(f"{path}: malformed FRF CSV ({e})") from None


# ---- model files ----------------------------------------------------------------------------
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
    for k, v in metadata.items():
        if v is not None:
            arrays[k] = np.asarray(v)
    return _write_arrays(path, arrays)


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
    d = _read_arrays(path, "a model file (M_H, B_H, K_H, M_T, B_T, K_T)")
    return {k: v for k, v in d.items() if k not in MODEL_KEYS}
