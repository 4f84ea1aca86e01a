"""The only file I/O: run, FRF and model files (npz contracts in docs/contracts.md), CSV and MATLAB .mat.

Every writer validates before it writes and writes atomically (temporary file + rename), so a
bad input never leaves a half-written file. Every reader validates what it read and names the
file and the problem in its error.
"""

from __future__ import annotations

import csv
import hashlib
import io as _io
import json
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .control._compensator import FIELDS as COMPENSATOR_FIELDS
from .control._compensator import POSITIVE_FIELDS, Compensator
from .experiment import Run, validate_run
from .frf import FRF, as_frf
from .impedance import ImpedanceModel, SecondOrder

if TYPE_CHECKING:
    from .uncertainty._samples import PosteriorSamples

MODEL_KEYS = ("M_H", "B_H", "K_H", "M_T", "B_T", "K_T")


class FileFormatError(ValueError):
    """A file does not follow hapid's file contract."""


def _fmt(path) -> str:
    ext = Path(path).suffix.lower()
    if ext in (".npz", ".csv", ".mat"):
        return ext[1:]
    raise FileFormatError(f"{path}: unknown file type {ext!r}; use .npz, .csv or .mat")


def _umask() -> int:
    """The process umask (read without changing it for longer than the two calls)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _atomic_write(path, write) -> Path:
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


def _open_text(path):
    """A CSV file as text (``io.StringIO``); a file that is not UTF-8 text is a
    :class:`FileFormatError` naming it."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise FileFormatError(f"{path}: is a folder; expected a CSV file")
    raw = path.read_bytes()
    try:
        return _io.StringIO(raw.decode("utf-8-sig"), newline="")
    except UnicodeDecodeError:
        raise FileFormatError(
            f"{path}: not UTF-8 text: it holds {_describe_head(raw[:128])}; expected a CSV file"
        ) from None


def _complex(re: np.ndarray, im: np.ndarray) -> np.ndarray:
    """``re + j·im`` without arithmetic (``1j * inf`` warns and makes NaN; a non-finite entry
    must reach the validator as itself)."""
    z = np.empty(np.shape(re), dtype=np.complex128)
    z.real, z.imag = re, im
    return z


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


