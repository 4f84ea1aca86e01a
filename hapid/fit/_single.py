# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""Fit one measured impedance ``Z(jω) ≈ M (jω)² + B jω + K`` (lab data: a collocated
dynamic stiffness, not the haptic hand/total pair).

- ``method="wls"``: element-wise linear least squares with relative weights ``1/‖Z(jω)‖_F``
  (unconstrained, generally non-symmetric M, B, K); ``positize=True`` applies the paper's
  positizing (section 5.1) afterwards.
- ``method="nls"``: ``M, B, K = L Lᵀ`` (symmetric PSD by construction, ``hapid.fit._pd``'s
  Cholesky parameterization), Levenberg–Marquardt (optimistix) from the projected WLS fit,
  Laplace covariance ``σ̂²(JᵀJ)⁺`` of the factors and, by the delta method, standard
  deviations of every entry of M, B, K. Weights ``"relative"`` (``1/‖Z(jω)‖_F``) or
  ``"noise"`` (``√2/σ``: each real residual has unit variance, σ̂² = 1).

The band is applied by selecting frequencies before the fit (``f_min_hz ≤ f ≤ f_max_hz``),
identically for every method. Units follow ``zfrf.unit`` (``model_units``).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, Complex, Float

from .._plain import jsonable
from ..defaults import NLS_MAX_STEPS
from ..impedance import SecondOrder
from ..impedance_frf import ImpedanceFRF
from ._nls import laplace_covariance
from ._pd import Scale, _project_matrix
from ._physics import CHI2_SCALE_ABOVE, chi2_note, correct_exponential, physics_warnings
from ._positize import positize_matrix
from ._quality import FitQuality, impedance_quality
from ._result import FIT_OK, STATUS_NAMES, FitStatus
from ._solvers import run_solver

SINGLE_WEIGHTS = ("relative", "noise")
SINGLE_METHODS = ("wls", "nls")


def _scale(zfrf: ImpedanceFRF) -> Scale:
    """ω_ref = geometric-mean frequency (rad/s), z_ref = median |element| of Z."""
    w, Z = np.asarray(zfrf.omega), np.asarray(zfrf.Z)
    return Scale(jnp.asarray(np.exp(np.mean(np.log(w)))), jnp.asarray(np.median(np.abs(Z))))


def wls_single(zfrf: ImpedanceFRF) -> SecondOrder:
    """Relative-weight linear least squares, element by element (one real solve; numpy).

    Minimizes ``Σ_k |(m (jω_k)² + b jω_k + k − z_ij(jω_k))/‖Z(jω_k)‖_F|²`` for every element;
    columns are scaled to unit norm before the solve. Returns unconstrained M, B, K.
    """
    w, Z = np.asarray(zfrf.omega), np.asarray(zfrf.Z)
    s = 1j * w
    wt = 1.0 / np.linalg.norm(Z, axis=(-2, -1))
    A = wt[:, None] * np.stack([s**2, s, np.ones_like(s)], axis=-1)  # (N, 3)
    Ar = np.concatenate([A.real, A.imag])  # (2N, 3)
    c = np.linalg.norm(Ar, axis=0)
    flat = (wt[:, None, None] * Z).reshape(Z.shape[0], -1)
    rhs = np.concatenate([flat.real, flat.imag])  # (2N, n²)
    coef = np.linalg.lstsq(Ar / c, rhs, rcond=None)[0]
    m, b, k = (coef / c[:, None]).reshape((3,) + Z.shape[1:])
    return SecondOrder(jnp.asarray(m), jnp.asarray(b), jnp.asarray(k))


class SingleProblem(eqx.Module):
    """Weighted residual ``r(θ)`` of one impedance (``θ``: three Cholesky factors M, B, K in
    ``scale`` units, ``3·n(n+1)/2`` entries); duck-types ``hapid.fit._nls.Problem``."""

    s: Complex[Array, " N"]  # jω/ω_ref
    Z: Complex[Array, "N n n"]  # Z/z_ref
    W: Float[Array, "N n n"]
    scale: Scale

    @property
    def n(self) -> int:
        return int(self.Z.shape[-1])

    @property
    def n_residuals(self):
        return 2 * self.Z.size

    def matrices(self, theta):
        n = self.n
        t = n * (n + 1) // 2
        rows, cols = np.tril_indices(n)
        L = jnp.stack(
            [jnp.zeros((n, n)).at[rows, cols].set(theta[k * t : (k + 1) * t]) for k in range(3)]
        )
        return L @ jnp.swapaxes(L, -1, -2)

    def __call__(self, theta, args=None):
        M, B, K = self.matrices(theta)
        s = self.s[:, None, None]
        e = self.W * (M * s**2 + B * s + K - self.Z)
        return jnp.concatenate([jnp.real(e).ravel(), jnp.imag(e).ravel()])

    def cost(self, theta, args=None):
        r = self(theta)
        return 0.5 * jnp.sum(r**2)

    def model(self, theta) -> SecondOrder:
        M, B, K = self.matrices(theta)
        fm, fb, fk = self.scale.factors()
        return SecondOrder(M / fm, B / fb, K / fk)


