"""Differentiable design of the compensator g(s): robust gradient tuning and its validation.

* :class:`ParamMap` — g's parameters in log coordinates.
* :func:`g_response`, :func:`smooth_sigma_max` — LAPACK-free differentiable pieces.
* :func:`make_scenarios` → :class:`Scenarios` — plants pre-diagonalized as loops ``g·Q``.
* :class:`Requirements`, :class:`Family`, :func:`scenario_constraints`, :func:`aggregate` —
  the smooth bandwidth surrogate, margin constraints and their CVaR over scenarios.
* :func:`tune` → :class:`TuneResult` — continuation penalty + BFGS (optimistix).
* :func:`robust_design` (model, draws, evidence, :class:`Recipe`) → :class:`RobustDesign`,
  whose :class:`Decision` says which g it returns and why (the table of :mod:`._decision`).
* :func:`validate` → :class:`Validation` — the non-smooth re-check (Nyquist verdict, iso bandwidth, GM/PM, disk
  margin) on held-out plants, the true plant and in the time domain.

Names load on first use (PEP 562): a command that needs only the certificate or g's
response (``hapid robust``, ``hapid analyze``) does not import the optimizer stack.
"""

from .. import _config  # noqa: F401  (float64)
from .._lazy import lazy_names as _lazy_names

_NAMES = {
    "Binding": "_binding",
    "BindingStatus": "_binding",
    "Constraint": "_binding",
    "binding_constraints": "_binding",
    "Choice": "_decision",
    "Decision": "_decision",
    "Certificate": "_evidence",
    "Evidence": "_evidence",
    "certificate": "_evidence",
    "evidence_from_frf": "_evidence",
    "load_design": "_files",
    "save_design": "_files",
    "tune_from_files": "_files",
    "Box": "_objective",
    "Family": "_objective",
    "Requirements": "_objective",
    "aggregate": "_objective",
    "cvar": "_objective",
    "penalized": "_objective",
    "scenario_constraints": "_objective",
    "ParamMap": "_params",
    "extend_structure": "_params",
    "Recipe": "_recipe",
    "RobustDesign": "_recipe",
    "posterior_grid": "_recipe",
    "robust_design": "_recipe",
    "PosteriorPlants": "_recipe_plants",
    "posterior_plants": "_recipe_plants",
    "g_response": "_response",
    "smooth_sigma_max": "_response",
    "Scenarios": "_scenarios",
    "concat": "_scenarios",
    "make_scenarios": "_scenarios",
    "matrix_part": "_scenarios",
    "TuneResult": "_tune",
    "TuneStatus": "_tune",
    "smooth_bandwidth": "_tune",
    "tune": "_tune",
    "StepResponse": "_validate",
    "StepStatus": "_validate",
    "Validation": "_validate",
    "device_grid": "_validate",
    "step_response": "_validate",
    "true_plant_loop": "_validate",
    "validate": "_validate",
}
__all__ = list(_NAMES)

__getattr__, __dir__ = _lazy_names(__name__, _NAMES)
