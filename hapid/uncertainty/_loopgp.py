"""Draws of the loop coordinate ``Q = P P̂⁻¹`` conditioned on the measured FRF.

The inverse-model controller ``G = g Ẑ_T Ẑ_H⁻¹`` sees any plant through ``Q = P P̂⁻¹``
(``L = g Q``; ``Q = I`` for the model's own plant). Posterior draws of a second-order fit
describe ``Q`` only through the θ-model (and, for predictive draws, through a model error
defined on the impedance elements), and they are not calibrated in these coordinates
(docs/robust-design.md, Evidence E3). This module draws
``Q`` directly: the multiplicative error ``Δ = Q − I`` is measured at every FRF frequency
(``Δ_k = P_meas(ω_k) P̂(ω_k)⁻¹ − I``, the whole FRF band, 1–100 Hz on the paper's protocol), and
between the measured frequencies it is a Gaussian process in ``u = ln ω``:

    vec Δ(u) ~ CN(0, σ² a(u) a(u') [m(|u − u'|/ℓ) + η δ_{uu'}] ⊗ I_{n²})

— every element an independent circular complex GP with the same correlation (Matérn-5/2
``m``), an amplitude envelope ``a(u)`` (the measured RMS element size of ``Δ``, smoothed over
``ENVELOPE_WIDTH`` in ``ln ω``), a nugget ``η`` (measurement noise and roughness) and a
scale ``σ²``. ``ℓ`` and ``η`` maximize the leave-one-out predictive density on a grid and
``σ²`` calibrates the leave-one-out residuals (each measured ``Δ_k`` predicted from the
others): the band between measured frequencies is sized by how well the data predict
themselves, not by a likelihood that trusts the kernel (why: docs/robust-design.md, Evidence
E3). A draw is
the exact GP conditional on the measured ``Δ_k``.

When the FRF carries its element std (a periodic run's FRF does), the measured ``Δ_k`` are
the loop plus measurement noise of known variance ``v_k`` (:func:`measured_noise_var`):
the data covariance is ``σ² C + diag(v)`` and a draw is of the loop, not of the noisy
measurement. Without it the draws pass through the measured values to within the nugget, and
a bandwidth whose crossing lies between two measured points comes out mHz-narrow and offset
by the noise (docs/robust-design.md, Evidence E1).

Outside the measured band the data say nothing; the draws continue as stated assumptions:

- below ``ω_1`` (lowest measured): each draw continues from its value at ``ω_1`` as the
  Matérn process of the fitted ``ℓ`` conditioned on it, reverting to a prior of the size the
  lowest measured frequencies show (``E|Δ_ij|² → a(u_1)²``, *not* ``σ² a(u_1)²``: ``σ²``
  sizes the interpolation between measured frequencies; :func:`_below`), with the
  imaginary part scaled by ``ω/ω_1`` — a stable plant's response is real at DC, and the
  Nyquist count needs the loop real at the grid's low end;
- above ``ω_e`` (highest measured): ``Δ(ω_e)`` tapered to 0 (raised cosine over ``TOP_TAPER`` in
  ``ln ω``): the draw becomes the model's own plant. The true plant there is covered by the
  small-gain condition on ``g`` (:mod:`hapid.tune._evidence`), not by these draws.

:func:`loop_gp_plants` returns plants ``P_d = Q_d P̂`` for :func:`hapid.tune.make_scenarios`
(continuous loops, like the posterior family), so ``robust_design(draw_family="loop_gp")``
tunes on them and re-checks on held-out draws of the same process.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from ..impedance import plant

ENVELOPE_WIDTH = 0.35  # ln-ω half-width of the amplitude envelope's Gaussian smoothing
TOP_TAPER = 0.25  # ln-ω width of the taper of Δ to 0 above the highest measured frequency
ELLS = tuple(np.geomspace(0.03, 3.0, 25))  # candidate length scales (ln ω)
ETAS = (1e-6, 1e-4, 1e-3, 1e-2, 3e-2, 0.1, 0.3)  # candidate nuggets (relative to σ² a²)
TWO_PI = 2.0 * np.pi


def matern52(r):
    """Matérn-5/2 correlation of a scaled distance ``r ≥ 0``."""
    s = np.sqrt(5.0) * np.abs(r)
    return (1.0 + s + s * s / 3.0) * np.exp(-s)


@dataclasses.dataclass(frozen=True)
class LoopGP:
    """A fitted GP of ``Δ = P_meas P̂⁻¹ − I``: measured ``u (K,)`` (ln rad/s), ``D (K, n²)``
    complex, envelope data ``r (K,)`` (RMS element size of ``Δ_k``), hyperparameters ``ell``,
    ``eta``, ``sigma2``; ``n``. ``log_lik`` the leave-one-out log predictive density at the
    optimum. ``v (K,)``: the measurement-noise variance ``E|ε_ij|²`` of the elements of each
    ``Δ_k`` (from the FRF's element std, :func:`measured_noise_var`), or ``None`` (unknown:
    the nugget ``η`` alone stands for it)."""

    u: np.ndarray
    D: np.ndarray
    r: np.ndarray
    ell: float
    eta: float
    sigma2: float
    n: int
    log_lik: float
    v: np.ndarray | None = None

    def envelope(self, u) -> np.ndarray:
        """``a(u)``: RMS of the measured ``|Δ_ij|`` smoothed with a Gaussian of width
        ``ENVELOPE_WIDTH`` in ``ln ω`` (positive, defined at any ``u``)."""
        u = np.asarray(u, dtype=float)
        w = np.exp(-0.5 * ((u[:, None] - self.u[None]) / ENVELOPE_WIDTH) ** 2)
        a = np.sqrt(np.sum(w * self.r[None] ** 2, 1) / np.sum(w, 1))
        return np.maximum(a, 1e-6 * max(float(np.max(self.r)), 1e-300))


def measured_delta(omega, P_meas, model) -> np.ndarray:
    """``Δ_k = P_meas(ω_k) P̂(ω_k)⁻¹ − I`` ``(K, n, n)``."""
    Ph = model.P(1j * jnp.asarray(omega, dtype=float))
    Q = np.asarray(plant(jnp.asarray(P_meas), Ph))  # right division P P̂⁻¹
    return Q - np.eye(Q.shape[-1])


def _corr(u, a, ell, eta):
    """``a a' [m(|u − u'|/ℓ) + η δ]`` ``(K, K)``: the GP's covariance of the data over ``σ²``."""
    return a[:, None] * a[None] * (matern52((u[:, None] - u[None]) / ell) + eta * np.eye(u.size))


