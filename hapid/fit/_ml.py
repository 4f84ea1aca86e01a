# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""Frequency-domain (sample) maximum likelihood: errors-in-variables fit of a periodic run.

Every other hapid estimator fits the empirical FRF ``Z = −𝓡 𝓛⁻¹``; when the displacement
𝓛 is noisy that FRF is biased (the inverse of a noisy matrix), and weighting it by its own
std does not remove the bias. Following Pintelon & Schoukens (*System Identification: A
Frequency Domain Approach*, the "sample maximum likelihood" of FDIDENT/ELiS), ``fit_ml``
fits the PD-constrained model of :func:`~hapid.fit.fit_nls` to the *spectra* of the run.

Data (per excited frequency ``k`` ≤ ``f_max_hz``, experiment ``e``, period ``p``): the DFT
amplitudes of ``x = [R_I; R_A; L]`` (``3n``), averaged over the ``P`` periods (``x̄_ke``),
and the sample covariance of one period's ``x`` pooled over the experiments
(``ν = E(P − 1)`` degrees of freedom: the sensor noise does not depend on the pattern),
``C_k = Σ_{e,p} (x − x̄)(x − x̄)ᴴ / ν``; the covariance of the average is ``C_k / P``.

Residual (the paper's equations ``R_I = −Z_H L``, ``R_A = −Z_T L``)::

    e_ke = [R̄_I + Ẑ_H L̄ ; R̄_A + Ẑ_T L̄] = A_k(θ) x̄_ke,   A_k = [[I, 0, Ẑ_H], [0, I, Ẑ_T]]

Its covariance is ``S_k(θ) = A_k C_k A_kᴴ / P`` — it depends on the model: the input (𝓛)
noise enters through ``Ẑ C_L Ẑᴴ`` with the cross terms ``C_RL Ẑᴴ + Ẑ C_LR``, and the
``Z_H`` and ``Z_T`` equations are correlated through their common 𝓛. The cost is

    V(θ) = Σ_k Σ_e e_keᴴ S_k(θ)⁻¹ e_ke

with **no** log-det term: with the noise covariances given (here: their sample estimates),
eliminating the unknown noise-free spectra from the Gaussian errors-in-variables likelihood
leaves exactly this weighted sum (Pintelon & Schoukens, ch. 7 and 10; sample ML when the
covariances are estimated from periods). It is minimized by Levenberg–Marquardt on the
whitened residual ``r = √2 W_k⁻¹ e_ke`` (``W_k W_kᴴ = S_k``, Cholesky, unrolled; real and imaginary
parts stacked), so ``½‖r‖² = V`` and each real residual has unit variance at the truth.

Two floors keep ``S_k`` positive definite:

- encoder quantization: when every sample of ``L`` is a multiple of one step ``q``, a
  uniform quantization error (``q²/12`` per sample, i.e. ``q²/(3 T_p)`` per DFT bin) is added
  to the 𝓛 block. It repeats every period, so the period-to-period scatter cannot see it;
  without it a run with exact commands ``R_A`` and no encoder noise would claim an exactly
  known ``Z_T``.
- ``model_floor`` φ: ``φ²·mean_e |x̄_R|²`` per frequency on the ``R_I`` and ``R_A`` blocks (an
  equation error relative to the force spectra). φ = 0 is the pure ML (for data the
  second-order model can describe); a device with unmodeled dynamics (cu5's sensor
  compliance and extra modes) violates the model by more than the noise and a small φ keeps
  the high-SNR frequencies from dominating. As φ → ∞ the fit becomes an equation-error fit
  weighted by force power.

Uncertainty: the Fisher information ``F = JᵀJ`` of the whitened residual with the weighting
held at ``θ̂`` (the derivative of ``S(θ)`` multiplies the zero-mean ``e`` and drops out of
the expected information). ``crb = F⁺`` (with φ = 0, in symmetric-matrix coordinates, where
the model is linear) is the Cramér–Rao bound of the fitted model at the data's noise level (estimated: measured 𝓛 in place of the noise-free one,
sample covariances); ``covariance = max(1, σ̂²)·F_φ⁺`` (information of the cost as fitted,
with its floor) with ``σ̂² = 2V/(m − p)`` (≫ 1 signals model error, which inflates the
Laplace covariance rather than being hidden).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from ..defaults import FIT_BAND_HZ, NLS_MAX_STEPS
from ..experiment import Run, estimate_frf
from ..experiment._estimate import _dft_bins
from ..experiment._protocol import validate_run
from ..frf import FRF
from ..impedance import ImpedanceModel
from ._checks import TWO_PI
from ._nls import final_status, fit_nls, init_model, pinv_psd
from ._pd import (
    Scale,
    boundary_report,
    model_to_theta,
    scaled_pair,
    theta_to_model,
    theta_to_scaled,
)
from ._problem import PD_EPS, data_scale
from ._result import NLSResult
from ._solvers import (
    DEFAULT_SOLVER,
    Solver,
    check_solver,
    run_solver,
    solver_name,
    with_array_tolerances,
)

