# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Posterior-predictive credible bands of impedances and plants (vmapped over samples).

Quantities (each per frequency ω, ``(N, …)``; linear magnitudes, convert to dB yourself):

- ``"abs_Z_H"``, ``"abs_Z_T"`` — element magnitudes ``|Ẑ_ij|`` (``(N, n, n)``);
- ``"sv_Z_H"``, ``"sv_Z_T"`` — singular values, descending (``(N, n)``);
- ``"sv_P"`` — singular values of ``P̂ = Ẑ_H Ẑ_T⁻¹`` (``(N, n)``);
- ``"sv_P_Phatinv"`` — singular values of ``P P̂⁻¹`` with ``P = P_ref`` the measured or true
  plant (``(N, n)``; ``P_ref`` required). Its band around 0 dB is the paper's model-quality
  figure.

Band ``q`` levels are quantiles over the samples, per frequency and per index (singular
values are sorted per sample before the quantile, so the k-th band is the band of the k-th
largest singular value).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._linalg import svdvals
from ..fit._pd import theta_to_model
from ..impedance import plant
from ..samples import PosteriorSamples
from ._gp import (
    GP_CORR_KERNEL,
    KERNELS,
    corr_warp,
    gp_corr_covariance,
    gp_covariance,
    hm_correlation,
    kernel,
    split_hyper,
    warp,
)
from ._weights import element_weights, gp_amplitudes

QUANTITIES = ("abs_Z_H", "abs_Z_T", "sv_Z_H", "sv_Z_T", "sv_P", "sv_P_Phatinv")


@eqx.filter_jit
def _chunk(theta, scale, s, P_ref, names):
    def one(t):
        m = theta_to_model(t, scale)
        ZH, ZT = m.hand(s), m.total(s)
        out = {}
        if "abs_Z_H" in names:
            out["abs_Z_H"] = jnp.abs(ZH)
        if "abs_Z_T" in names:
            out["abs_Z_T"] = jnp.abs(ZT)
        if "sv_Z_H" in names:
            out["sv_Z_H"] = svdvals(ZH)
        if "sv_Z_T" in names:
            out["sv_Z_T"] = svdvals(ZT)
        if "sv_P" in names:
            out["sv_P"] = svdvals(plant(ZH, ZT))
        if "sv_P_Phatinv" in names:
            # P P̂⁻¹ = P Ẑ_T Ẑ_H⁻¹
            out["sv_P_Phatinv"] = svdvals(plant(P_ref @ ZT, ZH))
        return out

    return jax.vmap(one)(theta)


def predictive_samples(
    ps: PosteriorSamples, omega, quantities=("sv_Z_H", "sv_Z_T", "sv_P"), P_ref=None,
    chunk: int = 500, max_samples: int | None = 2000, seed: int = 0,
) -> dict[str, np.ndarray]:  # fmt: skip
    """Per-sample quantities ``{name: (S', N, …)}`` on ``omega`` (rad/s), computed in chunks.

    At most ``max_samples`` samples are used (a random subset, ``seed``); ``None`` = all.
    """
    names = tuple(quantities)
    bad = [q for q in names if q not in QUANTITIES]
    if bad:
        raise ValueError(f"unknown quantities {bad}; choose from {QUANTITIES}")
    omega = jnp.asarray(omega, dtype=jnp.float64)
    if omega.ndim != 1:
        raise ValueError(f"omega must be (N,), got shape {omega.shape}")
    if "sv_P_Phatinv" in names:
        if P_ref is None:
            raise ValueError("sv_P_Phatinv needs P_ref (N, n, n): the measured or true plant")
        P_ref = jnp.asarray(P_ref, dtype=jnp.complex128)
        if P_ref.shape != (omega.shape[0], ps.n, ps.n):
            raise ValueError(f"P_ref must be ({omega.shape[0]}, {ps.n}, {ps.n}), got {P_ref.shape}")
    else:
        P_ref = jnp.zeros((1, 1, 1), dtype=jnp.complex128)
    theta = ps.theta
    if max_samples is not None and theta.shape[0] > max_samples:
        idx = np.random.default_rng(seed).choice(theta.shape[0], max_samples, replace=False)
        theta = theta[np.sort(idx)]
    s = 1j * omega
    parts = [
        _chunk(jnp.asarray(theta[i : i + chunk]), ps.scale, s, P_ref, names)
        for i in range(0, theta.shape[0], chunk)
    ]
    return {k: np.concatenate([np.asarray(p[k]) for p in parts]) for k in names}


