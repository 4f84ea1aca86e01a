"""Posterior-samples files (``.npz``, ``hapid posterior``): the samples, their log density,
the parameter scale, the scalar diagnostics, the model-error predictive data and the measured FRF.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import jax.numpy as jnp
import numpy as np

from ._common import _atomic_write, _numeric, _read_arrays, _scalar

if TYPE_CHECKING:
    from ..samples import PosteriorSamples


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


def load_samples(path, n: int | None = None) -> PosteriorSamples:
    """Read a :func:`save_samples` file. ``n`` (optional): the rod count expected — a file
    for a different ``n``, or whose sample width does not match its ``n``, is a
    ``ValueError``."""
    from ..fit._pd import Scale, n_params  # local: CLI start-up (hapid.fit, optimistix)
    from ..samples import PosteriorSamples  # local: CLI start-up (hapid.fit, optimistix)

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
    keys = ("omega", "Z_H", "Z_T", "Z_H_std", "Z_T_std")
    out = {k: np.asarray(d[f"meas_{k}"]) for k in keys if f"meas_{k}" in d}
    K = np.shape(out.get("omega", ()))
    for k in ("Z_H", "Z_T", "Z_H_std", "Z_T_std"):
        if k.endswith("_std") and k not in out:  # the element std is optional
            continue
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
