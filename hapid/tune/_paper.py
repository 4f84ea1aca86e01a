"""The tuned column of the paper-reproduction summary (``hapid paper``).

:func:`tuned_design` is a short robust tuning on the device's pose/subject variants (the
nominal plant is held out, :func:`.robust_design` without posterior samples). In the scene it
is the ``tuned`` stage, cached like every other stage (keyed by its inputs and hapid's source,
bypassed by ``--no-cache``); :func:`paper_column` analyses it exactly as the other two
columns through :mod:`hapid.pipeline`: discretized controller on the true sampled plant,
generalized Nyquist verdict first.
"""

from __future__ import annotations

import os

import numpy as np

from .. import (
    _config,  # noqa: F401  (float64)
    pipeline,
)
from ._params import ParamMap
from ._recipe import robust_design


def tuned_design(device, model, *, fast: bool | None = None) -> dict:
    """``{"g": Compensator, "status", "decision", "training_stable", "parameters": {name:
    value (Hz for frequencies)}, "constraints", "history"}``: g tuned for ``model`` on
    ``device``'s variants (``status``: :attr:`.TuneResult.status`; ``decision``: why the
    tuned g or the start was returned, :func:`.robust_design`). ``fast`` (default
    ``HAPID_FAST=1``): a short tuning, fewer variants and steps (CI, notebooks)."""
    if fast is None:
        fast = os.environ.get("HAPID_FAST", "0") == "1"
    opts = dict(n_subjects=4, n_freq=150, mu_schedule=(1e2, 1e4), max_steps=100) if fast else {}
    out = robust_design(model, device=device, validate_designs=False, **opts)
    res = out["result"]
    pm = ParamMap.from_template(res.g)
    return {
        "g": res.g,
        "status": res.status,
        "decision": out["decision"],
        "training_stable": {k: list(v) for k, v in res.training.items()},
        "parameters": {k: float(v) for k, v in pm.describe(pm.vector(res.g)).items()},
        "constraints": res.constraints,
        "history": res.history,
    }


def paper_column(device, model, omega, *, design: dict | None = None) -> dict:
    """``{"report": LoopMetrics, "parameters": {...}, "g": Compensator}`` for the tuned g on
    ``device.sampled_P(omega)`` (``design`` from :func:`tuned_design`, computed when
    ``None`` — the scene's ``tuned`` stage caches it)."""
    design = tuned_design(device, model) if design is None else design
    plant = pipeline.device_plant(device, np.asarray(omega, dtype=float))
    rep = pipeline.loop(pipeline.controller(model, design["g"], ts=device.ts), plant)
    return {"report": rep, "parameters": design["parameters"], "g": design["g"]}