def credible_bands(
    ps: PosteriorSamples, omega, quantities=("sv_Z_H", "sv_Z_T", "sv_P"), P_ref=None,
    q=(0.05, 0.5, 0.95), chunk: int = 500, max_samples: int | None = 2000, seed: int = 0,
) -> dict[str, np.ndarray]:  # fmt: skip
    """Credible bands ``{name: (len(q), N, …)}`` of the quantities (module docstring) over
    the posterior samples, on ``omega`` (rad/s). Default levels 5/50/95 %."""
    qs = np.asarray(q, dtype=float)
    if np.any((qs < 0) | (qs > 1)):
        raise ValueError(f"quantile levels must be in [0, 1], got {q}")
    per = predictive_samples(ps, omega, quantities, P_ref, chunk, max_samples, seed)
    return {k: np.quantile(v, qs, axis=0) for k, v in per.items()}


# --- predictive draws of the plant, model error included ------------------------------


def _taper(omega, lo, hi, width: float = 0.5):
    """1 on [lo, hi], raised-cosine to 0 within ``width`` (natural-log units) outside."""
    lw = np.log(omega)
    d = np.maximum(np.log(lo) - lw, 0.0) + np.maximum(lw - np.log(hi), 0.0)
    return np.where(d >= width, 0.0, 0.5 * (1.0 + np.cos(np.pi * np.minimum(d / width, 1.0))))


def _interp_log(x_new, x, y):
    """``y(x)`` log-log interpolated at ``x_new`` (constant beyond the ends)."""
    return np.exp(np.interp(np.log(x_new), np.log(x), np.log(np.maximum(y, 1e-300))))


