"""Test oracles: independent reference implementations and example inputs, written without
the code paths they check (numpy only, no JAX).

- :func:`example_model` — a random but physically plausible ``n``-rod second-order model
  (rod-space coupling; not a device simulation), to exercise control code on its own.
- :func:`log_prob_numpy` — :class:`hapid.uncertainty.LogPosterior`'s log-probability rebuilt
  with explicit loops and ``numpy.linalg.solve`` / ``slogdet`` per element.

Benchmarks import this module too (``sys.path`` gets ``tests/``).
"""

from __future__ import annotations

import numpy as np

from hapid.impedance import ImpedanceModel, SecondOrder


def _spd(rng, n, lo, hi, Q):
    return Q @ np.diag(rng.uniform(lo, hi, n)) @ Q.T


def example_model(n: int = 5, seed: int = 0) -> ImpedanceModel:
    """A random but physically plausible ``n``-rod model (SI units, rod space).

    Hand: M_H eigenvalues 0.1–0.5 kg, B_H 2–20 N·s/m, K_H 200–1000 N/m, coupled by a random
    rotation; mechanism: diagonal 0.4–0.6 kg, 20–40 N·s/m, no stiffness. ``Ẑ_T = Ẑ_H + Ẑ_M``.
    All matrices symmetric positive definite, so both impedances have OLHP roots.
    """
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    hand = SecondOrder(
        M=_spd(rng, n, 0.1, 0.5, Q), B=_spd(rng, n, 2.0, 20.0, Q), K=_spd(rng, n, 200.0, 1000.0, Q)
    )
    mech = SecondOrder(
        M=np.diag(rng.uniform(0.4, 0.6, n)),
        B=np.diag(rng.uniform(20.0, 40.0, n)),
        K=np.zeros((n, n)),
    )
    hand = SecondOrder(*(np.asarray(x) for x in (hand.M, hand.B, hand.K)))
    return ImpedanceModel.from_hand_mechanism(hand, mech)


def log_prob_numpy(post, xs) -> np.ndarray:
    """``post.log_prob(xs)`` computed with numpy only (``(W, d) → (W,)``)."""
    xs = np.atleast_2d(np.asarray(xs, dtype=np.float64))
    n, p = post.n, post.n_free
    s = np.asarray(post.s)
    ZH_d, ZT_d = np.asarray(post.Z_H), np.asarray(post.Z_T)
    sH2, sT2 = np.asarray(post.var_H), np.asarray(post.var_T)
    aH, aM = np.asarray(post.a_H), np.asarray(post.a_M)
    W = xs.shape[0]
    out = np.empty(W)
    for w in range(W):
        theta = post.full_theta_numpy(xs[w])
        mats = []
        k = 0
        for _ in range(6):  # θ: the lower-triangular entries of each symmetric matrix
            L = np.zeros((n, n))
            for i in range(n):
                for j in range(i + 1):
                    L[i, j] = theta[k]
                    k += 1
            mats.append(L + L.T - np.diag(np.diag(L)))
        MH, BH, KH, MM, BM, KM = mats
        S = s[:, None, None]
        ZH = MH * S**2 + BH * S + KH
        ZT = ZH + MM * S**2 + BM * S + KM
        r = np.stack([ZH - ZH_d, ZT - ZT_d], axis=-1)  # (N, n, n, 2)
        white = post.error.n_hyper > 0  # NoError or White: the oracle's two kinds
        if white:
            tH, tM = np.exp(xs[w, p]), np.exp(xs[w, p + 1])
            vH = ((tH * aH) ** 2)[:, None, None]
            vM = ((tM * aM) ** 2)[:, None, None]
        else:
            vH = vM = 0.0
        jit = 1e-12 * ((aH + aM) ** 2)[:, None, None]
        C = np.empty(r.shape + (2,))
        C[..., 0, 0] = sH2 + vH + jit
        C[..., 1, 1] = sT2 + vH + vM + jit
        C[..., 0, 1] = C[..., 1, 0] = post.noise_corr * np.sqrt(sH2 * sT2) + vH
        Cr = np.linalg.solve(C.astype(complex), r[..., None])[..., 0]
        quad = np.real(np.sum(np.conj(r) * Cr, axis=-1))
        _, logdet = np.linalg.slogdet(C)
        ll = np.sum(-2 * np.log(np.pi) - logdet - quad)
        lp = np.sum(
            -0.5 * (xs[w, :p] / post.prior_scale) ** 2
            - np.log(post.prior_scale * np.sqrt(2 * np.pi))
        )
        if white:
            m, sd = post.error.log_tau_mean, post.error.log_tau_sd
            z = (xs[w, p:] - m) / sd
            lp += np.sum(-0.5 * z**2 - np.log(sd * np.sqrt(2 * np.pi)))
        if post.psd_constraint and min(np.linalg.eigvalsh(A)[0] for A in mats) < -1e-12 * max(
            np.abs(np.linalg.eigvalsh(A)).max() for A in mats
        ):
            lp = -np.inf
        v = ll + lp
        out[w] = v if np.isfinite(v) else -np.inf
    return out
