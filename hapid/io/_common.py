"""What every reader and writer of :mod:`hapid.io` shares.

* :class:`FileFormatError` — a file does not follow hapid's file contract.
* Format from the suffix (``.npz``, ``.mat``, ``.csv``); atomic writes (temporary file in the
  same folder + rename, the mode ``open(path, "w")`` would give).
* Reading every array of a ``.npz``/``.mat`` (v7.3 HDF5 MAT-files through h5py for lab data) and
  CSV text, with errors that name the file and the problem.
* Checks on what was read: numeric arrays, scalars, required arrays, text entries, frequency-first
  ``(N, n, n)`` layout.
"""

from __future__ import annotations

import io as _io
from pathlib import Path

import numpy as np

from .._atomic import atomic_write as _atomic_write  # noqa: F401  (the io writers' name)


class FileFormatError(ValueError):
    """A file does not follow hapid's file contract."""


def _fmt(path) -> str:
    ext = Path(path).suffix.lower()
    if ext in (".npz", ".csv", ".mat"):
        return ext[1:]
    raise FileFormatError(f"{path}: unknown file type {ext!r}; use .npz, .csv or .mat")


def _write_arrays(path, arrays: dict) -> Path:
    kind = _fmt(path)
    if kind == "npz":
        return _atomic_write(path, lambda fh: np.savez(fh, **arrays))
    if kind == "mat":
        from scipy.io import savemat  # local: CLI start-up (scipy.io, ~0.12 s on import hapid.io)

        return _atomic_write(path, lambda fh: savemat(fh, arrays))
    raise FileFormatError(f"{path}: this writer supports .npz and .mat")


def _write_with_metadata(path, arrays: dict, metadata: dict) -> Path:
    """Write ``arrays`` plus every ``metadata`` entry that is not ``None`` (as an array)."""
    extra = {k: np.asarray(v) for k, v in metadata.items() if v is not None}
    return _write_arrays(path, arrays | extra)


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
    from scipy.io import loadmat  # local: CLI start-up (scipy.io, ~0.12 s on import hapid.io)

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


def _read_mat73(path) -> dict:
    """Numeric arrays of a MATLAB v7.3 (HDF5) MAT-file through h5py (the ``hdf5`` extra).

    MATLAB writes column-major, so every array is transposed back to MATLAB's shape; complex
    arrays (compound ``real``/``imag``) become complex128. Strings, cells and structs are
    skipped.
    """
    try:
        import h5py  # local: optional dependency h5py
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


def _text(d: dict, key: str, default: str) -> str:
    if key not in d:
        return default
    a = np.asarray(d[key])
    return str(a.reshape(-1)[0]) if a.dtype.kind in "US" and a.size else default


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
