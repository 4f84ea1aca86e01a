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
"""

from .. import _config  # noqa: F401  (float64)
from ._binding import Binding as Binding
from ._binding import BindingStatus as BindingStatus
from ._binding import Constraint as Constraint
from ._binding import binding_constraints as binding_constraints
from ._decision import Choice as Choice
from ._decision import Decision as Decision
from ._evidence import Certificate as Certificate
from ._evidence import Evidence as Evidence
from ._evidence import certificate as certificate
from ._evidence import evidence_from_frf as evidence_from_frf
from ._files import load_design as load_design
from ._files import save_design as save_design
from ._files import tune_from_files as tune_from_files
from ._objective import Box as Box
from ._objective import Family as Family
from ._objective import Requirements as Requirements
from ._objective import aggregate as aggregate
from ._objective import cvar as cvar
from ._objective import penalized as penalized
from ._objective import scenario_constraints as scenario_constraints
from ._params import ParamMap as ParamMap
from ._params import extend_structure as extend_structure
from ._recipe import Recipe as Recipe
from ._recipe import RobustDesign as RobustDesign
from ._recipe import posterior_grid as posterior_grid
from ._recipe import robust_design as robust_design
from ._recipe_plants import PosteriorPlants as PosteriorPlants
from ._recipe_plants import posterior_plants as posterior_plants
from ._response import g_response as g_response
from ._response import smooth_sigma_max as smooth_sigma_max
from ._scenarios import Scenarios as Scenarios
from ._scenarios import concat as concat
from ._scenarios import make_scenarios as make_scenarios
from ._scenarios import matrix_part as matrix_part
from ._tune import TuneResult as TuneResult
from ._tune import TuneStatus as TuneStatus
from ._tune import smooth_bandwidth as smooth_bandwidth
from ._tune import tune as tune
from ._validate import StepResponse as StepResponse
from ._validate import StepStatus as StepStatus
from ._validate import Validation as Validation
from ._validate import device_grid as device_grid
from ._validate import step_response as step_response
from ._validate import true_plant_loop as true_plant_loop
from ._validate import validate as validate