def _lpd(res, var):
    return float(np.sum(-np.log(np.pi * var) - np.abs(res) ** 2 / var))


def _loo(u, D, a, ell, eta, v=None):
    """Leave-one-out fit of one ``(ℓ, η)``: ``(LOO log predictive density, σ̂²)``. Each
    measured ``Δ_k`` is predicted from the others (closed form: residual ``[R⁻¹y]_k/[R⁻¹]_kk``,
    variance ``1/[R⁻¹]_kk``). Without measurement noise (``v`` None) ``R = σ² C`` and ``σ̂²``
    makes the standardized LOO residuals unit mean-square; with it ``R = σ² C + diag(v)`` and
    ``σ̂²`` maximizes the LOO density over a log grid (one eigendecomposition of the
    noise-whitened ``C``, then ``O(K²)`` per candidate). Interpolating across a gap twice the
    measured spacing, LOO calibrates the band between measured frequencies from the data
    themselves, and errs wide."""
    K, E = D.shape
    C = _corr(u, a, ell, eta)
    Ri = np.linalg.inv(C)
    dii = np.real(np.diag(Ri))
    if np.any(dii <= 0) or not np.all(np.isfinite(Ri)):
        return -np.inf, 1.0
    res = (Ri @ D) / dii[:, None]  # (K, E) LOO residuals
    s2 = float(np.mean(np.abs(res) ** 2 * dii[:, None]))  # |ρ|² / (var/σ²)
    if v is None:
        return _lpd(res, s2 / dii[:, None]), s2
    vh = np.sqrt(v)
    lam, U = np.linalg.eigh(C / (vh[:, None] * vh[None]))
    lam = np.maximum(lam, 0.0)
    UD, U2 = U.T @ (D / vh[:, None]), U * U
    s2s = s2 * np.geomspace(1e-4, 1e1, 41)
    d = 1.0 / (s2s[:, None] * lam[None] + 1.0)  # (S, K): eigenvalues of (I + σ² C̃)⁻¹
    dii = (d @ U2.T) / v[None]  # (S, K) diagonal of R⁻¹
    RiD = np.einsum("kj,sje->ske", U, d[:, :, None] * UD[None]) / vh[None, :, None]
    var = 1.0 / dii[:, :, None]
    lpd = np.sum(-np.log(np.pi * var) - np.abs(RiD * var) ** 2 / var, axis=(1, 2))
    b = int(np.argmax(lpd))
    return float(lpd[b]), float(s2s[b])