def predictive_plants(ps: PosteriorSamples, omega, *, max_samples: int | None = 500, seed: int = 0,
                      include_error: bool = True, error_band=None,
                      taper_width: float = 0.5) -> dict[str, np.ndarray]:  # fmt: skip
    """Posterior-predictive draws of the *true* ``Z_H, Z_T, P = Z_H Z_T⁻¹`` on ``omega`` (rad/s,
    any grid), including the model-error term — not only parameter uncertainty.

    Per draw ``(θ, τ, ℓ, β, κ)``: ``Z(θ)`` of the second-order model plus the model-error
    function drawn from its posterior *given that draw's fit residuals* (with ``hyper="map"``,
    the default, the hyperparameters are the same in every draw — their posterior mode — and
    only θ varies; files with six gp columns are read with κ = 0):

    - ``"gp"`` samples: the error functions ``e_H, e_M`` (per element, re and im) are the GP
      of :func:`hapid.uncertainty._likelihood.gp_covariance`; the draw at ``omega`` is the
      exact GP conditional on the residuals ``[Ẑ_H − Z_H(θ); Ẑ_T − Z_T(θ)]`` at the fit
      frequencies (pathwise: a joint prior draw on fit ∪ new frequencies corrected by
      ``K_{*x} C⁻¹ (r − ỹ)``, Matheron's rule). Far from the fit band it reverts to the prior
      (amplitude ``τ a(ω)``, :func:`~hapid.uncertainty._likelihood.gp_amplitudes`, with the
      slope factor ``(ω/ω_ref)^β`` held at its band-edge value beyond the fit band).
    - ``"gp_corr"`` samples: the same exact conditional for the correlated model (shared
      latent function of ``e_H`` and ``e_M``, complex ρ, asinh knee coordinate:
      :func:`hapid.uncertainty._likelihood.gp_corr_blocks`), in complex circular form.
    - ``"white"`` samples: independent circular errors of variance ``τ² a(ω)²`` at each new
      frequency (``a`` log-log interpolated from the fit band): the white model has no
      correlation to condition on.
    - no model error (or ``include_error=False``): ``Z(θ)`` only.

    ``error_band = (ω_lo, ω_hi)`` (rad/s, optional) confines the error term to that band: it
    is multiplied by a taper that is 1 inside and falls to 0 (raised cosine) within a factor
    e^taper_width of frequency outside — for loop analyses that need a rational plant far from
    the data (see :func:`hapid.tune._recipe.predictive_scenario_plants`).

    ``Z_T`` carries ``e_H + e_M`` (``Z_T = Z_H + Z_M``). Returns ``{"omega": (N,), "Z_H",
    "Z_T", "P": (S', N, n, n)}`` with at most ``max_samples`` draws (random subset, ``seed``).
    """
    omega = np.asarray(omega, dtype=np.float64)
    if (
        omega.ndim != 1
        or omega.shape[0] < 1
        or not np.all(np.isfinite(omega))
        or np.any(omega <= 0)
    ):
        raise ValueError(
            "predictive_plants: omega must be a 1-D array of positive frequencies (rad/s)"
        )
    rng = np.random.default_rng(seed)
    S = ps.n_samples
    idx = np.arange(S)
    if max_samples is not None and S > max_samples:
        idx = np.sort(rng.choice(S, max_samples, replace=False))
    theta = ps.theta[idx]
    kind = ps.error_kind if include_error else "none"
    data = ps.predictive
    if kind != "none" and data is None:
        raise ValueError("predictive_plants: these samples carry no fit data (old file or Laplace-NLS "
                         "draws); rerun hapid posterior, or pass include_error=False")  # fmt: skip
    n = ps.n
    ms = jax.vmap(lambda t: theta_to_model(t, ps.scale))(jnp.asarray(theta))
    s_new = 1j * jnp.asarray(omega)
    ZH = np.asarray(jax.vmap(lambda m: m.hand(s_new))(ms))
    ZM = np.asarray(jax.vmap(lambda m: m.mechanism(s_new))(ms))
    S_, N = ZH.shape[:2]
    if kind == "white":
        tau = ps.tau[idx]
        om_fit = np.asarray(data["omega"])
        aH = _interp_log(omega, om_fit, np.asarray(data["a_H"]))
        aM = _interp_log(omega, om_fit, np.asarray(data["a_M"]))
        if error_band is not None:
            w = _taper(omega, *error_band, taper_width)
            aH, aM = aH * w, aM * w

        def circ(sd):  # (S, N) → circular complex (S, N, n, n) with E|e|² = sd²
            z = rng.standard_normal((2, S_, N, n, n)) * np.sqrt(0.5)
            return (z[0] + 1j * z[1]) * sd[:, :, None, None]

        ZH = ZH + circ(tau[:, :1] * aH[None])
        ZM = ZM + circ(tau[:, 1:2] * aM[None])
    elif kind == "gp_corr":
        gH, gM = _gp_corr_errors(ps, idx, ms, omega, rng)
        if error_band is not None:
            w = _taper(omega, *error_band, taper_width)[None, :, None, None]
            gH, gM = gH * w, gM * w
        ZH, ZM = ZH + gH, ZM + gM
    elif kind == "gp":
        hyper = ps.samples[idx, ps.n_theta :]
        om_fit = np.asarray(data["omega"])
        Nf = om_fit.shape[0]
        ref = np.asarray(data["ref_theta"])
        aH_f, aM_f = np.asarray(data["a_H"]), np.asarray(data["a_M"])
        aH_n, aM_n = gp_amplitudes(omega, om_fit, (aH_f, aM_f), ref, ps.scale)
        sf = 1j * jnp.asarray(om_fit)
        ZHf = np.asarray(jax.vmap(lambda m: m.hand(sf))(ms))
        ZTf = np.asarray(jax.vmap(lambda m: m.total(sf))(ms))
        rH, rT = np.asarray(data["Z_H"])[None] - ZHf, np.asarray(data["Z_T"])[None] - ZTf
        var_H, var_T = np.asarray(data["var_H"]), np.asarray(data["var_T"])
        rho = float(data["noise_corr"])
        u = np.log(np.concatenate([om_fit, omega]) / float(np.asarray(ps.scale.omega_ref)))
        a_all = (np.concatenate([aH_f, aH_n]), np.concatenate([aM_f, aM_n]))
        E = n * n
        dH = 0.5 * var_H.reshape(Nf, E).T  # (E, Nf)
        dT = 0.5 * var_T.reshape(Nf, E).T
        dHT = rho * np.sqrt(dH * dT)
        cond_T = np.sqrt(
            np.clip(dT - np.where(dH > 0, dHT**2 / np.where(dH > 0, dH, 1), 0), 0, None)
        )
        flat = lambda r: np.moveaxis(r.reshape(r.shape[0], Nf, E), 1, 2)  # noqa: E731  (S, E, Nf)
        y_all = np.stack([np.concatenate([flat(rH.real), flat(rT.real)], -1),
                          np.concatenate([flat(rH.imag), flat(rT.imag)], -1)], -1)  # fmt: skip
        gH = np.empty((S_, N, n, n), complex)
        gM = np.empty((S_, N, n, n), complex)
        u_j, a_j = jnp.asarray(u), tuple(jnp.asarray(a) for a in a_all)
        sdH, cT = jnp.sqrt(jnp.asarray(dH)), jnp.asarray(cond_T)
        lamT = jnp.asarray(np.where(dH > 0, dHT / np.where(dH > 0, np.sqrt(dH), 1), 0))

        def one(h, y, key):  # y (E, 2Nf, 2): residuals; returns gH, gM (E, 2, N)
            tau, ell, beta, kap = split_hyper(h)
            # the amplitude slope is learned on the fit band: held constant beyond it
            b = [a_j[i] * jnp.exp(beta[i] * jnp.clip(u_j, u_j[0], u_j[Nf - 1])) for i in range(2)]
            wu = [warp(u_j, kap[i]) for i in range(2)]
            R = [kernel(wu[i], wu[i], ell[i]) for i in range(2)]  # correlations, unit diagonal
            Ks = [0.5 * tau[i] ** 2 * jnp.outer(b[i], b[i]) * R[i] for i in range(2)]
            C = gp_covariance(u_j[:Nf], a_j[0][:Nf], a_j[1][:Nf], var_H, var_T, rho, h)
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

        run = jax.jit(jax.vmap(one))
        keys = jax.random.split(jax.random.PRNGKey(int(rng.integers(2**31))), S_)
        parts = [run(jnp.asarray(hyper[i : i + 50]), jnp.asarray(y_all[i : i + 50]), keys[i : i + 50])
                 for i in range(0, S_, 50)]  # fmt: skip
        oH = np.concatenate([np.asarray(p[0]) for p in parts])  # (S, E, 2, N)
        oM = np.concatenate([np.asarray(p[1]) for p in parts])
        cplx = lambda o: np.moveaxis(o[:, :, 0] + 1j * o[:, :, 1], 1, 2).reshape(S_, N, n, n)  # noqa: E731
        gH, gM = cplx(oH), cplx(oM)
        if error_band is not None:
            w = _taper(omega, *error_band, taper_width)[None, :, None, None]
            gH, gM = gH * w, gM * w
        ZH, ZM = ZH + gH, ZM + gM
    ZT = ZH + ZM
    return {"omega": omega, "Z_H": ZH, "Z_T": ZT, "P": np.asarray(plant(ZH, ZT))}


