"""The tuned column of the paper-reproduction summary (``hapid paper``).

A short robust tuning on the device's pose/subject variants (the nominal plant is held out,
:func:`.robust_design` without posterior samples), cached on disk under a hash of the
nominal model and the device's sampling, then analysed exactly as the other two columns:
discretized controller on the true sampled plant, generalized Nyquist verdict first.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from .. import _config  # noqa: F401  (float64)
from ..control import analyze_loop, controller_unstable_poles, discretize_controller
from ._files import load_design, save_design

VERSION = "tune-1"
CACHE_DIR = ".hapid_cache/tuned"


def _key(model, device) -> str:
    """Hash of the nominal model, the device's sampling/pose and the tuning code itself (so a
    change of the recipe or the objective never reuses a stale design)."""
    h = hashlib.sha256(VERSION.encode())
    here = Path(__file__).resolve().parent
    for name in ("_objective.py", "_tune.py", "_recipe.py", "_response.py", "_scenarios.py"):
        h.update((here / name).read_bytes())
    for part in (model.hand, model.total):
        for a in (part.M, part.B, part.K):
            h.update(np.ascontiguousarray(np.asarray(a, dtype=float)).tobytes())
    h.update(repr((device.fs_hz, device.delay_samples, device.n)).encode())
    h.update(np.asarray(device.pose.center, dtype=float).tobytes())
    return h.hexdigest()[:16]


def design_path(model, device, cache_dir: str | None = None) -> Path:
    """Where :func:`paper_column` keeps the tuned design of ``model`` on ``device``."""
    cache = Path(cache_dir or os.environ.get("HAPID_TUNE_CACHE", CACHE_DIR))
    fast = os.environ.get("HAPID_FAST", "0") == "1"
    return cache / f"design-{_key(model, device)}{'-fast' if fast else ''}.npz"


def paper_column(device, model, omega, *, cache_dir: str | None = None) -> dict:
    """``{"report": LoopReport, "parameters": {name: value (Hz for frequencies)}, "cached":
    bool}`` for the tuned g on ``device.sampled_P(omega)``. ``cache_dir`` (default
    ``$HAPID_TUNE_CACHE`` or ``.hapid_cache/tuned`` under the working directory) holds one
    design file per model; with ``HAPID_FAST=1`` the tuning is shortened (and cached apart)."""
    from ._params import ParamMap
    from ._recipe import robust_design

    fast = os.environ.get("HAPID_FAST", "0") == "1"
    path = design_path(model, device, cache_dir)
    cached = path.exists()
    if cached:
        g, _ = load_design(path)
    else:
        # HAPID_FAST=1 (CI, notebooks): a short tuning, fewer variants and steps
        opts = dict(n_subjects=4, n_freq=150, mu_schedule=(1e2, 1e4), max_steps=100) if fast else {}
        out = robust_design(model, device=device, validate_designs=False, **opts)
        g = out["result"].g
        save_design(path, g, constraints=out["result"].constraints, history=out["result"].history)
    omega = np.asarray(omega, dtype=float)
    ctrl = discretize_controller(model, g, device.ts)
    G = np.asarray(ctrl.at_omega(omega))
    rep = analyze_loop(np.asarray(device.sampled_P(omega)), G, omega,
                       P_ol_rhp=int(controller_unstable_poles(model, g)))  # fmt: skip
    pm = ParamMap.from_template(g)
    return {
        "report": rep,
        "parameters": pm.describe(pm.vector(g)),
        "cached": cached,
        "design_file": str(path),
    }
