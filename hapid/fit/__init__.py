"""Identification: the paper's WLS baseline, positizing, and PD-constrained nonlinear fits.

- :func:`wls` — paper section 4.2, element-wise weighted least squares (one batched solve);
  :func:`wls_batch_coefficients` — the same for a batch of FRFs on one grid (one fused pass).
- :func:`positize`, :func:`crhp_report` — paper section 5.1 and its root check.
- :func:`fit_nls` — hapid's fit: PSD hand and mechanism matrices (``L Lᵀ``, free-sign
  diagonal), joint Z_H/Z_T residuals, Laplace covariance; the solver an object (an optimistix
  solver, :data:`DEFAULT_SOLVER`, or :class:`JaxoptLM`; a name maps to one in
  :func:`solver_from`).
- :func:`fit_ml` — sample maximum likelihood (errors-in-variables) on a periodic run's
  spectra with their noise covariances; Cramér–Rao bound and its P·P̂⁻¹ band.
- diagnostics — singular values of Z vs Ẑ and of P P̂⁻¹, the paper's band and anisotropy
  reduction.
"""

from .. import _config  # noqa: F401  (float64)
from ._compare import ESTIMATORS as ESTIMATORS
from ._compare import EstimatorFits as EstimatorFits
from ._compare import fit_estimators as fit_estimators
from ._crb import CramerRao as CramerRao
from ._crb import cramer_rao as cramer_rao
from ._crb import crb_band_db as crb_band_db
from ._diagnostics import AnisotropyReduction as AnisotropyReduction
from ._diagnostics import ImpedanceSV as ImpedanceSV
from ._diagnostics import PPhatBand as PPhatBand
from ._diagnostics import anisotropy_reduction as anisotropy_reduction
from ._diagnostics import impedance_singular_values as impedance_singular_values
from ._diagnostics import model_relative_errors as model_relative_errors
from ._diagnostics import pphat as pphat
from ._diagnostics import pphat_band_db as pphat_band_db
from ._diagnostics import pphat_singular_values as pphat_singular_values
from ._jaxopt_adapter import JaxoptLM as JaxoptLM
from ._ml import MLResult as MLResult
from ._ml import fit_ml as fit_ml
from ._ml import ml_cost as ml_cost
from ._ml import run_spectra as run_spectra
from ._nls import LaplaceCovariance as LaplaceCovariance
from ._nls import fit_nls as fit_nls
from ._nls import fit_nls_batch as fit_nls_batch
from ._nls import laplace_covariance as laplace_covariance
from ._nls import nls_cost as nls_cost
from ._pd import MATRIX_NAMES as MATRIX_NAMES
from ._pd import Scale as Scale
from ._pd import boundary_names as boundary_names
from ._pd import boundary_report as boundary_report
from ._pd import canonical_theta as canonical_theta
from ._pd import model_to_theta as model_to_theta
from ._pd import n_params as n_params
from ._pd import project_pd as project_pd
from ._pd import theta_to_model as theta_to_model
from ._physics import CorrectedMBK as CorrectedMBK
from ._physics import correct_exponential as correct_exponential
from ._physics import physics_warnings as physics_warnings
from ._positize import CRHPReport as CRHPReport
from ._positize import CRHPStatus as CRHPStatus
from ._positize import crhp_report as crhp_report
from ._positize import positize as positize
from ._positize import positize_matrix as positize_matrix
from ._problem import WEIGHTS as WEIGHTS
from ._problem import Problem as Problem
from ._problem import data_scale as data_scale
from ._problem import make_problem as make_problem
from ._quality import FitQuality as FitQuality
from ._quality import QualityStatus as QualityStatus
from ._quality import fit_quality as fit_quality
from ._quality import impedance_quality as impedance_quality
from ._quality import pair_quality as pair_quality
from ._result import FitFailedError as FitFailedError
from ._result import FitStatus as FitStatus
from ._result import NLSResult as NLSResult
from ._single import ImpedanceFit as ImpedanceFit
from ._single import fit_impedance as fit_impedance
from ._single import wls_single as wls_single
from ._solvers import DEFAULT_SOLVER as DEFAULT_SOLVER
from ._solvers import LINEAR_SOLVERS as LINEAR_SOLVERS
from ._solvers import SOLVERS as SOLVERS
from ._solvers import solver_from as solver_from
from ._wls import OMEGA_C_PAPER as OMEGA_C_PAPER
from ._wls import paper_weight as paper_weight
from ._wls import wls as wls
from ._wls import wls_batch_coefficients as wls_batch_coefficients
from ._wls import wls_coefficients as wls_coefficients
from ._wls import wls_operator as wls_operator
