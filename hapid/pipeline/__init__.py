"""hapid's chain as pure stages; every entry point (scene runner, CLI, sweep, paper report,
tuner re-check) composes these instead of rebuilding one.

Stage graph (value objects in, value objects out; numeric stages jittable and vmappable)::

    options ─► device ─► experiment (run) ─► frf          (or simulated_frf: device → frf)
    frf ─► fit(estimator, **options) ─► Fit(model, ok, CRHP counts)
    frf ─► control_fit(**nls options) ─► ControlFit(fit, refitted)   the NLS fit for control
           use, with the PSD-boundary refit; every command fits through it
    Fit.model + g ─► controller(ts | continuous, mimo | siso) ─► Controller(response, p_rhp)
    device | model | frf ─► Plant(omega, P, p_rhp, ts)
    Controller + Plant ─► loop(spec) ─► report (verdict rule: :func:`verdict`, i.e. :func:`hapid.control.nyquist_verdict`)

Estimators are registered by name in :data:`ESTIMATORS` (``wls``, ``wls+positize``,
``nls``; one line adds another).
"""

from ._controller import Controller as Controller
from ._controller import compensator as compensator
from ._controller import controller as controller
from ._estimate import ESTIMATORS as ESTIMATORS
from ._estimate import ControlFit as ControlFit
from ._estimate import Fit as Fit
from ._estimate import control_fit as control_fit
from ._estimate import controller_ready as controller_ready
from ._estimate import fit as fit
from ._estimate import register as register
from ._experiment import analysis_grid as analysis_grid
from ._experiment import base_device as base_device
from ._experiment import device as device
from ._experiment import experiment as experiment
from ._experiment import frf as frf
from ._experiment import protocol as protocol
from ._experiment import simulated_frf as simulated_frf
from ._experiment import vary_device as vary_device
from ._loop import SPEC_FIGURES as SPEC_FIGURES
from ._loop import SPEC_REPORT as SPEC_REPORT
from ._loop import SPEC_SWEEP as SPEC_SWEEP
from ._loop import SPEC_VALIDATE as SPEC_VALIDATE
from ._loop import SPEC_VERDICT as SPEC_VERDICT
from ._loop import MetricsSpec as MetricsSpec
from ._loop import Plant as Plant
from ._loop import check_nyquist as check_nyquist
from ._loop import device_plant as device_plant
from ._loop import frf_plant as frf_plant
from ._loop import loop as loop
from ._loop import model_plant as model_plant
from ._loop import verdict as verdict