def fit_loop_gp(omega, P_meas, model, *, noise_var=None, ells=ELLS, etas=ETAS) -> LoopGP:
    """Fit the GP of the module docstring to a measured FRF's plant ``P_meas (K, n, n)`` on
    ``omega (K,)`` rad/s (increasing), for the nominal ``model``. ``noise_var (K,)``: the
    measurement-noise variance of each ``Δ_k``'s elements (:func:`measured_noise_var`; ``None``:
    unknown). Hyperparameters: the grid point of ``ells × etas`` with the largest
    leave-one-out log predictive density, ``σ²`` its LOO calibration (:func:`_loo`)."""
    omega = np.asarray(omega, dtype=float)
    if omega.ndim != 1 or omega.size < 3 or np.any(np.diff(omega) <= 0) or omega[0] <= 0:
        raise ValueError("fit_loop_gp: omega must be ≥ 3 increasing positive frequencies (rad/s)")
    Dm = measured_delta(omega, P_meas, model)
    if not np.all(np.isfinite(Dm)):
        raise ValueError("fit_loop_gp: P_meas P̂⁻¹ is not finite (singular model or plant)")
    K, n = Dm.shape[0], Dm.shape[-1]
    D = Dm.reshape(K, n * n)
    u = np.log(omega)
    r = np.sqrt(np.mean(np.abs(D) ** 2, 1))
    v = None
    if noise_var is not None:
        v = np.asarray(noise_var, dtype=float)
        if v.shape != (K,) or not np.all(np.isfinite(v)) or np.any(v < 0):
            raise ValueError(f"fit_loop_gp: noise_var must be ({K},) finite and ≥ 0")
        v = np.maximum(v, 1e-12 * max(float(np.mean(np.abs(D) ** 2)), 1e-300))
    proto = LoopGP(u, D, r, 1.0, 0.0, 1.0, n, 0.0, v)
    a = proto.envelope(u)
    best = None
    for ell in ells:
        for eta in etas:
            ll, s2 = _loo(u, D, a, float(ell), float(eta), v)
            if best is None or ll > best[0]:
                best = (ll, s2, float(ell), float(eta))
    ll, s2, ell, eta = best
    return dataclasses.replace(proto, ell=ell, eta=eta, sigma2=max(s2, 1e-300), log_lik=float(ll))


def conditional(gp: LoopGP, u_new) -> tuple[np.ndarray, np.ndarray]:
    """GP conditional of ``Δ`` at ``u_new (M,)`` (inside the measured band): mean ``(M, n²)``
    and the shared covariance ``(M, M)`` of each element (circular complex: ``E|e|²``)."""
    u_new = np.asarray(u_new, dtype=float)
    a, an = gp.envelope(gp.u), gp.envelope(u_new)
    R = gp.sigma2 * _corr(gp.u, a, gp.ell, gp.eta)
    if gp.v is not None:  # the measurement noise, known
        R = R + np.diag(gp.v)
    Ks = gp.sigma2 * an[:, None] * a[None] * matern52((u_new[:, None] - gp.u[None]) / gp.ell)
    Kss = gp.sigma2 * an[:, None] * an[None] * matern52((u_new[:, None] - u_new[None]) / gp.ell)
    L = np.linalg.cholesky(R)
    A = np.linalg.solve(L, Ks.T)  # L⁻¹ K_xs
    mean = A.T @ np.linalg.solve(L, gp.D)
    cov = Kss - A.T @ A
    return mean, 0.5 * (cov + cov.T)