# ---- FRF files ------------------------------------------------------------------------------
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
    ``draws`` (e.g. ``P``, ``Z_H``, ``Z_T``: ``(S, N, n, n)`` complex) to an ``.npz``."""
    arrays = {"freq_hz": np.asarray(freq_hz, dtype=np.float64)}
    arrays |= {k: np.asarray(v, dtype=np.complex128) for k, v in draws.items()}
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
    return _write_with_metadata(path, arrays, metadata)


def _write_with_metadata(path, arrays: dict, metadata: dict) -> Path:
    """Write ``arrays`` plus every ``metadata`` entry that is not ``None`` (as an array)."""
    extra = {k: np.asarray(v) for k, v in metadata.items() if v is not None}
    return _write_arrays(path, arrays | extra)


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


# ---- lab data: time series, single-impedance FRF and model files ---------------------------
# Contracts (docs/lab-data.md):
# - time series: fs_hz (scalar), force and response (T, n) or (E, T, n); optional strings
#   force_unit, length_unit. CSV: first line "# fs_hz=…" (or a time_s column), then columns
#   [experiment,] force_0 … force_{n-1}, response_0 … response_{n-1}.
# - impedance FRF: freq_hz (N,), Z (N, n, n) complex, optional Z_std (N, n, n), coherence
#   (N, n), exp_tau_s (s), unit (text).
# - impedance model: M, B, K (n, n) plus metadata (method, status, quality_*, …).

TIMESERIES_CSV_LAYOUT = (
    "expected a time-series CSV: first line '# fs_hz=<Hz>' (or a time_s column), a header row "
    "'[experiment,] [time_s,] force_0,…,force_{n-1},response_0,…,response_{n-1}', then one row "
    "per sample"
)
IMPEDANCE_CSV_LAYOUT = (
    "expected an impedance-FRF CSV: header 'freq_hz,Z_re_0_0,…,Z_im_0_0,…[,Z_std_0_0,…]' "
    "(row-major i_j), one row per frequency"
)


def _read_mat73(path) -> dict:
    """Numeric arrays of a MATLAB v7.3 (HDF5) MAT-file through h5py (the ``hdf5`` extra).

    MATLAB writes column-major, so every array is transposed back to MATLAB's shape; complex
    arrays (compound ``real``/``imag``) become complex128. Strings, cells and structs are
    skipped.
    """
    try:
        import h5py
    except ImportError:
        raise FileFormatError(
            f"{path}: a MATLAB v7.3 (HDF5) MAT-file needs h5py: pip install 'hapid[hdf5]' "
            "(or save it in MATLAB with save(..., '-v7'))"
        ) from None
    out = {}
    try:
        h = h5py.File(path, "r")
    except OSError as e:
        raise FileFormatError(
            f"{path}: damaged MATLAB v7.3 (HDF5) file ({e}); expected a readable MAT-file"
        ) from None
    with h:
        for k, ds in h.items():
            if k.startswith("#") or not isinstance(ds, h5py.Dataset):
                continue
            if ds.attrs.get("MATLAB_class", b"") in (b"char", b"cell", b"struct"):
                continue
            a = ds[()]
            if a.dtype.names and {"real", "imag"} <= set(a.dtype.names):
                a = a["real"] + 1j * a["imag"]
            if a.dtype.kind not in "biufc":
                continue
            out[k] = np.asarray(a).T
    return out


def _is_hdf5(path) -> bool:
    with open(path, "rb") as fh:
        head = fh.read(128)
    return head.startswith(b"\x89HDF") or b"MATLAB 7.3" in head


def _read_lab_arrays(path, what: str = "a hapid .npz or .mat file") -> dict:
    """``_read_arrays`` that also opens MATLAB v7.3 files (h5py)."""
    path = Path(path)
    if path.suffix.lower() == ".mat" and path.is_file() and _is_hdf5(path):
        return _read_mat73(path)
    return _read_arrays(path, what)


def _text(d: dict, key: str, default: str) -> str:
    if key not in d:
        return default
    a = np.asarray(d[key])
    return str(a.reshape(-1)[0]) if a.dtype.kind in "US" and a.size else default


def file_kind(path, what: str = "a hapid .npz or .mat file") -> str:
    """What a file holds, from its arrays: ``"run"``, ``"timeseries"``, ``"frf"`` (the haptic
    Z_H/Z_T pair), ``"impedance_frf"``, ``"model"`` (hand/total), ``"impedance_model"``, or
    ``"unknown"``. CSV files are told apart by their header."""
    path = Path(path)
    if _fmt(path) == "csv":
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such file")
        with _open_text(path) as fh:
            head = fh.readline() + fh.readline()
        if not head.strip():
            raise FileFormatError(f"{path}: the file is empty")
        if "R_A_" in head:
            return "run"
        if "Z_H_re_" in head:
            return "frf"
        if "Z_re_" in head:
            return "impedance_frf"
        if "force_" in head:
            return "timeseries"
        return "unknown"
    keys = set(_read_lab_arrays(path, what))
    for kind, need in (("run", {"R_A", "R_I", "L"}), ("frf", {"Z_H", "Z_T"}),
                       ("impedance_frf", {"Z", "freq_hz"}), ("model", set(MODEL_KEYS)),
                       ("impedance_model", {"M", "B", "K"}), ("timeseries", {"force", "response"})):  # fmt: skip
        if need <= keys:
            return kind
    return "unknown"


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
    from .experiment import TimeSeries

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


def _csv_table(path, layout: str) -> tuple[dict, list[str], list[str]]:
    """A CSV file with an optional ``# key=value; …`` first line, split into
    ``(meta, header, data lines)``; ``layout`` ends the error messages."""
    with _open_text(path) as fh:
        lines = fh.read().splitlines()
    meta = {}
    if lines and lines[0].startswith("#"):
        meta = dict(p.strip().split("=", 1) for p in lines[0][1:].split(";") if "=" in p)
        lines = lines[1:]
    if not any(ln.strip() for ln in lines):
        raise FileFormatError(f"{path}: the file is empty; {layout}")
    if not lines:
        raise FileFormatError(f"{path}: no header row; {layout}")
    return meta, [h.strip() for h in lines[0].split(",")], lines[1:]


def _csv_rows(path, rows: list[str], header: list[str], layout: str) -> np.ndarray:
    """The numeric data lines of a CSV as ``(rows, len(header))`` float64; at least one row."""
    try:
        data = np.loadtxt(rows, delimiter=",", ndmin=2)
    except ValueError as e:
        raise FileFormatError(f"{path}: non-numeric row ({e}); {layout}") from None
    if data.shape[0] == 0 or data.shape[1] != len(header):
        raise FileFormatError(
            f"{path}: {data.shape[0]} rows of {data.shape[1] if data.size else 0} values for "
            f"{len(header)} header columns; {layout}"
        )
    return data


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
    from .experiment._impedance import validate_timeseries

    validate_timeseries(ts)
    arrays = {"fs_hz": np.float64(ts.fs_hz), "force": np.asarray(ts.force, dtype=np.float64),
              "response": np.asarray(ts.response, dtype=np.float64),
              "force_unit": np.asarray(ts.force_unit), "length_unit": np.asarray(ts.length_unit)}  # fmt: skip
    return _write_arrays(path, arrays)


def _frequency_first(a: np.ndarray, N: int, name: str, path) -> np.ndarray:
    """``(N, n, n)``; a MATLAB-style ``(n, n, N)`` is named with a hint, ``(n, n)`` with N = 1."""
    a = np.asarray(a)
    if a.ndim == 2 and N == 1:
        a = a[None]
    if a.ndim == 3 and a.shape[0] != N and a.shape[-1] == N and a.shape[0] == a.shape[1]:
        raise FileFormatError(
            f"{path}: {name} has shape {a.shape}, which looks like (n, n, N) (MATLAB's "
            f"frequency-last layout); hapid expects frequency first (N, n, n): use "
            f"permute({name}, [3 1 2]) in MATLAB or np.moveaxis({name}, -1, 0)"
        )
    if a.ndim != 3 or a.shape[0] != N or a.shape[1] != a.shape[2]:
        raise FileFormatError(
            f"{path}: {name} must be (N, n, n) with N = {N} frequencies, got {a.shape}"
        )
    return a


def load_impedance_frf(path):
    """Read and validate an impedance FRF file (``freq_hz``, ``Z``, optional ``Z_std``, ``unit``)."""
    from .impedance_frf import as_impedance_frf

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


# ---- stage cache entries (hapid._stages): arrays + one JSON string, never pickle ----------------
def save_cache_entry(path, arrays: dict, meta: str) -> Path:
    """Write a stage-cache entry atomically: ``arrays`` by name plus the JSON string ``meta``."""
    return _atomic_write(path, lambda fh: np.savez(fh, __meta__=np.asarray(meta), **arrays))


def load_cache_entry(path) -> tuple[dict, str]:
    """``(arrays, meta)`` of a stage-cache entry (``allow_pickle=False``)."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != "__meta__"}
        return arrays, str(z["__meta__"])