def _gp_corr_errors(ps: PosteriorSamples, idx, ms, omega, rng):
    """Model-error draws ``(e_H, e_M)``, each ``(S, N, n, n)`` complex, of gp_corr samples on
    ``omega`` (rad/s): the exact GP conditional on each draw's fit residuals (Matheron's rule
    in the complex circular form: a joint prior draw of the shared latent ``f₁`` and of ``f₂``
    on fit ∪ new frequencies, corrected by ``Cov(e_*, r) C⁻¹ (r − r̃)``;
    :func:`hapid.uncertainty._likelihood.gp_corr_blocks`)."""
    data = ps.predictive
    n, E = ps.n, ps.n * ps.n
    hyper = ps.samples[idx, ps.n_theta :]
    om_fit = np.asarray(data["omega"])
    Nf, N = om_fit.shape[0], omega.shape[0]
    aH_f, aM_f = np.asarray(data["a_H"]), np.asarray(data["a_M"])
    aH_n, aM_n = gp_amplitudes(omega, om_fit, (aH_f, aM_f), np.asarray(data["ref_theta"]), ps.scale)
    sf = 1j * jnp.asarray(om_fit)
    ZHf = np.asarray(jax.vmap(lambda m: m.hand(sf))(ms))
    ZTf = np.asarray(jax.vmap(lambda m: m.total(sf))(ms))
    rH, rT = np.asarray(data["Z_H"])[None] - ZHf, np.asarray(data["Z_T"])[None] - ZTf
    S_ = rH.shape[0]
    flat = lambda r: np.moveaxis(r.reshape(S_, Nf, E), 1, 2)  # noqa: E731  (S, E, Nf)
    y_all = np.concatenate([flat(rH), flat(rT)], -1)  # (S, E, 2Nf) complex
    var_H, var_T = np.asarray(data["var_H"]), np.asarray(data["var_T"])
    rho_n = float(data["noise_corr"])
    sdH = jnp.asarray(np.sqrt(var_H.reshape(Nf, E).T))  # (E, Nf)
    sdT = jnp.asarray(np.sqrt(var_T.reshape(Nf, E).T))
    om_all = np.concatenate([om_fit, omega])
    u = jnp.asarray(np.log(om_all / float(np.asarray(ps.scale.omega_ref))))
    a_all = (np.concatenate([aH_f, aH_n]), np.concatenate([aM_f, aM_n]))  # (Nf + N,) each
    scale_kind = str(data.get("error_scale", "shared"))
    if scale_kind == "element":  # per element: (E, Nf + N)
        w = element_weights(np.asarray(data["ref_theta"]), ps.scale, om_all)
        a_all = tuple(a[None] * wi for a, wi in zip(a_all, w, strict=True))
    a_all = tuple(jnp.asarray(a) for a in a_all)
    M = Nf + N

    def circ(key, shape):  # circular complex, unit variance
        z = jax.random.normal(key, (2,) + shape)
        return (z[0] + 1j * z[1]) * np.sqrt(0.5)

    def one(h, y, key):  # y (E, 2Nf) complex; returns e_H, e_M (E, N)
        tau, ell, beta, kap = split_hyper(h)
        rho = hm_correlation(h)
        r2 = jnp.abs(rho) ** 2
        C = gp_corr_covariance(u[:Nf], a_all[0][..., :Nf], a_all[1][..., :Nf], var_H, var_T,
                               rho_n, h)  # fmt: skip
        # the amplitude slope is learned on the fit band: held constant beyond it
        g = [
            jnp.broadcast_to(
                tau[i] * a_all[i] * jnp.exp(beta[i] * jnp.clip(u, u[0], u[Nf - 1])), (E, M)
            ).T
            for i in range(2)
        ]  # fmt: skip  (M, E) error sizes
        k = jax.random.split(key, 4)
        R, f = [], []
        for i in range(2):  # unit-variance latent draws (relative jitter: see the gp branch)
            wi = corr_warp(u, kap[i])
            R.append(KERNELS[GP_CORR_KERNEL](wi, wi, ell[i]))
            Lr = jnp.linalg.cholesky(R[i] + 1e-9 * jnp.eye(M))
            f.append(Lr @ circ(k[i], (M, E)))  # (M, E)
        eH = g[0] * f[0]
        eM = g[1] * (rho * f[0] + jnp.sqrt(1.0 - r2) * f[1])
        z1, z2 = circ(k[2], (E, Nf)), circ(k[3], (E, Nf))
        nH = sdH * z1
        nT = sdT * (rho_n * z1 + np.sqrt(1.0 - rho_n**2) * z2)
        sim = jnp.concatenate([eH[:Nf].T + nH, (eH[:Nf] + eM[:Nf]).T + nT], -1)  # (E, 2Nf)
        Lc = jnp.linalg.cholesky(C)
        alpha = jax.scipy.linalg.cho_solve((Lc, True), (y - sim)[..., None])[..., 0]
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

    run = jax.jit(jax.vmap(one))
    keys = jax.random.split(jax.random.PRNGKey(int(rng.integers(2**31))), S_)
    parts = [run(jnp.asarray(hyper[i : i + 50]), jnp.asarray(y_all[i : i + 50]), keys[i : i + 50])
             for i in range(0, S_, 50)]  # fmt: skip
    cplx = lambda o: np.moveaxis(o, 1, 2).reshape(S_, N, n, n)  # noqa: E731  (S, E, N) → (S, N, n, n)
    return (cplx(np.concatenate([np.asarray(p[0]) for p in parts])),
            cplx(np.concatenate([np.asarray(p[1]) for p in parts])))  # fmt: skip