def loop_gp_draws(
    gp: LoopGP, omega, n_draws: int, seed: int = 0, *, mean: bool = False
) -> np.ndarray:
    """``Q_d = I + Δ_d`` ``(S, N, n, n)`` on ``omega (N,)`` rad/s: GP conditional draws inside
    the measured band, the continuations of the module docstring outside it. ``mean=True``:
    the conditional mean instead (``(n_draws, N, n, n)``, every draw the same loop: the
    measured-FRF-conditioned nominal loop, no draw spread)."""
    omega = np.asarray(omega, dtype=float)
    if omega.ndim != 1 or np.any(omega <= 0) or n_draws < 1:
        raise ValueError("loop_gp_draws: omega must be positive (N,) rad/s and n_draws ≥ 1")
    u = np.log(omega)
    u1, ue = float(gp.u[0]), float(gp.u[-1])
    lo, hi = u <= u1, u >= ue
    inside = ~lo & ~hi
    u_pred = np.concatenate([[u1], u[inside], [ue]])
    mean_only = mean
    mean, cov = conditional(gp, u_pred)
    rng = np.random.default_rng(seed)
    E = gp.D.shape[1]
    if mean_only:
        Dd = np.broadcast_to(mean, (n_draws, *mean.shape))
    else:  # in place: the draws are the largest arrays of a robust check (S·M·E complex)
        Dd = _correlated(cov, n_draws, E, rng)
        Dd += mean[None]  # (S, M, E)
    d1, din, de = Dd[:, 0], Dd[:, 1:-1], Dd[:, -1]
    N = omega.size
    out = np.empty((n_draws, N, E), complex)  # lo, inside and hi cover every frequency
    out[:, inside] = din
    if np.any(lo):
        if mean_only:  # the continuation's mean: ρ(u) d1
            dlo = matern52((gp.u[0] - u[lo]) / gp.ell)[None, :, None] * d1[:, None, :]
        else:
            dlo = _below(gp, u[lo], d1, rng)
        dlo.imag *= (omega[lo] / np.exp(u1))[None, :, None]
        out[:, lo] = dlo
    t = np.clip((u[hi] - ue) / TOP_TAPER, 0.0, 1.0)
    out[:, hi] = de[:, None] * (0.5 * (1.0 + np.cos(np.pi * t)))[None, :, None]
    Q = out.reshape(n_draws, N, gp.n, gp.n)
    diag = np.arange(gp.n)
    Q[..., diag, diag] += 1.0  # I + Δ, without a second (S, N, n, n) array
    return Q


def loop_gp_mean(gp: LoopGP, omega) -> np.ndarray:
    """``Q̄ = I + E[Δ]`` ``(N, n, n)`` on ``omega (N,)`` rad/s: the mean of
    :func:`loop_gp_draws` — the GP conditional mean inside the measured band, below it the
    mean at the lowest measured frequency times ``ρ = m(|u − u_1|/ℓ)``, above it the mean at
    the highest tapered to 0. ``Q̄ P̂`` is the measured plant interpolated on any grid."""
    u = np.log(np.asarray(omega, dtype=float))
    u1, ue = float(gp.u[0]), float(gp.u[-1])
    lo, hi = u <= u1, u >= ue
    inside = ~lo & ~hi
    mean, _ = conditional(gp, np.concatenate([[u1], u[inside], [ue]]))
    out = np.zeros((u.size, gp.D.shape[1]), complex)
    out[inside] = mean[1:-1]
    ratio = np.exp(u[lo] - u1)[:, None]
    dlo = matern52((u1 - u[lo]) / gp.ell)[:, None] * mean[0][None]
    out[lo] = dlo.real + 1j * ratio * dlo.imag
    t = np.clip((u[hi] - ue) / TOP_TAPER, 0.0, 1.0)
    out[hi] = mean[-1][None] * (0.5 * (1.0 + np.cos(np.pi * t)))[:, None]
    return np.eye(gp.n) + out.reshape(u.size, gp.n, gp.n)


def _correlated(cov, n_draws: int, E: int, rng) -> np.ndarray:
    """``(S, M, E)`` circular complex Gaussian draws with covariance ``cov (M, M)`` per
    element (PSD-safe square root: eigenvalues clipped at 0).

    ``root (M, r)`` over the ``r`` positive eigenvalues times standard normals ``(r, S·E)``
    for the real and for the imaginary part: two real BLAS products written straight into
    the complex result, no complex or transposed temporaries (``hapid robust``'s default
    draws M ≈ 1000 frequencies × S = 1000 draws × E = 25 entries). The returned array is a
    view ``(S, M, E)`` of the ``(M, S, E)`` result."""
    w, V = np.linalg.eigh(cov)
    M = cov.shape[0]
    keep = w > 0.0
    root = V[:, keep] * np.sqrt(0.5 * w[keep])[None]  # circular: half the variance in each part
    r = int(np.sum(keep))
    out = np.empty((M, n_draws * E), complex)
    out.real = root @ rng.standard_normal((r, n_draws * E))
    out.imag = root @ rng.standard_normal((r, n_draws * E))
    return np.moveaxis(out.reshape(M, n_draws, E), 0, 1)


