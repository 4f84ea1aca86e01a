"""What a file holds, told from its arrays (or a CSV's header)."""

from __future__ import annotations

from pathlib import Path

from ._common import FileFormatError, _fmt, _open_text, _read_lab_arrays
from ._model import MODEL_KEYS


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
