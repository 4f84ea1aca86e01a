# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""The model-error term of the likelihood, as strategy objects.

A model error is the part of the measured impedances that no second-order model explains
(delays, chain modes, nonlinearity). Each kind is one frozen object that carries what it
needs — its hyperparameter names and count, their prior, the likelihood's covariance and
how its hyperparameters are fixed — so :class:`~hapid.uncertainty.LogPosterior` holds one
object instead of a kind string and the options valid for it:

==============  ===========  =======================================================
kind            hyper count  covariance of element (i, j)'s residual pair (r_H, r_T)
==============  ===========  =======================================================
:class:`NoError`      0      measurement noise only (the FRF's std, > 0 everywhere)
:class:`White`        2      plus independent relative floors ``(τ_H a_H)², (τ_M a_M)²``
:class:`GP`           8      plus Matérn-5/2 GPs in warped log-frequency (τ, ℓ, β, κ)
:class:`GPCorr`      10      plus a hand/mechanism correlation ρ (the CLI's default)
==============  ===========  =======================================================

``a_H(ω)``, ``a_M(ω)`` are the RMS element sizes of the measured hand and mechanism
impedances (scaled units), so τ is a relative RMS element error. The covariances are those
of :mod:`hapid.uncertainty._gp`; the module docstring of
:mod:`hapid.uncertainty._likelihood` gives the likelihood they enter.

Each object also draws its term on a new frequency grid given a posterior draw's fit
residuals (:meth:`ModelError.predictive_errors`, the conditional behind
:func:`~hapid.uncertainty.predictive_plants`; computations in
:mod:`hapid.uncertainty._conditional`).

The CLI's ``--model-error`` / ``--gp-hyper`` / ``--error-scale`` flags map to these objects
in one place, :func:`model_error_from`; the kind a samples file stores
(:attr:`~hapid.samples.PosteriorSamples.error_kind`) in one place, :func:`model_error_for`.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from ..samples import PosteriorSamples
from ._conditional import gp_corr_errors, gp_errors, white_errors
from ._gp import (
    _JITTER,
    N_GP_CORR_HYPER,
    N_GP_HYPER,
    gp_complex_log_likelihood,
    gp_corr_covariance,
    gp_covariance,
    gp_log_likelihood,
)

TAU_NAMES = ("log_tau_H", "log_tau_M")
ELL_NAMES = ("log_ell_H", "log_ell_M")
SLOPE_NAMES = ("beta_H", "beta_M")
WARP_NAMES = ("kappa_H", "kappa_M")
RHO_NAMES = ("rho_re", "rho_im")  # unconstrained coordinates z of ρ = tanh|z| z/|z|
DEFAULT_LOG_TAU_MEAN = float(np.log(0.03))
DEFAULT_LOG_TAU_SD = 2.0
DEFAULT_LOG_ELL_MEAN = float(np.log(0.5))  # length scale in natural-log frequency units
DEFAULT_LOG_ELL_SD = 1.0
DEFAULT_BETA_SD = 1.0  # prior sd of the amplitude slopes β (per e-fold of frequency)
DEFAULT_KAPPA_SD = 1.0  # prior sd of the frequency warps κ (mean 0: log-frequency)
DEFAULT_RHO_SD = 1.0  # prior sd of each of the two ρ coordinates (mean 0: independent)
HYPER_FIXINGS = ("map", "marginal", "sample")
ERROR_SCALES = ("shared", "element")


def _normal(lp, z, sd):
    """``lp`` plus the log-density of two independent ``N(0, sd²)`` standardized values ``z``."""
    return lp - 0.5 * jnp.sum(z**2) - 2 * np.log(sd * np.sqrt(2 * np.pi))


@dataclasses.dataclass(frozen=True)
class ModelError:
    """Base of the model-error strategies (not used on its own)."""

    name: ClassVar[str] = ""
    hyper_names: ClassVar[tuple[str, ...]] = ()

    @property
    def n_hyper(self) -> int:
        """Model-error coordinates sampled after θ (when not fixed)."""
        return len(self.hyper_names)

    def hyper_mean(self) -> np.ndarray:
        """Prior means of the hyperparameters ``(n_hyper,)``."""
        return np.zeros(0)

    def log_prior(self, lp, h):
        """``lp`` plus the log prior density of the hyperparameters ``h`` ``(n_hyper,)``."""
        return lp

    def log_likelihood(self, post, reH, imH, reT, imT, h):
        """Log-likelihood of the residuals (each ``(N, n, n)``, scaled units; real and
        imaginary parts of ``r_H = Ẑ_H − Z_H`` and ``r_T``) under the data of ``post`` (a
        :class:`~hapid.uncertainty.LogPosterior`) and hyperparameters ``h``."""
        return _independent_log_likelihood(post, 0.0, 0.0, reH, imH, reT, imT)

    def predictive_errors(self, ps: PosteriorSamples, idx, models, omega, rng, weight=None):
        """Draws ``(e_H, e_M)`` of this model-error term on ``omega (N,)`` rad/s given each
        posterior draw's fit residuals: the errors of the hand and of the mechanism impedance,
        each ``(S, N, n, n)`` complex (N/m; ``Z_T`` carries ``e_H + e_M``).

        ``ps``: samples of this kind whose ``predictive`` holds the fit data; ``idx (S,)``:
        the draws used; ``models``: their batched models (``(S, …)``, physical units);
        ``rng``: a numpy ``Generator`` (the draws' randomness); ``weight (N,)``: a factor on
        the error term per frequency (a taper; None = 1). Without model error: zeros."""
        z = np.zeros((len(idx), np.shape(omega)[0], ps.n, ps.n), complex)
        return z, z.copy()


def _independent_log_likelihood(post, vH, vM, reH, imH, reT, imT):
    """Residual pairs independent across elements and frequencies, each with the real 2 × 2
    covariance ``[[s_H² + v_H, ρ s_H s_T + v_H], [·, s_T² + v_H + v_M]]``."""
    sH2, sT2 = post.var_H, post.var_T
    jit = _JITTER * ((post.a_H + post.a_M) ** 2)[:, None, None]
    c11 = sH2 + vH + jit
    c22 = sT2 + vH + vM + jit
    c12 = post.noise_corr * jnp.sqrt(sH2 * sT2) + vH
    det = c11 * c22 - c12**2
    quad = (
        c22 * (reH**2 + imH**2) - 2.0 * c12 * (reH * reT + imH * imT) + c11 * (reT**2 + imT**2)
    ) / det
    return -jnp.sum(quad) - jnp.sum(jnp.log(det)) - 2.0 * np.log(np.pi) * det.size


@dataclasses.dataclass(frozen=True)
class NoError(ModelError):
    """No model error: the residuals are the FRF's measurement noise alone, so its std must
    be > 0 at every band frequency."""

    name: ClassVar[str] = "none"


@dataclasses.dataclass(frozen=True)
class White(ModelError):
    """Relative model-error floors independent per frequency: variances ``(τ_H a_H(ω))²`` of
    the hand and ``(τ_M a_M(ω))²`` of the mechanism; prior ``log τ ~ N(log_tau_mean,
    log_tau_sd²)`` (default median 0.03, sd 2)."""

    name: ClassVar[str] = "white"
    hyper_names: ClassVar[tuple[str, ...]] = TAU_NAMES
    log_tau_mean: float = DEFAULT_LOG_TAU_MEAN
    log_tau_sd: float = DEFAULT_LOG_TAU_SD

    def __post_init__(self):
        if not (self.log_tau_sd > 0 and np.isfinite(self.log_tau_mean)):
            raise ValueError("log_tau_sd must be > 0 and log_tau_mean finite")

    def hyper_mean(self) -> np.ndarray:
        return np.array([self.log_tau_mean] * 2)

    def log_prior(self, lp, h):
        return _normal(lp, (h[:2] - self.log_tau_mean) / self.log_tau_sd, self.log_tau_sd)

    def log_likelihood(self, post, reH, imH, reT, imT, h):
        tau = jnp.exp(h)
        vH = ((tau[0] * post.a_H) ** 2)[:, None, None]
        vM = ((tau[1] * post.a_M) ** 2)[:, None, None]
        return _independent_log_likelihood(post, vH, vM, reH, imH, reT, imT)

    def predictive_errors(self, ps: PosteriorSamples, idx, models, omega, rng, weight=None):
        """Independent circular errors of variance ``(τ a(ω))²`` at each frequency (``a`` log-log
        interpolated from the fit band, constant beyond it): no correlation to condition on.
        Contract: :meth:`ModelError.predictive_errors`."""
        return white_errors(ps, idx, omega, rng, weight)


@dataclasses.dataclass(frozen=True)
class GP(White):
    """The model error of each element a smooth random function of frequency: a Matérn-5/2
    Gaussian process in Box–Cox-warped log-frequency, amplitudes ``τ a(ω) e^{β u}`` with the
    data's RMS element sizes inside the fit band and the reference model's outside it,
    length scales ℓ (prior ``log ℓ ~ N(log_ell_mean, log_ell_sd²)``), slopes ``β ~ N(0, 1)``
    and warps ``κ ~ N(0, 1)``; marginalized in closed form (:func:`~hapid.uncertainty._gp.
    gp_covariance`). Hand and mechanism errors independent.

    ``hyper``: how the hyperparameters are fixed before sampling θ
    (:func:`~hapid.uncertainty.fix_hyperparameters`): ``"map"`` (default; at the joint
    posterior mode from the NLS start), ``"sample"`` (sampled with θ), or the numbers
    (6 or 8; κ may be left out).
    """

    name: ClassVar[str] = "gp"
    hyper_names: ClassVar[tuple[str, ...]] = TAU_NAMES + ELL_NAMES + SLOPE_NAMES + WARP_NAMES
    log_ell_mean: float = DEFAULT_LOG_ELL_MEAN
    log_ell_sd: float = DEFAULT_LOG_ELL_SD
    hyper: str | tuple[float, ...] = "map"

    def __post_init__(self):
        super().__post_init__()
        if not (self.log_ell_sd > 0 and np.isfinite(self.log_ell_mean)):
            raise ValueError("log_ell_sd must be > 0 and log_ell_mean finite")
        if isinstance(self.hyper, str):
            if self.hyper not in self._fixings():
                raise ValueError(f"{type(self).__name__}.hyper must be one of {self._fixings()} "
                                 f"or numbers, got {self.hyper!r}")  # fmt: skip
        else:
            h = tuple(float(v) for v in np.ravel(np.asarray(self.hyper, dtype=np.float64)))
            if not all(np.isfinite(h)):
                raise ValueError(f"{type(self).__name__}.hyper contains NaN or inf")
            object.__setattr__(self, "hyper", h)

    def _fixings(self) -> tuple[str, ...]:
        return ("map", "sample")

    def hyper_mean(self) -> np.ndarray:
        extra = [self.log_ell_mean] * 2 + [0.0] * (self.n_hyper - 4)
        return np.array([self.log_tau_mean] * 2 + extra)

    def log_prior(self, lp, h):
        lp = super().log_prior(lp, h)
        lp = _normal(lp, (h[2:4] - self.log_ell_mean) / self.log_ell_sd, self.log_ell_sd)
        for lo, sd in ((4, DEFAULT_BETA_SD), (6, DEFAULT_KAPPA_SD)):
            lp = _normal(lp, h[lo : lo + 2] / sd, sd)
        return lp

    def log_likelihood(self, post, reH, imH, reT, imT, h):
        w = jnp.imag(post.s)
        C = gp_covariance(jnp.log(w), post.a_H, post.a_M, post.var_H, post.var_T,
                          post.noise_corr, h)  # fmt: skip
        return gp_log_likelihood(reH, imH, reT, imT, C)

    def predictive_errors(self, ps: PosteriorSamples, idx, models, omega, rng, weight=None):
        """The exact GP conditional on each draw's fit residuals (pathwise, Matheron's rule;
        far from the fit band it reverts to the prior, amplitude ``τ a(ω)`` with the slope
        held at its band-edge value). Contract: :meth:`ModelError.predictive_errors`."""
        return _weighted(gp_errors(ps, idx, models, omega, rng), weight)


@dataclasses.dataclass(frozen=True)
class GPCorr(GP):
    """:class:`GP` with the hand and mechanism errors of each element correlated through a
    shared latent function (complex correlation ρ, prior ``N(0, 1)`` on its two coordinates),
    in the frequency coordinate ``asinh(ω/ω_c)`` (the κ slots hold ``log(ω_c/ω_ref)``):
    :func:`~hapid.uncertainty._gp.gp_corr_covariance`. ``hapid posterior``'s default.

    ``hyper``: ``"marginal"`` (default; the mode of the hyperparameters' marginal posterior,
    the matrices integrated out: :func:`~hapid.uncertainty._hyper.marginal_hyper`), ``"map"``,
    ``"sample"``, or the numbers (6, 8 or 10).
    ``scale``: ``"shared"`` (default; every element's error has the amplitude ``τ a(ω)``) or
    ``"element"`` (element (i, j)'s amplitude weighted by the reference model's element size:
    :func:`~hapid.uncertainty._weights.element_weights`).
    """

    name: ClassVar[str] = "gp_corr"
    hyper_names: ClassVar[tuple[str, ...]] = GP.hyper_names + RHO_NAMES
    hyper: str | tuple[float, ...] = "marginal"
    scale: str = "shared"

    def __post_init__(self):
        super().__post_init__()
        if self.scale not in ERROR_SCALES:
            raise ValueError(f"GPCorr.scale must be one of {ERROR_SCALES}, got {self.scale!r}")

    def _fixings(self) -> tuple[str, ...]:
        return HYPER_FIXINGS

    def log_prior(self, lp, h):
        lp = super().log_prior(lp, h)
        return _normal(lp, h[N_GP_HYPER:N_GP_CORR_HYPER] / DEFAULT_RHO_SD, DEFAULT_RHO_SD)

    def log_likelihood(self, post, reH, imH, reT, imT, h):
        w = jnp.imag(post.s)
        aH, aM = post.error_amplitudes()
        C = gp_corr_covariance(jnp.log(w), aH, aM, post.var_H, post.var_T, post.noise_corr, h)
        return gp_complex_log_likelihood(reH + 1j * imH, reT + 1j * imT, C)

    def predictive_errors(self, ps: PosteriorSamples, idx, models, omega, rng, weight=None):
        """The exact conditional of the correlated model on each draw's fit residuals, in
        complex circular form (amplitudes per element when ``scale == "element"``). Contract:
        :meth:`ModelError.predictive_errors`."""
        draws = gp_corr_errors(ps, idx, models, omega, rng, element=self.scale == "element")
        return _weighted(draws, weight)


def _weighted(draws, weight):
    """``(e_H, e_M)`` each multiplied by ``weight (N,)`` along frequency (None: unchanged)."""
    if weight is None:
        return draws
    w = np.asarray(weight)[None, :, None, None]
    return draws[0] * w, draws[1] * w


MODEL_ERRORS: dict[str, type[ModelError]] = {c.name: c for c in (NoError, White, GP, GPCorr)}
"""The model-error kinds by the name the CLI and the samples files use."""


def model_error_from(name: str, *, gp_hyper: str | None = None,
                     error_scale: str | None = None) -> ModelError:  # fmt: skip
    """The model-error object of the CLI's ``--model-error NAME`` (one of
    :data:`MODEL_ERRORS`), ``--gp-hyper`` (GP kinds; None = the kind's default) and
    ``--error-scale`` (gp_corr; None = shared). Raises ``ValueError`` naming a bad or
    inapplicable option."""
    if name not in MODEL_ERRORS:
        raise ValueError(f"model error must be one of {tuple(MODEL_ERRORS)}, got {name!r}")
    cls = MODEL_ERRORS[name]
    kw = {}
    if gp_hyper is not None:
        if not issubclass(cls, GP):
            raise ValueError(f"gp_hyper applies to the gp kinds, not to model error {name!r}")
        if gp_hyper == "marginal" and cls is GP:
            raise ValueError("gp_hyper 'marginal' applies to model error 'gp_corr' (its marginal "
                             "mode is that model's); use 'map' or 'sample' with 'gp'")  # fmt: skip
        kw["hyper"] = gp_hyper
    if error_scale is not None:
        if cls is not GPCorr:
            raise ValueError(f"error_scale applies to model error 'gp_corr', not {name!r}")
        kw["scale"] = error_scale
    return cls(**kw)


def model_error_for(samples: PosteriorSamples) -> ModelError:
    """The model-error object of posterior samples: the class of their kind
    (:attr:`~hapid.samples.PosteriorSamples.error_kind`, read from the number of model-error
    columns) with, for gp_corr, the ``scale`` their fit data records (``"shared"`` when
    absent). Prior settings and ``hyper`` take the class defaults: the samples carry the
    hyperparameter draws themselves."""
    cls = MODEL_ERRORS[samples.error_kind]
    if cls is GPCorr and samples.predictive is not None:
        return GPCorr(scale=str(samples.predictive.get("error_scale", "shared")))
    return cls()


def as_model_error(model_error) -> ModelError:
    """``model_error`` if it is a :class:`ModelError`; ``ValueError`` otherwise, naming the
    objects (the library takes objects; strings are the CLI's, :func:`model_error_from`)."""
    if isinstance(model_error, ModelError) and type(model_error) is not ModelError:
        return model_error
    raise ValueError(
        "model_error must be a model-error object — NoError(), White(), GP() or GPCorr() "
        f"from hapid.uncertainty — got {model_error!r} (for a CLI name use model_error_from)"
    )
