"""Posterior uncertainty of identified impedance models and robust-margin checks.

- :func:`make_log_posterior` → :class:`LogPosterior` — complex-Gaussian likelihood with a
  model-error term (a strategy object: :class:`NoError`, :class:`White`, :class:`GP`,
  :class:`GPCorr`; the CLI's names map to them in :func:`model_error_from`, a samples file's
  kind in :func:`model_error_for`) and proper priors on the matrices in the PSD cone
  (``log_prob`` jitted and vmapped over walkers);
  :func:`fix_hyperparameters` is the step that fixes a GP's hyperparameters.
- :func:`sample_posterior` (emcee), :func:`laplace_samples` (fast path),
  :func:`laplace_posterior` (→ :class:`LaplacePosterior`) → :class:`PosteriorSamples`
  (files: :func:`hapid.io.save_samples`, :func:`hapid.io.load_samples`);
  :func:`posterior_from_files` for the CLI.
- :func:`credible_bands` — posterior-predictive bands of |Z|, σ(Z), σ(P), σ(P P̂⁻¹).
- :func:`predictive_plants` — draws of the true Z_H, Z_T, P on any grid *including* the
  model-error term (GP conditional on the fit residuals); :func:`band_calibration`;
  :func:`holdout_check` (→ :class:`HoldoutCheck`) — where between the measured frequencies
  that band is not established (each one left out in turn and predicted from the rest);
  :func:`recalibration` (→ :class:`Recalibration`) — that band recalibrated on the check's
  left-out errors, split by direction (:func:`direction_split`).
- :func:`robust_check`, :func:`device_plants` → :class:`RobustReport` — P(stable), margin
  and bandwidth quantiles of a fixed controller over posterior samples or device variants.
- :func:`fit_loop_gp`, :func:`loop_gp_plants` — draws of the loop ``Q = P P̂⁻¹`` conditioned
  on the whole measured FRF, calibrated where the model class is wrong (the robust check on
  them, with the evidence on the measured FRF, is :func:`hapid.robust.loop_gp_check`).
- :class:`ParamDraws`, :class:`LoopDraws` (:func:`draws_from`) — the two constructions of
  draws of the true plant, one interface (``plants(model, omega, n_draws, seed)``).
- :func:`plant_draws` → :class:`PlantDraws` — draws of the true P on any grid by either
  construction (``params`` or ``loop_gp``), the draws of ``hapid predict``.
- :func:`pose_study` → :class:`PoseStudy` — nominal vs re-identified controller over a grid
  of stylus poses.

Names that need emcee (the sampler and the command that runs it) load on first use (PEP 562):
the loop draws, the robust check and the Laplace posterior do not pay emcee's and
scipy.stats' import.
"""

from .. import _config  # noqa: F401  (float64)
from .._lazy import lazy_names as _lazy_names
from ..samples import PosteriorSamples as PosteriorSamples
from ..samples import SamplesStatus as SamplesStatus
from ._coords import fold_theta as fold_theta
from ._coords import matrix_to_theta as matrix_to_theta
from ._coords import theta_to_matrix as theta_to_matrix
from ._draws import Draws as Draws
from ._draws import LoopDraws as LoopDraws
from ._draws import ParamDraws as ParamDraws
from ._draws import draws_from as draws_from
from ._holdout import HoldoutCheck as HoldoutCheck
from ._holdout import HoldoutStatus as HoldoutStatus
from ._holdout import direction_split as direction_split
from ._holdout import holdout_check as holdout_check
from ._hyper import fix_hyperparameters as fix_hyperparameters
from ._laplace import LaplacePosterior as LaplacePosterior
from ._laplace import ModeStatus as ModeStatus
from ._laplace import laplace_posterior as laplace_posterior
from ._laplace import laplace_samples as laplace_samples
from ._laplace import posterior_laplace_samples as posterior_laplace_samples
from ._likelihood import FixedMatrices as FixedMatrices
from ._likelihood import LogPosterior as LogPosterior
from ._likelihood import batched_log_prob as batched_log_prob
from ._likelihood import boundary_fixed as boundary_fixed
from ._likelihood import param_names as param_names
from ._loopgp import LoopGP as LoopGP
from ._loopgp import fit_loop_gp as fit_loop_gp
from ._loopgp import loop_gp_mean as loop_gp_mean
from ._loopgp import loop_gp_plants as loop_gp_plants
from ._loopgp import measured_data as measured_data
from ._loopgp import measured_loop_gp as measured_loop_gp
from ._loopgp import measured_noise_var as measured_noise_var
from ._mode import check_initial_state as check_initial_state
from ._mode import initial_point as initial_point
from ._model_error import GP as GP
from ._model_error import MODEL_ERRORS as MODEL_ERRORS
from ._model_error import GPCorr as GPCorr
from ._model_error import ModelError as ModelError
from ._model_error import NoError as NoError
from ._model_error import White as White
from ._model_error import model_error_for as model_error_for
from ._model_error import model_error_from as model_error_from
from ._plant_draws import DrawsStatus as DrawsStatus
from ._plant_draws import PlantDraws as PlantDraws
from ._plant_draws import plant_draws as plant_draws
from ._poses import PoseLoop as PoseLoop
from ._poses import PoseRow as PoseRow
from ._poses import PoseStudy as PoseStudy
from ._poses import identify as identify
from ._poses import pose_grid as pose_grid
from ._poses import pose_study as pose_study
from ._posterior import make_log_posterior as make_log_posterior
from ._predictive import QUANTITIES as QUANTITIES
from ._predictive import BandCalibration as BandCalibration
from ._predictive import CalibrationStatus as CalibrationStatus
from ._predictive import CredibleBands as CredibleBands
from ._predictive import PredictivePlants as PredictivePlants
from ._predictive import PredictiveQuantities as PredictiveQuantities
from ._predictive import band_calibration as band_calibration
from ._predictive import credible_bands as credible_bands
from ._predictive import predictive_plants as predictive_plants
from ._predictive import predictive_samples as predictive_samples
from ._recalibrate import Recalibration as Recalibration
from ._recalibrate import recalibration as recalibration
from ._robust import DevicePlants as DevicePlants
from ._robust import RobustReport as RobustReport
from ._robust import device_plants as device_plants
from ._robust import posterior_omega as posterior_omega
from ._robust import robust_check as robust_check
from ._robust import robust_omega as robust_omega

_LAZY = {
    "posterior_from_files": "_files",
    "MOVES": "_sampler",
    "ShortChainWarning": "_sampler",
    "sample_posterior": "_sampler",
}
__all__ = sorted([n for n in globals() if not n.startswith("_")] + list(_LAZY))

__getattr__, __dir__ = _lazy_names(__name__, _LAZY)
