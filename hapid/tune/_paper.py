"""The ``tuned`` stage of the paper-reproduction scene (``hapid paper``).

:func:`tuned_design` is a short robust tuning on the device's pose/subject variants (the
nominal plant is held out, :func:`.robust_design` without draws). Its value is the stage's
cached record (plain values and the Compensator, what the stage cache stores), keyed by its
inputs and hapid's source; the scene analyses it as the other columns through
:mod:`hapid.pipeline`.
"""

from __future__ import annotations

import os

from .. import (
    _config,  # noqa: F401  (float64)
)
from ._params import ParamMap
from ._recipe import Recipe, robust_design


def tuned_design(device, model, *, fast: bool | None = None) -> dict:
    """``{"g": Compensator, "status", "decision", "training_stable", "parameters": {name:
    value (Hz for frequencies)}, "constraints", "history"}``: g tuned for ``model`` on
    ``device``'s variants (``status``: :attr:`.TuneResult.status`; ``decision``: why the
    tuned g or the start was returned, :func:`.robust_design`). ``fast`` (default
    ``HAPID_FAST=1``): a short tuning, fewer variants and steps (CI, notebooks)."""
    if fast is None:
        fast = os.environ.get("HAPID_FAST", "0") == "1"
    opts = dict(n_subjects=4, n_freq=150, mu_schedule=(1e2, 1e4), max_steps=100) if fast else {}
    out = robust_design(model, device=device, recipe=Recipe(validate=False, **opts))
    res = out.result
    pm = ParamMap.from_template(res.g)
    return {
        "g": res.g,
        "status": res.status,
        "decision": out.decision.reason,
        "training_stable": {k: list(v) for k, v in res.training.items()},
        "parameters": {k: float(v) for k, v in pm.describe(pm.vector(res.g)).items()},
        "constraints": res.constraints,
        "history": res.history,
    }