def _below(gp: LoopGP, u_lo, d1, rng) -> np.ndarray:
    """``Δ`` below the lowest measured frequency ``u_1`` ``(S, M_lo, E)``, continuing each
    draw's value ``d1 (S, E)`` at ``u_1``: ``ρ(u) d1 + e(u)``, ``ρ = m(|u − u_1|/ℓ)``, ``e`` the
    zero-mean GP with kernel ``a(u_1)² [m(|u − u'|/ℓ) − ρ(u) ρ(u')]`` — the Matérn process of
    the fitted ``ℓ`` conditioned on ``d1``, reverting to a prior of the size the lowest
    measured frequencies show (``E|Δ_ij|² → a(u_1)²``, the measured RMS element size there).
    Not ``σ² a(u_1)²``: ``σ²`` calibrates how far the data predict themselves *between*
    measured frequencies, not the size of an unmeasured band (why: docs/robust-design.md,
    Evidence E4, "The collapse")."""
    a1 = float(gp.envelope(gp.u[:1])[0])
    rho = matern52((gp.u[0] - u_lo) / gp.ell)
    C = a1**2 * (matern52((u_lo[:, None] - u_lo[None]) / gp.ell) - rho[:, None] * rho[None])
    out = _correlated(0.5 * (C + C.T), d1.shape[0], d1.shape[1], rng)
    out += rho[None, :, None] * d1[:, None, :]
    return out


def loop_gp_plants(gp: LoopGP, model, omega, n_draws: int, seed: int = 0, *,
                   mean: bool = False) -> np.ndarray:  # fmt: skip
    """Plants ``P_d = Q_d P̂`` ``(S, N, n, n)`` on ``omega`` rad/s (for
    :func:`hapid.tune.make_scenarios`: its ``P P̂⁻¹`` gives back ``Q_d``); ``mean``: the
    conditional mean loop (:func:`loop_gp_draws`)."""
    Q = loop_gp_draws(gp, omega, n_draws, seed, mean=mean)
    Ph = np.asarray(model.P(1j * jnp.asarray(omega, dtype=float)))
    return Q @ Ph[None]


def measured_plant(Z_H, Z_T) -> np.ndarray:
    """``P = Z_H Z_T⁻¹`` of measured impedances ``(N, n, n)``."""
    return np.asarray(plant(jnp.asarray(Z_H), jnp.asarray(Z_T)))


def measured_data(frf) -> dict:
    """``{"omega" (K,) rad/s, "Z_H", "Z_T" (K, n, n)}`` (numpy) of an FRF: anything with
    those attributes (:class:`hapid.experiment.FRF`) or keys (a samples file's ``measured``);
    with ``"Z_H_std"``, ``"Z_T_std"`` (K, n, n) too when the FRF has its element std."""
    get = (lambda k: frf.get(k)) if isinstance(frf, dict) else (lambda k: getattr(frf, k, None))  # noqa: E731
    out = {k: np.asarray(get(k)) for k in ("omega", "Z_H", "Z_T")}
    std = {k: get(k) for k in ("Z_H_std", "Z_T_std")}
    if all(v is not None for v in std.values()):
        out |= {k: np.asarray(v, dtype=float) for k, v in std.items()}
    return out


def measured_noise_var(data: dict, model) -> np.ndarray | None:
    """The measurement-noise variance ``(K,)`` of the elements of ``Δ_k = P_meas P̂⁻¹ − I``
    (mean of ``E|δΔ_ij|²`` over ``i, j``) from the FRF's element std, to first order and with
    the elements' errors independent: ``δΔ = (δZ_H − P δZ_T) Z_T⁻¹ P̂⁻¹``. ``None`` when
    ``data`` (:func:`measured_data`) has no std."""
    if "Z_H_std" not in data:
        return None

    omega = np.asarray(data["omega"], dtype=float)
    Ph = np.asarray(model.P(1j * jnp.asarray(omega)))
    W2 = np.abs(np.linalg.inv(Ph @ data["Z_T"])) ** 2  # |Z_T⁻¹ P̂⁻¹|² (K, n, n)
    P2 = np.abs(measured_plant(data["Z_H"], data["Z_T"])) ** 2
    var = data["Z_H_std"] ** 2 @ W2 + P2 @ (data["Z_T_std"] ** 2 @ W2)
    return np.mean(var, axis=(1, 2))


def measured_loop_gp(data: dict, model) -> LoopGP:
    """:func:`fit_loop_gp` of a measured FRF (:func:`measured_data`) with its measurement
    noise (:func:`measured_noise_var`) when the FRF has its element std."""
    return fit_loop_gp(data["omega"], measured_plant(data["Z_H"], data["Z_T"]), model,
                       noise_var=measured_noise_var(data, model))  # fmt: skip