@jax.jit
def _theta0(model: SecondOrder, scale: Scale, floor: float):
    fm, fb, fk = scale.factors()
    mats = jnp.stack([model.M * fm, model.B * fb, model.K * fk])
    mats = _project_matrix(mats, floor, global_floor=floor * 1e-3)
    L = jnp.linalg.cholesky(0.5 * (mats + jnp.swapaxes(mats, -1, -2)))
    rows, cols = np.tril_indices(model.n)
    return L[:, rows, cols].reshape(-1)


#: the frequency axis of an NLS fit is padded (zero-weight rows) to a multiple of this
#: power-of-two bucket, so fits on different bands share one compiled solver
PAD_MIN = 128


def _padded(n_freq: int) -> int:
    return max(PAD_MIN, 1 << (int(n_freq) - 1).bit_length())


@eqx.filter_jit
def _nls_core(omega, Z, W, scale: Scale, theta0, max_steps, rtol, atol, ftol):
    """The jitted LM fit on padded arrays (rows with ``W = 0`` are padding). The covariance
    and std are returned for σ̂² = 1; the caller scales them (one compile for every weight)."""
    prob = SingleProblem(s=1j * omega / scale.omega_ref, Z=Z / scale.z_ref, W=W, scale=scale)
    lm = optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))
    theta, n_steps, code = run_solver(prob, theta0, lm, max_steps, ftol, 20)
    cov, sigma2, cost = laplace_covariance(prob, theta, True)
    code = jnp.where(jnp.all(jnp.isfinite(theta)) & jnp.isfinite(cost), code, 2)
    model = prob.model(theta)
    # delta-method std of every entry of M, B, K
    G = jax.jacfwd(lambda th: _flat(prob.model(th)))(theta)
    var = jnp.einsum("ip,pq,iq->i", G, cov, G)
    sd = jnp.sqrt(jnp.maximum(var, 0.0)).reshape((3,) + Z.shape[1:])
    return model, SecondOrder(sd[0], sd[1], sd[2]), theta, code, n_steps, cost, cov, sigma2


def _nls(zfrf: ImpedanceFRF, weight: str, max_steps: int, rtol, atol, ftol):
    """Scale, weights, start and padding outside the compiled core; unpadded results."""
    scale = _scale(zfrf)
    N = int(zfrf.Z.shape[0])
    Zs = np.asarray(zfrf.Z) / float(scale.z_ref)
    if weight == "relative":
        W = np.broadcast_to(1.0 / np.linalg.norm(Zs, axis=(-2, -1))[:, None, None], Zs.shape)
    else:
        W = np.sqrt(2.0) * float(scale.z_ref) / np.asarray(zfrf.Z_std)
    theta0 = _theta0(wls_single(zfrf), scale, 1e-6)
    P = _padded(N) - N
    pad = lambda a, v: np.concatenate([a, np.full((P,) + a.shape[1:], v, a.dtype)])  # noqa: E731
    out = _nls_core(
        jnp.asarray(pad(np.asarray(zfrf.omega), float(zfrf.omega[-1]))),
        jnp.asarray(pad(np.asarray(zfrf.Z), 1.0 + 0j)),
        jnp.asarray(pad(np.asarray(W, dtype=np.float64), 0.0)),
        scale, theta0, jnp.asarray(max_steps), jnp.asarray(rtol), jnp.asarray(atol),
        jnp.asarray(ftol),
    )  # fmt: skip
    model, sd, theta, code, steps, cost, cov, _ = out
    # σ̂² = 2·cost/(m − p) (m the real, unpadded residuals) for relative weights; for noise
    # weights 1, or the reduced χ² when the misfit is well above what the std explain
    m, p = 2 * N * zfrf.n**2, int(theta.shape[0])
    chi2_red = 2.0 * float(cost) / max(m - p, 1)
    sigma2 = chi2_red if weight != "noise" or chi2_red > CHI2_SCALE_ABOVE else 1.0
    cov = cov * sigma2
    sd = SecondOrder(*(a * np.sqrt(sigma2) for a in (sd.M, sd.B, sd.K)))
    return model, sd, theta, scale, code, steps, cost, cov, sigma2, chi2_red


def _flat(m: SecondOrder):
    return jnp.concatenate([m.M.ravel(), m.B.ravel(), m.K.ravel()])


