# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Posterior-predictive draws of the model-error term on a new frequency grid, given each
posterior draw's fit residuals: the computations behind
:meth:`hapid.uncertainty.ModelError.predictive_errors`, one function per kind.

Every function takes a :class:`~hapid.samples.PosteriorSamples` ``ps`` whose ``predictive``
holds the fit data (:meth:`~hapid.uncertainty.LogPosterior.predictive_data`), the indices
``idx (S,)`` of the draws used, the new frequencies ``omega (N,)`` rad/s and a numpy
``Generator``; it returns ``(e_H, e_M)``, each ``(S, N, n, n)`` complex (N/m), the errors of
the hand and of the mechanism impedance (``Z_T`` carries ``e_H + e_M``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._aot import cached_jit
from ..samples import PosteriorSamples
from ._gp import (
    corr_kernel,
    corr_warp,
    gp_corr_covariance,
    gp_covariance,
    hm_correlation,
    kernel,
    split_hyper,
    switches,
    warp,
)
from ._weights import element_weights, gp_amplitudes

_BATCH = 50  # draws per jitted vmap call


def _interp_log(x_new, x, y):
    """``y(x)`` log-log interpolated at ``x_new`` (constant beyond the ends)."""
    return np.exp(np.interp(np.log(x_new), np.log(x), np.log(np.maximum(y, 1e-300))))


def _fit_residuals(ps: PosteriorSamples, models):
    """``(r_H, r_T)``, each ``(S, N_fit, n, n)`` complex (N/m): the measured ``Ẑ − Z(θ)`` at
    the fit frequencies of the batched ``models`` (``(S, …)``, physical units)."""
    data = ps.predictive
    sf = 1j * jnp.asarray(np.asarray(data["omega"]))
    ZHf = np.asarray(jax.vmap(lambda m: m.hand(sf))(models))
    ZTf = np.asarray(jax.vmap(lambda m: m.total(sf))(models))
    return np.asarray(data["Z_H"])[None] - ZHf, np.asarray(data["Z_T"])[None] - ZTf


def _batched(run, hyper, y_all, rng, *consts):
    """``run(hyper, y, keys, *consts, switches)`` (a jitted, vmapped function of the draws) in
    batches of :data:`_BATCH` draws, with keys split from one seed drawn from ``rng``; the
    per-batch outputs (a pair). ``switches``: :func:`~hapid.uncertainty._gp.switches`, static,
    so a flipped kernel or warp switch is another program."""
    S_ = hyper.shape[0]
    keys = jax.random.split(jax.random.PRNGKey(int(rng.integers(2**31))), S_)
    return [run(jnp.asarray(hyper[i : i + _BATCH]), jnp.asarray(y_all[i : i + _BATCH]),
                keys[i : i + _BATCH], *consts, switches()) for i in range(0, S_, _BATCH)]  # fmt: skip


def white_errors(ps: PosteriorSamples, idx, omega, rng, weight=None):
    """Independent circular errors of variance ``(τ a(ω) w(ω))²`` per element and frequency
    (``a`` the fit band's RMS element sizes, log-log interpolated and constant beyond it;
    ``w = weight (N,)``, 1 when None): the white model has no correlation to condition on."""
    data = ps.predictive
    tau = ps.tau[idx]
    S_, N, n = tau.shape[0], omega.shape[0], ps.n
    om_fit = np.asarray(data["omega"])
    aH = _interp_log(omega, om_fit, np.asarray(data["a_H"]))
    aM = _interp_log(omega, om_fit, np.asarray(data["a_M"]))
    if weight is not None:
        aH, aM = aH * weight, aM * weight

    def circ(sd):  # (S, N) → circular complex (S, N, n, n) with E|e|² = sd²
        z = rng.standard_normal((2, S_, N, n, n)) * np.sqrt(0.5)
        return (z[0] + 1j * z[1]) * sd[:, :, None, None]

    eH = circ(tau[:, :1] * aH[None])
    return eH, circ(tau[:, 1:2] * aM[None])


def gp_errors(ps: PosteriorSamples, idx, models, omega, rng):
    """Draws of the independent hand/mechanism GP errors (re and im parts of each element;
    :func:`~hapid.uncertainty._gp.gp_covariance`) on ``omega``: the exact GP conditional on
    each draw's residuals at the fit frequencies, pathwise (a joint prior draw on fit ∪ new
    frequencies corrected by ``K_{*x} C⁻¹ (r − ỹ)``, Matheron's rule). ``models``: the batched
    models of the draws ``idx``."""
    data = ps.predictive
    n, E, N = ps.n, ps.n * ps.n, omega.shape[0]
    hyper = ps.samples[idx, ps.n_theta :]
    om_fit = np.asarray(data["omega"])
    Nf = om_fit.shape[0]
    ref = np.asarray(data["ref_theta"])
    aH_f, aM_f = np.asarray(data["a_H"]), np.asarray(data["a_M"])
    aH_n, aM_n = gp_amplitudes(omega, om_fit, (aH_f, aM_f), ref, ps.scale)
    rH, rT = _fit_residuals(ps, models)
    S_ = rH.shape[0]
    var_H, var_T = np.asarray(data["var_H"]), np.asarray(data["var_T"])
    rho = float(data["noise_corr"])
    u = np.log(np.concatenate([om_fit, omega]) / float(np.asarray(ps.scale.omega_ref)))
    a_all = (np.concatenate([aH_f, aH_n]), np.concatenate([aM_f, aM_n]))
    dH = 0.5 * var_H.reshape(Nf, E).T  # (E, Nf)
    dT = 0.5 * var_T.reshape(Nf, E).T
    dHT = rho * np.sqrt(dH * dT)
    cond_T = np.sqrt(np.clip(dT - np.where(dH > 0, dHT**2 / np.where(dH > 0, dH, 1), 0), 0, None))
    flat = lambda r: np.moveaxis(r.reshape(r.shape[0], Nf, E), 1, 2)  # noqa: E731  (S, E, Nf)
    y_all = np.stack([np.concatenate([flat(rH.real), flat(rT.real)], -1),
                      np.concatenate([flat(rH.imag), flat(rT.imag)], -1)], -1)  # fmt: skip
    sdH, cT = np.sqrt(dH), cond_T
    lamT = np.where(dH > 0, dHT / np.where(dH > 0, np.sqrt(dH), 1), 0)
    consts = tuple(jnp.asarray(x) for x in (u, *a_all, sdH, lamT, cT, var_H, var_T, rho))
    parts = _batched(_gp_chunk, hyper, y_all, rng, consts)
    oH = np.concatenate([np.asarray(p[0]) for p in parts])  # (S, E, 2, N)
    oM = np.concatenate([np.asarray(p[1]) for p in parts])
    cplx = lambda o: np.moveaxis(o[:, :, 0] + 1j * o[:, :, 1], 1, 2).reshape(S_, N, n, n)  # noqa: E731
    return cplx(oH), cplx(oM)


def gp_corr_errors(ps: PosteriorSamples, idx, models, omega, rng, element: bool = False):
    """Draws of the correlated GP errors (shared latent function of ``e_H`` and ``e_M``,
    complex ρ, asinh knee coordinate: :func:`~hapid.uncertainty._gp.gp_corr_covariance`) on
    ``omega``: the exact conditional on each draw's fit residuals, Matheron's rule in the
    complex circular form (a joint prior draw of the shared latent ``f₁`` and of ``f₂`` on
    fit ∪ new frequencies, corrected by ``Cov(e_*, r) C⁻¹ (r − r̃)``). ``element``: the
    amplitudes weighted per element (``GPCorr(scale="element")``,
    :func:`~hapid.uncertainty._weights.element_weights`). ``models``: the batched models of
    the draws ``idx``."""
    data = ps.predictive
    n, E = ps.n, ps.n * ps.n
    hyper = ps.samples[idx, ps.n_theta :]
    om_fit = np.asarray(data["omega"])
    Nf, N = om_fit.shape[0], omega.shape[0]
    aH_f, aM_f = np.asarray(data["a_H"]), np.asarray(data["a_M"])
    aH_n, aM_n = gp_amplitudes(omega, om_fit, (aH_f, aM_f), np.asarray(data["ref_theta"]), ps.scale)
    rH, rT = _fit_residuals(ps, models)
    S_ = rH.shape[0]
    flat = lambda r: np.moveaxis(r.reshape(S_, Nf, E), 1, 2)  # noqa: E731  (S, E, Nf)
    y_all = np.concatenate([flat(rH), flat(rT)], -1)  # (S, E, 2Nf) complex
    var_H, var_T = np.asarray(data["var_H"]), np.asarray(data["var_T"])
    rho_n = float(data["noise_corr"])
    sdH = jnp.asarray(np.sqrt(var_H.reshape(Nf, E).T))  # (E, Nf)
    sdT = jnp.asarray(np.sqrt(var_T.reshape(Nf, E).T))
    om_all = np.concatenate([om_fit, omega])
    u = jnp.asarray(np.log(om_all / float(np.asarray(ps.scale.omega_ref))))  # (Nf + N,)
    a_all = (np.concatenate([aH_f, aH_n]), np.concatenate([aM_f, aM_n]))  # (Nf + N,) each
    if element:  # per element: (E, Nf + N)
        w = element_weights(np.asarray(data["ref_theta"]), ps.scale, om_all)
        a_all = tuple(a[None] * wi for a, wi in zip(a_all, w, strict=True))
    consts = (u, *(jnp.asarray(a) for a in a_all), sdH, sdT, jnp.asarray(var_H),
              jnp.asarray(var_T), jnp.asarray(rho_n))  # fmt: skip
    shared = bool(np.all(hyper == hyper[:1]))  # hyperparameters fixed (the default)
    run = _gp_corr_chunk_shared if shared else _gp_corr_chunk
    parts = _batched(run, hyper, y_all, rng, consts)
    cplx = lambda o: np.moveaxis(o, 1, 2).reshape(S_, N, n, n)  # noqa: E731  (S, E, N) → (S, N, n, n)
    return (cplx(np.concatenate([np.asarray(p[0]) for p in parts])),
            cplx(np.concatenate([np.asarray(p[1]) for p in parts])))  # fmt: skip


def _gp_one(h, y, key, u, aH, aM, sdH, lamT, cT, var_H, var_T, rho):
    """One draw of :func:`gp_errors`: ``h`` the hyperparameters, ``y (E, 2Nf, 2)`` the
    residuals (re, im), ``u (Nf + N,)`` log-frequency of fit ∪ new frequencies, ``aH, aM
    (Nf + N,)`` amplitudes, ``sdH, lamT, cT (E, Nf)`` the measurement-noise factors per re/im
    part, ``var_H, var_T (Nf, n, n)`` the FRF's variance, ``rho`` its H–T correlation;
    returns ``g_H, g_M (E, 2, N)``. The data are arguments (see :func:`gp_corr_chunk`)."""
    E, Nf = y.shape[0], y.shape[1] // 2
    N = u.shape[0] - Nf
    a_j = (aH, aM)
    tau, ell, beta, kap = split_hyper(h)
    # the amplitude slope is learned on the fit band: held constant beyond it
    b = [a_j[i] * jnp.exp(beta[i] * jnp.clip(u, u[0], u[Nf - 1])) for i in range(2)]
    wu = [warp(u, kap[i]) for i in range(2)]
    R = [kernel(wu[i], wu[i], ell[i]) for i in range(2)]  # correlations, unit diagonal
    Ks = [0.5 * tau[i] ** 2 * jnp.outer(b[i], b[i]) * R[i] for i in range(2)]
    C = gp_covariance(u[:Nf], aH[:Nf], aM[:Nf], var_H, var_T, rho, h)
    k1, k2, k3 = jax.random.split(key, 3)
    f = []
    for i, kk in enumerate((k1, k2)):
        # prior draw = amplitude × draw of the unit-variance correlation: the jitter is
        # relative to each frequency's own variance (a jitter relative to the mean
        # diagonal of K is dominated by the kHz amplitudes, ~10¹⁴ × the 1 Hz ones, and
        # added white noise far larger than the error itself at low frequency)
        Lr = jnp.linalg.cholesky(R[i] + 1e-9 * jnp.eye(R[i].shape[0]))
        z = Lr @ jax.random.normal(kk, (Nf + N, 2 * E))
        sd = jnp.sqrt(0.5) * tau[i] * b[i]
        f.append((sd[:, None] * z).T.reshape(E, 2, Nf + N))
    z1, z2 = jax.random.normal(k3, (2, E, 2, Nf))
    eH = sdH[:, None] * z1
    eT = lamT[:, None] * z1 + cT[:, None] * z2
    sim = jnp.concatenate([f[0][..., :Nf] + eH, f[0][..., :Nf] + f[1][..., :Nf] + eT], -1)
    resid = jnp.moveaxis(y, -1, 1) - sim  # (E, 2, 2Nf)
    Lc = jnp.linalg.cholesky(C)[:, None]
    alpha = jax.scipy.linalg.cho_solve((Lc, True), resid[..., None])[..., 0]
    outH = f[0][..., Nf:] + (alpha[..., :Nf] + alpha[..., Nf:]) @ Ks[0][Nf:, :Nf].T
    outM = f[1][..., Nf:] + alpha[..., Nf:] @ Ks[1][Nf:, :Nf].T
    return outH, outM


def gp_chunk(hyper, y, keys, consts, switches_):
    """:func:`_gp_one` vmapped over the draws ``hyper (B, H)``, ``y (B, E, 2Nf, 2)``,
    ``keys (B, 2)``; ``consts`` the shared data (its arguments after ``key``); ``switches_``
    the GP switches at the call (:func:`~hapid.uncertainty._gp.switches`): not used here,
    only part of the compiled program's key."""
    return jax.vmap(lambda h, yy, kk: _gp_one(h, yy, kk, *consts))(hyper, y, keys)


_gp_chunk = cached_jit(gp_chunk)


def _circ(key, shape):
    """Circular complex standard normals of ``shape`` (unit variance)."""
    z = jax.random.normal(key, (2,) + shape)
    return (z[0] + 1j * z[1]) * np.sqrt(0.5)


def _gp_corr_setup(h, E, Nf, u, aH, aM, sdH, sdT, var_H, var_T, rho_n):
    """What every draw of :func:`gp_corr_errors` with hyperparameters ``h`` shares: the
    error sizes ``g`` (two ``(M, E)``), the unit correlations ``R`` and their Cholesky
    factors ``Lr`` (two ``(M, M)``), the residual covariance's Cholesky factor ``Lc (E, 2Nf,
    2Nf)`` and ``ρ``. ``u (M,)`` is log-frequency of fit ∪ new frequencies (``M = Nf + N``),
    ``aH, aM`` ``(M,)`` or ``(E, M)`` amplitudes, ``sdH, sdT (E, Nf)`` and ``var_H, var_T
    (Nf, n, n)`` the FRF's std and variance, ``rho_n`` its H–T correlation."""
    M = u.shape[0]
    tau, ell, beta, kap = split_hyper(h)
    a_all = (aH, aM)
    C = gp_corr_covariance(u[:Nf], aH[..., :Nf], aM[..., :Nf], var_H, var_T, rho_n, h)
    # the amplitude slope is learned on the fit band: held constant beyond it
    g = [
        jnp.broadcast_to(
            tau[i] * a_all[i] * jnp.exp(beta[i] * jnp.clip(u, u[0], u[Nf - 1])), (E, M)
        ).T
        for i in range(2)
    ]  # fmt: skip  (M, E) error sizes
    R, Lr = [], []
    for i in range(2):  # unit-variance latent correlations (relative jitter: see gp_errors)
        wi = corr_warp(u, kap[i])
        R.append(corr_kernel(wi, wi, ell[i]))
        Lr.append(jnp.linalg.cholesky(R[i] + 1e-9 * jnp.eye(M)))
    return g, R, Lr, jnp.linalg.cholesky(C), hm_correlation(h)


def _gp_corr_draw(setup, y, key, sdH, sdT, rho_n, solve):
    """One draw of :func:`gp_corr_errors` given :func:`_gp_corr_setup`'s ``setup``: ``y (E,
    2Nf)`` the residuals ``[r_H, r_T]``, ``solve(r)`` ``C⁻¹ r`` for ``r (E, 2Nf)``; returns
    ``e_H, e_M (E, N)``."""
    g, R, Lr, _, rho = setup
    E, Nf = y.shape[0], y.shape[1] // 2
    M = R[0].shape[0]
    r2 = jnp.abs(rho) ** 2
    k = jax.random.split(key, 4)
    f = [Lr[i] @ _circ(k[i], (M, E)) for i in range(2)]  # (M, E) unit-variance latents
    eH = g[0] * f[0]
    eM = g[1] * (rho * f[0] + jnp.sqrt(1.0 - r2) * f[1])
    z1, z2 = _circ(k[2], (E, Nf)), _circ(k[3], (E, Nf))
    nH = sdH * z1
    nT = sdT * (rho_n * z1 + jnp.sqrt(1.0 - rho_n**2) * z2)
    sim = jnp.concatenate([eH[:Nf].T + nH, (eH[:Nf] + eM[:Nf]).T + nT], -1)  # (E, 2Nf)
    alpha = solve(y - sim)
    aH_, aT_ = alpha[:, :Nf], alpha[:, Nf:]  # (E, Nf)
    # Cov(e_X(*), [r_H; r_T]) C⁻¹ (r − r̃) through the unit correlations k₁, k₂
    # (gp_corr_blocks: K_HH = g_H g_Hᵀ k₁, K_HM = ρ̄ g_H g_Mᵀ k₁, K_MH = ρ g_M g_Hᵀ k₁,
    # K_MM = g_M g_Mᵀ (|ρ|² k₁ + (1 − |ρ|²) k₂); e_T = e_H + e_M)
    vH = g[0][:Nf].T * (aH_ + aT_)
    vM = g[1][:Nf].T * aT_
    k1s, k2s = R[0][Nf:, :Nf], R[1][Nf:, :Nf]  # (N, Nf)
    p1H, p1M, p2M = vH @ k1s.T, vM @ k1s.T, vM @ k2s.T  # (E, N)
    outH = eH[Nf:].T + g[0][Nf:].T * (p1H + jnp.conj(rho) * p1M)
    outM = eM[Nf:].T + g[1][Nf:].T * (rho * p1H + r2 * p1M + (1.0 - r2) * p2M)
    return outH, outM


def gp_corr_chunk(hyper, y, keys, consts, switches_):
    """Draws of :func:`gp_corr_errors` for ``hyper (B, H)``, ``y (B, E, 2Nf)``, ``keys (B,
    2)``; ``consts = (u, aH, aM, sdH, sdT, var_H, var_T, rho_n)`` the shared data
    (:func:`_gp_corr_setup`). The data are arguments, not constants, so one compiled program
    serves every data set of these shapes (:func:`~hapid.uncertainty.holdout_check`);
    ``switches_`` only keys the program (:func:`gp_chunk`)."""
    E, Nf = y.shape[1], y.shape[2] // 2
    sdH, sdT, rho_n = consts[3], consts[4], consts[7]

    def one(h, yy, kk):
        setup = _gp_corr_setup(h, E, Nf, *consts)
        solve = lambda r: jax.scipy.linalg.cho_solve((setup[3], True), r[..., None])[..., 0]  # noqa: E731
        return _gp_corr_draw(setup, yy, kk, sdH, sdT, rho_n, solve)

    return jax.vmap(one)(hyper, y, keys)


def gp_corr_chunk_shared(hyper, y, keys, consts, switches_):
    """:func:`gp_corr_chunk` when every draw has the hyperparameters ``hyper[0]`` (the
    marginal mode or the MAP, the default): the covariance and its factors once per chunk,
    not once per draw, and ``C⁻¹`` as a matrix: each draw's solve is then a matrix product
    (XLA:CPU runs a batch of small triangular solves one matrix at a time); ``switches_``
    only keys the program (:func:`gp_chunk`)."""
    E, Nf = y.shape[1], y.shape[2] // 2
    setup = _gp_corr_setup(hyper[0], E, Nf, *consts)
    Lc = setup[3]
    eye = jnp.broadcast_to(jnp.eye(Lc.shape[-1], dtype=Lc.dtype), Lc.shape)
    Cinv = jax.scipy.linalg.cho_solve((Lc, True), eye)  # (E, 2Nf, 2Nf)
    solve = lambda r: jnp.einsum("eij,ej->ei", Cinv, r)  # noqa: E731
    sdH, sdT, rho_n = consts[3], consts[4], consts[7]
    return jax.vmap(lambda yy, kk: _gp_corr_draw(setup, yy, kk, sdH, sdT, rho_n, solve))(y, keys)


_gp_corr_chunk_shared = cached_jit(gp_corr_chunk_shared)
_gp_corr_chunk = cached_jit(gp_corr_chunk)