# ---- reports, tables, samples and designs --------------------------------------------------
def jsonable(obj):
    """``obj`` as strict-JSON-ready Python values: numpy/JAX scalars and arrays → numbers and
    lists, NaN and ±inf → ``None`` (JSON ``null``), tuples → lists, dict keys → ``str``;
    anything else (e.g. a complex number) → its ``str``."""
    if obj is None or isinstance(obj, bool | str):
        return obj
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


def save_samples(path, ps) -> Path:
    """Write posterior samples (:class:`hapid.uncertainty.PosteriorSamples`) to ``.npz``:
    ``samples (S, d)``, ``log_prob (S,)``, ``n``, ``names``, ``omega_ref`` (rad/s), ``z_ref``,
    ``method``, the scalar diagnostics as ``diag_*`` and the model-error predictive data
    (``pred_*``: what the GP model error needs to predict at new frequencies) and the whole
    measured FRF (``meas_omega``, ``meas_Z_H``, ``meas_Z_T``: the loop draws' data). A path without the ``.npz`` suffix
    gets it appended (as ``numpy.savez`` does); the path written is returned."""
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_suffix(path.suffix + ".npz")
    arrays = {
        f"diag_{k}": np.asarray(v)
        for k, v in ps.diagnostics.items()
        if isinstance(v, int | float | bool | np.ndarray) and not isinstance(v, dict)
    }
    arrays |= {
        "samples": np.asarray(ps.samples, dtype=np.float64),
        "log_prob": np.asarray(ps.log_prob, dtype=np.float64),
        "n": np.int64(ps.n),
        "names": np.asarray(ps.names),
        "omega_ref": np.float64(ps.scale.omega_ref),
        "z_ref": np.float64(ps.scale.z_ref),
        "method": np.asarray(str(ps.diagnostics.get("method", ""))),
    }
    arrays |= {
        f"pred_{k}": np.asarray(v) for k, v in (getattr(ps, "predictive", None) or {}).items()
    }
    arrays |= {f"meas_{k}": np.asarray(v) for k, v in (getattr(ps, "measured", None) or {}).items()}
    return _atomic_write(path, lambda fh: np.savez(fh, **arrays))


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