@dataclasses.dataclass(frozen=True)
class ImpedanceFit:
    """Outcome of :func:`fit_impedance`.

    ``model`` (M, B, K in ``model_units(unit)``); ``method`` text; ``status`` a
    :class:`~hapid.fit.FitStatus` (a string is converted: "closed form", "converged",
    "max_steps", "failed"); ``ok`` (closed form or converged); ``n_steps``; ``cost`` (½‖r‖², NaN for WLS);
    ``model_std`` Laplace std of every entry (NLS; ``None`` for WLS); ``theta``, ``scale``,
    ``covariance``, ``sigma2`` (NLS: the variance scale of the std — the reduced χ² for relative
    weights, 1 for noise weights unless the reduced χ² exceeds ``CHI2_SCALE_ABOVE``);
    ``reduced_chi2`` (NLS); ``quality`` (:class:`FitQuality` over the band used, with the
    physics warnings: negative-definite M or K, negative damping, a collapse toward 0);
    ``boundary`` names of M, B, K with an eigenvalue at the PSD boundary; ``exp_tau_s`` > 0: the
    data were exponentially windowed and ``model``/``model_std`` are corrected for it.
    """

    model: SecondOrder
    method: str
    status: FitStatus
    unit: str
    quality: FitQuality
    n_steps: int = 0
    cost: float = float("nan")
    model_std: SecondOrder | None = None
    theta: np.ndarray | None = None
    scale: Scale | None = None
    covariance: np.ndarray | None = None
    sigma2: float = float("nan")
    boundary: tuple[str, ...] = ()
    reduced_chi2: float = float("nan")
    exp_tau_s: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "status", FitStatus(self.status))

    @property
    def ok(self) -> bool:
        return self.status in FIT_OK

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``method``, ``unit``, ``n_steps``, ``cost``,
        ``reduced_chi2``, ``boundary``, ``exp_tau_s`` and ``quality`` (its summary);
        non-finite numbers as ``None``."""
        return jsonable({"status": self.status, "ok": self.ok, "method": self.method,
                         "unit": self.unit, "n_steps": self.n_steps, "cost": self.cost,
                         "reduced_chi2": self.reduced_chi2, "boundary": self.boundary,
                         "exp_tau_s": self.exp_tau_s, "quality": self.quality.summary()})  # fmt: skip

    def metadata(self) -> dict:
        """Arrays for the model file (method, status, cost, std, covariance, quality)."""
        d = {"method": np.asarray(self.method), "status": np.asarray(self.status.value),
             "unit": np.asarray(self.unit), "cost": np.float64(self.cost),
             "steps": np.int64(self.n_steps)}  # fmt: skip
        if self.model_std is not None:
            d.update(M_std=self.model_std.M, B_std=self.model_std.B, K_std=self.model_std.K)
            d.update(covariance=self.covariance, theta=self.theta, sigma2=np.float64(self.sigma2))
            d.update(reduced_chi2=np.float64(self.reduced_chi2))
        if self.exp_tau_s:
            d.update(exp_tau_s=np.float64(self.exp_tau_s))
        return {k: np.asarray(v) for k, v in d.items()} | self.quality.to_arrays()


def _boundary(model: SecondOrder, rtol=1e-6) -> tuple[str, ...]:
    out = []
    for name, A in zip("MBK", (model.M, model.B, model.K), strict=True):
        lam = np.linalg.eigvalsh(0.5 * (np.asarray(A) + np.asarray(A).T))
        if lam[0] <= rtol * np.max(np.abs(lam)):
            out.append(name)
    return tuple(out)


def fit_impedance(
    zfrf: ImpedanceFRF,
    *,
    method: str = "nls",
    positize: bool = False,
    weight: str = "relative",
    f_min_hz: float = 0.0,
    f_max_hz: float = np.inf,
    max_steps: int = NLS_MAX_STEPS,
    rtol: float = 1e-10,
    atol: float = 1e-12,
    ftol: float = 1e-8,
) -> ImpedanceFit:
    """Fit ``M s² + B s + K`` to ``zfrf.Z`` over ``f_min_hz ≤ f ≤ f_max_hz`` (Hz).

    ``method`` ``"wls"`` (``positize`` optional) or ``"nls"`` (PSD, ``weight`` ``"relative"``
    or ``"noise"``; noise needs ``Z_std > 0``). Returns :class:`ImpedanceFit` with the fit
    quality over the band used. Raises ``ValueError`` naming the problem (unknown option,
    fewer than 3 frequencies in the band, missing std, non-finite data).
    """
    if method not in SINGLE_METHODS:
        raise ValueError(f"method must be one of {SINGLE_METHODS}, got {method!r}")
    if weight not in SINGLE_WEIGHTS:
        raise ValueError(
            f"weight for a single impedance must be one of {SINGLE_WEIGHTS}, got {weight!r}"
        )
    if positize and method != "wls":
        raise ValueError("positize applies to the WLS fit only (NLS is PSD by construction)")
    if not f_min_hz < f_max_hz:
        raise ValueError(f"empty band: f_min_hz = {f_min_hz} ≥ f_max_hz = {f_max_hz}")
    sel = zfrf.band(f_min_hz, f_max_hz)
    N = int(np.shape(sel.Z)[0])
    if N < 3:
        raise ValueError(
            f"only {N} frequencies in the band {f_min_hz:g}–{f_max_hz:g} Hz; a second-order "
            "fit needs at least 3"
        )
    if method == "nls" and weight == "noise":
        if sel.Z_std is None:
            raise ValueError("noise weights need Z_std, which the impedance FRF does not have")
        if np.any(np.asarray(sel.Z_std) <= 0):
            raise ValueError("noise weights need Z_std > 0 everywhere in the band")
    if np.any(np.linalg.norm(np.asarray(sel.Z), axis=(-2, -1)) == 0):
        raise ValueError("Z is zero at some frequency in the band: relative error is undefined")
    band = (float(f_min_hz), float(f_max_hz))
    if method == "wls":
        raw = wls_single(sel)
        q_raw = impedance_quality(sel, raw, method="wls", band_hz=band)
        if not positize:
            q_raw = _with_physics(q_raw, sel, raw)
            return _exp_corrected(ImpedanceFit(raw, "wls", "closed form", sel.unit, q_raw), sel)
        pos = SecondOrder(*(positize_matrix(a) for a in (raw.M, raw.B, raw.K)))
        q = impedance_quality(sel, pos, method="wls+positize", band_hz=band, before=q_raw)
        q = _with_physics(q, sel, raw, pos)
        return _exp_corrected(ImpedanceFit(pos, "wls+positize", "closed form", sel.unit, q), sel)
    model, sd, theta, scale, code, steps, cost, cov, sigma2, chi2_red = _nls(
        sel, weight, int(max_steps), rtol, atol, ftol
    )
    q = impedance_quality(sel, model, method=f"nls ({weight} weights)", band_hz=band)
    # the unconstrained fit shows what the PSD fit cannot: negative-definite M or K
    q = _with_physics(q, sel, model)
    q = _with_physics(q, sel, wls_single(sel), what="the unconstrained (WLS) fit of this band: ")
    if weight == "noise" and chi2_note(chi2_red):
        q = q.with_warning(chi2_note(chi2_red))
    fit = ImpedanceFit(
        model=model,
        method="nls",
        status=str(STATUS_NAMES[int(code)]),
        unit=sel.unit,
        quality=q,
        n_steps=int(steps),
        cost=float(cost),
        model_std=sd,
        theta=np.asarray(theta),
        scale=scale,
        covariance=np.asarray(cov),
        sigma2=float(sigma2),
        boundary=_boundary(model),
        reduced_chi2=float(chi2_red),
    )
    return _exp_corrected(fit, sel)


def _with_physics(q: FitQuality, sel: ImpedanceFRF, *models, what: str = "") -> FitQuality:
    """``q`` with the physics warnings of ``models`` (duplicates once)."""
    for m in models:
        for w in physics_warnings(m, np.asarray(sel.Z), np.asarray(sel.omega), what):
            if w not in q.warnings:
                q = q.with_warning(w)
    return q


def _exp_corrected(fit: ImpedanceFit, sel: ImpedanceFRF) -> ImpedanceFit:
    """The fit of exponentially windowed data (``sel.exp_tau_s`` > 0) with M, B, K (and std)
    corrected to the structure's (:func:`correct_exponential`); unchanged otherwise."""
    tau = float(sel.exp_tau_s)
    if not tau:
        return fit
    m = fit.model
    sd = fit.model_std
    M, B, K, ms, bs, ks = correct_exponential(
        m.M, m.B, m.K, tau, *((sd.M, sd.B, sd.K) if sd is not None else ())
    )
    q = fit.quality.with_line(
        "exp_window",
        f"exponential window τ = {tau:g} s: the data are Z(jω + 1/τ); M, B, K are corrected to "
        f"the structure's (B − 2M/τ, K − B/τ − M/τ²; modal ζ lowered by 1/(τ ω_n)); the quality "
        "figures compare the windowed fit with the windowed data",
    )
    return dataclasses.replace(
        fit,
        model=SecondOrder(jnp.asarray(M), jnp.asarray(B), jnp.asarray(K)),
        model_std=None if sd is None else SecondOrder(*(jnp.asarray(x) for x in (ms, bs, ks))),
        quality=q,
        exp_tau_s=tau,
    )


__all__ = ["fit_impedance", "ImpedanceFit", "wls_single"]
