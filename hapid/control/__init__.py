"""Control design and multivariable loop analysis.

* :class:`Compensator` — the scalar g(s) (lag, notches, low-pass), differentiable.
* :func:`inverse_model_response`, :func:`inverse_model_state_space`,
  :func:`siso_response`, :func:`max_siso_gain` — the controllers.
* :func:`controller_is_stable`, :func:`check_controller` — realizability (paper 5.1).
* :func:`loop_metrics` → :class:`LoopMetrics` (what a :class:`MetricsSpec` asks for) — the
  generalized Nyquist verdict (:func:`nyquist_verdict`), isotropic bandwidth, gain/phase/disk
  margins, σ̄(T) peak, crossings refined off the grid (jit/vmap-able).
* Building blocks, jit/vmap-able, each returning a ``NamedTuple`` of arrays:
  :func:`loop_matrices` → :class:`LoopMatrices`, :func:`isotropic_bandwidth` →
  :class:`IsotropicBandwidth`, :func:`nyquist_encirclements` → :class:`Encirclements`,
  :func:`loci_margins` → :class:`LociMargins`, :func:`disk_margin_from_peak` →
  :class:`DiskMargin`.
* :class:`StateSpace`, :func:`closed_loop_poles`, :func:`closed_loop_is_stable` — the
  state-space cross-check.
* :func:`discretize_compensator`, :func:`discretize_controller` — sampled controllers.
"""

from ..lti import StateSpace as StateSpace
from ..lti import closed_loop_is_stable as closed_loop_is_stable
from ..lti import closed_loop_matrix as closed_loop_matrix
from ..lti import closed_loop_poles as closed_loop_poles
from ..lti import closed_loop_well_posed as closed_loop_well_posed
from ..lti import series as series
from ._compensator import Compensator as Compensator
from ._controller import ControllerCheck as ControllerCheck
from ._controller import ControllerWarning as ControllerWarning
from ._controller import check_controller as check_controller
from ._controller import controller_is_stable as controller_is_stable
from ._controller import controller_unstable_poles as controller_unstable_poles
from ._controller import impedance_ratio_state_space as impedance_ratio_state_space
from ._controller import inverse_model_response as inverse_model_response
from ._controller import inverse_model_state_space as inverse_model_state_space
from ._controller import max_siso_gain as max_siso_gain
from ._controller import siso_response as siso_response
from ._discrete import DiscreteController as DiscreteController
from ._discrete import DiscreteStateSpace as DiscreteStateSpace
from ._discrete import discretize_compensator as discretize_compensator
from ._discrete import discretize_controller as discretize_controller
from ._discrete import discretize_siso_controller as discretize_siso_controller
from ._discrete import discretize_state_space as discretize_state_space
from ._loop import ISO_THRESHOLD as ISO_THRESHOLD
from ._loop import IsotropicBandwidth as IsotropicBandwidth
from ._loop import LoopMatrices as LoopMatrices
from ._loop import isotropic_bandwidth as isotropic_bandwidth
from ._loop import loop_matrices as loop_matrices
from ._margins import DiskMargin as DiskMargin
from ._margins import LociMargins as LociMargins
from ._margins import disk_margin_from_peak as disk_margin_from_peak
from ._margins import loci_margins as loci_margins
from ._metrics import LoopMetrics as LoopMetrics
from ._metrics import MetricsSpec as MetricsSpec
from ._metrics import loop_metrics as loop_metrics
from ._nyquist import Encirclements as Encirclements
from ._nyquist import characteristic_loci as characteristic_loci
from ._nyquist import nyquist_encirclements as nyquist_encirclements
from ._nyquist import nyquist_verdict as nyquist_verdict
from ._nyquist import track_loci as track_loci
from ._status import ControllerStatus as ControllerStatus
from ._status import LoopStatus as LoopStatus