def load_design(path) -> tuple[Compensator, dict]:
    """``(g, info)`` from a design file (:func:`save_design`): the compensator and the
    decoded ``json`` entry (``{}`` when absent). Raises ``FileNotFoundError`` or
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
    return g, info


def load_samples(path, n: int | None = None) -> PosteriorSamples:
    """Read a :func:`save_samples` file. ``n`` (optional): the rod count expected — a file
    for a different ``n``, or whose sample width does not match its ``n``, is a
    ``ValueError``."""
    # imported here: hapid.uncertainty pulls emcee, optimistix and scipy into every command that
    # reads a file (hapid analyze's start-up), for the one reader that builds its samples
    import jax.numpy as jnp

    from .fit._pd import Scale, n_params
    from .uncertainty._samples import PosteriorSamples

    path = Path(path)
    if not path.exists():
        raise ValueError(f"samples file {path} does not exist")
    d = _read_arrays(path, "a posterior-samples file (hapid posterior)")
    missing = [k for k in ("samples", "log_prob", "n", "omega_ref", "z_ref", "names") if k not in d]
    if missing:
        raise ValueError(f"{path}: not a posterior-samples file (missing {missing})")
    file_n = _scalar(d, "n", path, integer=True)
    if file_n < 1:
        raise ValueError(f"{path}: n = {file_n} rods; expected n ≥ 1")
    s = _numeric(d, "samples", path)
    log_prob = _numeric(d, "log_prob", path)
    omega_ref, z_ref = _scalar(d, "omega_ref", path), _scalar(d, "z_ref", path)
    if n is not None and file_n != int(n):
        raise ValueError(
            f"{path}: samples are for an n = {file_n} rod device, but n = {n} was expected"
        )
    p = n_params(file_n)
    if s.ndim != 2 or s.shape[1] not in (p, p + 2, p + 6, p + 8, p + 10):
        raise ValueError(
            f"{path}: samples have shape {s.shape}, which does not fit n = {file_n} "
            f"(expected (S, {p}), (S, {p + 2}), (S, {p + 6}), (S, {p + 8}) or (S, {p + 10}))"
        )
    if not np.all(np.isfinite(s)):
        raise ValueError(f"{path}: samples contain NaN or inf")
    if s.shape[0] == 0 or log_prob.shape != (s.shape[0],):
        raise ValueError(
            f"{path}: {s.shape[0]} samples with log_prob of shape {log_prob.shape}; expected "
            f"≥ 1 sample and log_prob of shape ({s.shape[0]},)"
        )
    if not (np.all(np.isfinite(log_prob)) or np.all(np.isnan(log_prob))):  # all NaN: not evaluated
        raise ValueError(
            f"{path}: log_prob has NaN or inf entries; expected all finite (MCMC draws) or all "
            "NaN (draws whose density was not evaluated, e.g. Laplace)"
        )
    if not (np.isfinite(omega_ref) and omega_ref > 0 and np.isfinite(z_ref) and z_ref > 0):
        raise ValueError(f"{path}: omega_ref = {omega_ref:g}, z_ref = {z_ref:g}; expected both > 0")
    diag = {k[5:]: (v.item() if v.ndim == 0 else v) for k, v in d.items() if k.startswith("diag_")}
    diag["method"] = str(d["method"]) if "method" in d else ""
    return PosteriorSamples(
        samples=s,
        log_prob=log_prob,
        scale=Scale(jnp.asarray(omega_ref), jnp.asarray(z_ref)),
        n=file_n,
        names=tuple(str(x) for x in d["names"]),
        diagnostics=diag,
        predictive=_load_predictive(d, path, file_n) if "pred_kind" in d else None,
        measured=_load_measured(d, path, file_n) if "meas_omega" in d else None,
    )


def _load_measured(d: dict, path, n: int) -> dict:
    out = {k: np.asarray(d[f"meas_{k}"]) for k in ("omega", "Z_H", "Z_T") if f"meas_{k}" in d}
    K = np.shape(out.get("omega", ()))
    for k in ("Z_H", "Z_T"):
        if k not in out or np.shape(out[k]) != K + (n, n) or not np.all(np.isfinite(out[k])):
            raise ValueError(
                f"{path}: measured FRF {k!r} missing, not finite or not ({K[0] if K else 0}, {n}, {n})"
            )
    if len(K) != 1 or K[0] < 3 or np.any(np.diff(out["omega"]) <= 0) or out["omega"][0] <= 0:
        raise ValueError(f"{path}: measured FRF omega must be ≥ 3 increasing positive frequencies")
    return out


def _load_predictive(d: dict, path, n: int) -> dict:
    out = {k[5:]: v for k, v in d.items() if k.startswith("pred_")}
    out["kind"] = str(out["kind"])
    if "error_scale" in out:
        out["error_scale"] = str(out["error_scale"])
    N = np.shape(out.get("omega", ()))
    for k in ("Z_H", "Z_T", "var_H", "var_T"):
        if k not in out or np.shape(out[k]) != N + (n, n) or not np.all(np.isfinite(out[k])):
            raise ValueError(
                f"{path}: predictive data {k!r} missing or not finite ({N[0] if N else 0}, {n}, {n})"
            )
    return out