#: relative variance always added to S_k (numerical safety: noise-free data): a floor of
#: ``REL_JITTER × force power`` on the equations and ``× trace(S)/2n`` on the diagonal.
REL_JITTER = 1e-12


class RunSpectra(eqx.Module):
    """Period-averaged spectra and pooled noise covariance of a periodic run.

    - ``omega`` ``(K,)`` rad/s: the excited frequencies kept (≤ ``f_max_hz``).
    - ``X`` ``(K, E, 3n)`` complex: period means of ``[R_I (N); R_A (N); L (m)]``, scaled so
      a cosine of amplitude ``a`` has ``|X| = a``.
    - ``C`` ``(K, 3n, 3n)`` complex: covariance of ``X`` (of the *mean* over periods),
      pooled over experiments, plus the quantization floor on the ``L`` block.
    - ``n_periods`` P, ``dof`` ν = E(P − 1), ``q`` encoder step found in ``L`` (m, 0 = none).
    """

    omega: Float[Array, " K"]
    X: Complex[Array, "K E m"]
    C: Complex[Array, "K m m"]
    n_periods: int = eqx.field(static=True)
    dof: int = eqx.field(static=True)
    q: float = eqx.field(static=True)

    @property
    def n(self) -> int:
        return int(self.X.shape[-1] // 3)


def _quantization_step(L: np.ndarray) -> float:
    """The step ``q`` when every sample of ``L`` is an integer multiple of it, else 0."""
    v = np.unique(np.abs(L.ravel()))
    d = np.diff(v)
    d = d[d > 0]
    if d.size == 0:
        return 0.0
    q = float(d.min())
    k = L / q
    if q > 0 and np.all(np.abs(k - np.round(k)) < 1e-6):
        return q
    return 0.0


def run_spectra(
    run: Run, f_max_hz: float | None = FIT_BAND_HZ, f_min_hz: float = 0.0
) -> RunSpectra:
    """:class:`RunSpectra` of ``run`` at its excited frequencies in ``[f_min_hz, f_max_hz]``.

    Needs ``P ≥ 2`` periods (the covariance is estimated from their scatter).
    """
    validate_run(run)
    Tp, (E, _, n), P = run.period_samples, run.R_A.shape, run.n_periods
    if P < 2:
        raise ValueError(
            f"fit_ml: the run has {P} period; the noise covariance is estimated from the "
            "period-to-period scatter, which needs ≥ 2 periods (4 or more recommended)"
        )
    f = np.asarray(run.freq_hz, dtype=float)
    keep = np.ones(f.shape, bool) if f_max_hz is None else f <= f_max_hz * (1 + 1e-12)
    keep &= f >= f_min_hz * (1 - 1e-12)
    if keep.sum() < 3:
        raise ValueError(
            f"fit_ml: only {int(keep.sum())} excited frequencies ≤ f_max_hz={f_max_hz} Hz; "
            "a second-order fit needs at least 3"
        )
    bins = np.round(f[keep] * Tp / run.fs_hz).astype(int)
    sig = np.concatenate([run.R_I, run.R_A, run.L], axis=-1)  # (E, P·Tp, 3n)
    S = _dft_bins(sig.reshape(E, P, Tp, 3 * n), bins, Tp)  # (E, P, K, 3n)
    Xbar = S.mean(axis=1)  # (E, K, 3n)
    D = S - Xbar[:, None]
    dof = E * (P - 1)
    C = np.einsum("epki,epkj->kij", D, D.conj()) / dof / P  # covariance of the mean
    q = _quantization_step(np.asarray(run.L))
    if q > 0:
        var = q**2 / (3.0 * Tp)  # E|DFT|² of a uniform ±q/2 error, white, 2/Tp scaling
        idx = np.arange(2 * n, 3 * n)
        C[:, idx, idx] += var
    return RunSpectra(
        omega=jnp.asarray(TWO_PI * f[keep]),
        X=jnp.asarray(np.transpose(Xbar, (1, 0, 2))),
        C=jnp.asarray(C),
        n_periods=int(P),
        dof=int(dof),
        q=float(q),
    )


def _inverse_cholesky(S):
    """``W⁻¹`` (lower triangular) of the Cholesky factor ``W Wᴴ = S`` for a batch of small
    Hermitian PD matrices ``(..., m, m)``, unrolled in elementary ops.

    XLA:CPU's batched ``triangular_solve`` (and LU ``solve``) under ``jacfwd`` is slow
    (benchmarks/README.md): forward-mode tangents become extra batch columns that the LAPACK
    custom call handles one by one.
    ``m = 2n`` is small, so a column-by-column Cholesky and forward substitution are cheap.
    """
    m = S.shape[-1]
    cols = []  # columns of W
    for j in range(m):
        if j:
            Lp = jnp.stack(cols, axis=-1)  # (..., m, j)
            v = S[..., :, j] - jnp.einsum("...ik,...k->...i", Lp, jnp.conj(Lp[..., j, :]))
        else:
            v = S[..., :, j]
        d = jnp.sqrt(jnp.real(v[..., j]))
        mask = (jnp.arange(m) >= j).astype(S.dtype)
        cols.append(mask * v / d[..., None])
    W = jnp.stack(cols, axis=-1)
    rows = []  # rows of T = W⁻¹: T[i] = (e_i − Σ_{k<i} W[i, k] T[k]) / W[i, i]
    eye = jnp.eye(m, dtype=S.dtype)
    for i in range(m):
        acc = jnp.broadcast_to(eye[i], S.shape[:-2] + (m,))
        if i:
            Tp = jnp.stack(rows, axis=-2)  # (..., i, m)
            acc = acc - jnp.einsum("...k,...km->...m", W[..., i, :i], Tp)
        rows.append(acc / W[..., i, i][..., None])
    return jnp.stack(rows, axis=-2)


class MLProblem(eqx.Module):
    """The whitened errors-in-variables residual ``r(θ)`` of a run (module docstring).

    Stored in scaled units: forces divided by ``scale.z_ref`` (so ``R/z_ref`` is in m like
    ``L``), ``s = jω/ω_ref``.
    """

    s: Complex[Array, " K"]
    X: Complex[Array, "K E m"]  # [R_I/z; R_A/z; L]
    C: Complex[Array, "K m m"]  # covariance of X (scaled), floors included
    F: Float[Array, "K q"]  # model floor variances on the 2n equations (scaled)
    scale: Scale
    eps: Array

    @property
    def n(self) -> int:
        return int(self.X.shape[-1] // 3)

    def model_arrays(self, theta):
        return scaled_pair(theta_to_scaled(theta, self.n, self.eps), self.s)

    def _A(self, theta):
        n = self.n
        ZH, ZT = self.model_arrays(theta)
        K = ZH.shape[0]
        eye = jnp.broadcast_to(jnp.eye(2 * n, dtype=ZH.dtype), (K, 2 * n, 2 * n))
        return jnp.concatenate([eye, jnp.concatenate([ZH, ZT], axis=-2)], axis=-1)  # (K, 2n, 3n)

    def errors(self, theta):
        """Equation errors ``e`` ``(K, 2n, E)`` (scaled: metres)."""
        return self._A(theta) @ jnp.swapaxes(self.X, -1, -2)

    def weight_factor(self, theta):
        """Whitening matrix ``T_k = W_k⁻¹`` ``(K, 2n, 2n)``, ``W_k W_kᴴ = S_k(θ) = A C Aᴴ + diag(F)``."""
        A = self._A(theta)
        S = A @ self.C @ jnp.conj(jnp.swapaxes(A, -1, -2))
        S = 0.5 * (S + jnp.conj(jnp.swapaxes(S, -1, -2)))
        d = self.F + REL_JITTER * jnp.real(jnp.trace(S, axis1=-2, axis2=-1))[:, None] / S.shape[-1]
        S = S + jax.vmap(jnp.diag)(d)
        return _inverse_cholesky(S)

    def whiten(self, theta, T):
        e = self.errors(theta)
        r = np.sqrt(2.0) * (T @ e)
        return jnp.concatenate([jnp.real(r).ravel(), jnp.imag(r).ravel()])

    def __call__(self, theta: Float[Array, " p"], args=None) -> Float[Array, " m"]:
        return self.whiten(theta, self.weight_factor(theta))

    def cost(self, theta: Float[Array, " p"], args=None) -> Float[Array, ""]:
        """``V(θ) = ½‖r(θ)‖² = Σ eᴴ S(θ)⁻¹ e``."""
        r = self(theta)
        return 0.5 * jnp.sum(r**2)

    @property
    def n_residuals(self) -> int:
        K, E, m = self.X.shape
        return 2 * K * E * (2 * m // 3)

    def fisher_matrices(self, theta):
        """``JᵀJ`` in symmetric-matrix coordinates at ``θ`` (weighting held there).

        Coordinates: the ``n(n+1)/2`` lower-triangle entries of each of the six scaled
        matrices (order of ``MATRIX_NAMES``) — the model is linear in them, so this is the
        information of an unconstrained ``M, B, K`` estimate, well defined also where a
        fitted matrix sits on the PSD boundary (where the Cholesky coordinates are singular).
        """
        T = jax.lax.stop_gradient(self.weight_factor(theta))
        mats0 = theta_to_scaled(theta, self.n, self.eps)
        v0 = _sym_to_vec(mats0)
        J = jax.jacfwd(lambda v: self._whiten_mats(_vec_to_sym(v, self.n), T))(v0)
        return J.T @ J

    def _whiten_mats(self, mats, T):
        ZH, ZT = scaled_pair(mats, self.s)
        K = ZH.shape[0]
        n = self.n
        eye = jnp.broadcast_to(jnp.eye(2 * n, dtype=ZH.dtype), (K, 2 * n, 2 * n))
        A = jnp.concatenate([eye, jnp.concatenate([ZH, ZT], axis=-2)], axis=-1)
        r = np.sqrt(2.0) * (T @ (A @ jnp.swapaxes(self.X, -1, -2)))
        return jnp.concatenate([jnp.real(r).ravel(), jnp.imag(r).ravel()])

    def fisher(self, theta):
        """``JᵀJ`` with the weighting held at ``θ`` (expected information)."""
        T = jax.lax.stop_gradient(self.weight_factor(theta))
        J = jax.jacfwd(lambda t: self.whiten(t, T))(theta)
        return J.T @ J


def _sym_to_vec(mats):
    n = mats.shape[-1]
    rows, cols = np.tril_indices(n)
    return mats[:, rows, cols].reshape(-1)


def _vec_to_sym(v, n):
    rows, cols = np.tril_indices(n)
    t = len(rows)
    L = jnp.zeros((6, n, n), dtype=v.dtype).at[:, rows, cols].set(v.reshape(6, t))
    return L + jnp.swapaxes(L, -1, -2) - L * jnp.eye(n)


def make_ml_problem(
    spectra: RunSpectra, scale: Scale, *, model_floor: float = 0.0, pd_eps: float = 0.0
) -> MLProblem:
    """The :class:`MLProblem` of run spectra in ``scale`` units (see :func:`fit_ml`)."""
    n = spectra.n
    zr = scale.z_ref
    unit = jnp.concatenate([jnp.full(2 * n, 1.0 / zr), jnp.ones(n)])
    X = spectra.X * unit
    C = spectra.C * unit[:, None] * unit[None, :]
    XR = X[..., : 2 * n]  # (K, E, 2n)
    pw_H = jnp.mean(jnp.abs(XR[..., :n]) ** 2, axis=(1, 2))
    pw_T = jnp.mean(jnp.abs(XR[..., n:]) ** 2, axis=(1, 2))
    F = (model_floor**2 + REL_JITTER) * jnp.concatenate(
        [jnp.repeat(pw_H[:, None], n, 1), jnp.repeat(pw_T[:, None], n, 1)], axis=1
    )
    return MLProblem(
        s=1j * spectra.omega / scale.omega_ref,
        X=X,
        C=C,
        F=F,
        scale=scale,
        eps=jnp.asarray(pd_eps, dtype=float),
    )


class MLResult(NLSResult):
    """:class:`NLSResult` of :func:`fit_ml`, plus the Cramér–Rao bound.

    - ``cost``: ``V(θ̂) = Σ eᴴ S⁻¹ e`` (≈ ``m/2`` real residuals' worth at the truth).
    - ``crb``: ``(p, p)`` Cramér–Rao bound at ``θ̂`` from the measurement noise alone
      (``model_floor`` = 0): what the data allow — in symmetric-*matrix* coordinates (the
      lower-triangle entries of the six scaled matrices, order ``MATRIX_NAMES``; see
      :meth:`MLProblem.fisher_matrices`), not in ``theta``'s Cholesky coordinates.
    - ``covariance``: ``max(1, sigma2)·F_φ⁺`` with the information ``F_φ`` of the cost as
      fitted (with the ``model_floor``) and ``sigma2 = 2V/(m − p)``.
    - ``dof``: ν = E(P − 1) degrees of freedom of the sample covariances.
    """

    crb: Float[Array, "p p"]
    dof: int = eqx.field(static=True)


@eqx.filter_jit
def _ml_core(problem: MLProblem, noise_only: MLProblem, theta0, dyn):
    theta, n_steps, code = run_solver(problem, theta0, dyn["solver"], dyn["max_steps"],
                                      dyn["ftol"], dyn["patience"])  # fmt: skip
    cost = problem.cost(theta)
    fisher_inv = pinv_psd(problem.fisher(theta))
    crb = pinv_psd(noise_only.fisher_matrices(theta))
    p = theta.shape[-1]
    sigma2 = 2.0 * cost / jnp.maximum(problem.n_residuals - p, 1)
    code = final_status(theta, cost, code)
    return theta, n_steps, code, cost, crb, sigma2, fisher_inv


def fit_ml(
    run: Run,
    init: ImpedanceModel | NLSResult | None = None,
    *,
    f_max_hz: float | None = FIT_BAND_HZ,
    f_min_hz: float = 0.0,
    model_floor: float = 0.0,
    solver: Solver = DEFAULT_SOLVER,
    max_steps: int = NLS_MAX_STEPS,
    ftol: float = 1e-8,
    patience: int = 20,
    pd_eps: float = PD_EPS,
    init_floor: float = 1e-6,
    boundary_rtol: float = 1e-6,
) -> MLResult:
    """Sample maximum-likelihood (errors-in-variables) fit of PSD hand and mechanism M, B, K.

    Arguments:
    - ``run``: a periodic :class:`~hapid.experiment.Run` (signals ``(E, P·T_p, n)``, ≥ 2
      periods) — the spectra and their noise covariances come from it. An FRF is not
      enough (it has lost the input noise): ``ValueError``.
    - ``init``: starting model; default ``fit_nls(estimate_frf(run), f_max_hz=f_max_hz)``.
    - ``f_max_hz``, ``f_min_hz``: only excited frequencies in this band enter (Hz;
      ``f_max_hz=None``: no upper edge). The start and the scale use the FRF up to ``f_max_hz``.
    - ``model_floor``: relative equation-error floor φ (module docstring; 0 = pure ML).
    - ``solver``: an optimistix least-squares solver or minimiser, as
      :func:`~hapid.fit.fit_nls` (default :data:`~hapid.fit.DEFAULT_SOLVER`; not
      :class:`~hapid.fit.JaxoptLM`); ``max_steps``, ``ftol``, ``patience``: as
      :func:`~hapid.fit.fit_nls`.
    - ``pd_eps``: ``pd_eps·I`` (scaled units, default 1e-3) added to every matrix: strictly
      PD, so a matrix the fit drives to the PSD boundary (a soft direction of the hand) does
      not put a root of det Ẑ at s = 0 or ∞ (closed RHP; docs/robust-design.md, Evidence E12).
    - ``init_floor``, ``boundary_rtol``: as :func:`~hapid.fit.fit_nls`.

    Returns an :class:`MLResult` (``weight == "ml"``): ``status`` converged / max_steps /
    failed, ``cost`` V(θ̂), ``crb`` and ``covariance`` of ``theta`` (in ``scale`` units).
    Raises ``ValueError`` for an FRF or other non-run data, a solver not of those kinds,
    ``max_steps`` not a positive int or a negative or non-finite ``model_floor``.
    """
    if isinstance(run, FRF):
        raise ValueError(
            "fit_ml needs the run (per-experiment, per-period signals R_A, R_I, L), not an "
            "FRF: the FRF has already inverted the noisy 𝓛 and lost the noise covariances; "
            "pass the run file (hapid simulate --out run.npz) instead"
        )
    if not isinstance(run, Run):
        raise ValueError(f"fit_ml: expected a Run, got {type(run).__name__}")
    check_solver(solver, "fit_ml", jaxopt=False)
    if not (isinstance(max_steps, int) and max_steps > 0):
        raise ValueError(f"fit_ml: max_steps must be a positive int, got {max_steps!r}")
    if not (np.isfinite(model_floor) and model_floor >= 0):
        raise ValueError(f"fit_ml: model_floor must be finite and ≥ 0, got {model_floor}")
    spectra = run_spectra(run, f_max_hz, f_min_hz)
    frf = estimate_frf(run)
    scale = data_scale(frf, f_max_hz)
    if init is None:
        init = fit_nls(frf, f_max_hz=f_max_hz)
    init = init_model(init, run.n, data="run", what="fit_ml: ")
    theta0 = model_to_theta(init, scale, floor=init_floor)
    problem = make_ml_problem(spectra, scale, model_floor=model_floor, pd_eps=pd_eps)
    dyn = dict(solver=with_array_tolerances(solver), ftol=jnp.asarray(ftol),
               max_steps=jnp.asarray(max_steps), patience=jnp.asarray(patience))  # fmt: skip
    noise_only = make_ml_problem(spectra, scale, model_floor=0.0, pd_eps=pd_eps)
    theta, n_steps, code, cost, crb, sigma2, fisher_inv = _ml_core(problem, noise_only, theta0, dyn)

    model = theta_to_model(theta, scale, pd_eps)
    return MLResult(
        model=model,
        theta=theta,
        scale=scale,
        status_code=code,
        n_steps=jnp.asarray(n_steps).astype(jnp.int32),
        cost=cost,
        covariance=jnp.maximum(sigma2, 1.0) * fisher_inv,
        sigma2=sigma2,
        n_residuals=jnp.asarray(problem.n_residuals),
        at_boundary=boundary_report(theta_to_model(theta, scale), rtol=boundary_rtol),
        weight="ml",
        solver=solver_name(solver),
        crb=crb,
        dof=spectra.dof,
    )


def ml_cost(theta, run: Run, scale: Scale, *, f_max_hz: float | None = FIT_BAND_HZ,
            model_floor: float = 0.0) -> Array:  # fmt: skip
    """``V(θ)`` of :func:`fit_ml` for ``run`` (``theta`` in ``scale`` units)."""
    return make_ml_problem(run_spectra(run, f_max_hz), scale, model_floor=model_floor).cost(theta)