def band_calibration(draws, truth, level: float = 0.9, n_reference: int = 20) -> dict[str, float]:
    """How well predictive draws ``(S, N, n, n)`` (complex) describe a true response
    ``(N, n, n)`` over ``N`` frequencies.

    The band at frequency ω is the ``level`` credible *ball* around the draws' (elementwise
    re/im) median ``X̃``: radius ``r(ω) = q_level(‖X_s − X̃‖_F)``; the actual error is
    ``e(ω) = ‖X_true − X̃‖_F`` (Frobenius norm of the complex matrix, i.e. the Euclidean norm
    of its ``2n²`` real numbers).

    - ``coverage`` — fraction of frequencies with ``e ≤ r`` (nominal: ``level``);
    - ``width_ratio`` — median over frequencies of ``r(ω)/e(ω)``: the band's *half*-width (its
      radius) in units of the actual error at the same frequency (scale-free, so frequencies
      where P is large do not dominate). A perfectly calibrated Gaussian band gives
      ``q_level(χ_m)/q_50(χ_m)`` for ``m`` real dimensions of equal spread — 2.44 (m = 1),
      1.82 (a circular complex scalar), 1.22 (3 × 3 complex), 1.13 (5 × 5) — and a value
      between these for an elongated band;
    - ``width_ratio_calibrated``, ``coverage_calibrated`` — the same two numbers with the
      truth replaced by one of the draws (mean over ``n_reference`` of them): what *this* band
      would give if it were exactly calibrated, the yardstick for ``width_ratio``;
    - ``width_ratio_of_medians`` — ``median_ω r / median_ω e`` (the earlier definition);
    - ``element_coverage`` — fraction of (frequency, element, re/im) whose central ``level``
      interval holds the truth;
    - ``rel_error_median`` — median of ``e / ‖X_true‖_F``; ``rel_radius_median`` — median of
      ``r / ‖X_true‖_F`` (the band's half-width relative to the response itself: a band can
      meet ``width_ratio`` by being centred badly, this says how wide it is in absolute terms).
    """
    X = np.asarray(draws)
    T = np.asarray(truth)
    if X.ndim != 4 or T.shape != X.shape[1:]:
        raise ValueError(
            f"band_calibration: draws (S, N, n, n) and truth (N, n, n), got {X.shape}, {T.shape}"
        )
    med = np.median(X.real, 0) + 1j * np.median(X.imag, 0)
    d = np.linalg.norm(X - med[None], axis=(-2, -1))  # (S, N)
    r = np.quantile(d, level, axis=0)
    e = np.linalg.norm(T - med, axis=(-2, -1))
    tiny = 1e-300
    ref = d[: max(1, min(n_reference, X.shape[0]))]  # draws standing in for the truth
    lo_q, hi_q = (1 - level) / 2, 1 - (1 - level) / 2
    inside = []
    for part in (np.real, np.imag):
        lo, hi = np.quantile(part(X), [lo_q, hi_q], axis=0)
        inside.append((part(T) >= lo) & (part(T) <= hi))
    return {"coverage": float(np.mean(e <= r)),
            "width_ratio": float(np.median(r / np.maximum(e, tiny))),
            "width_ratio_calibrated": float(np.mean(np.median(r / np.maximum(ref, tiny), axis=1))),
            "coverage_calibrated": float(np.mean(ref <= r)),
            "width_ratio_of_medians": float(np.median(r) / np.median(e)),
            "element_coverage": float(np.mean(inside)),
            "rel_error_median": float(np.median(e / np.linalg.norm(T, axis=(-2, -1)))),
            "rel_radius_median": float(np.median(r / np.linalg.norm(T, axis=(-2, -1))))}  # fmt: skip
