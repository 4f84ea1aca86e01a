"""A plain-numpy implementation of :class:`LogPosterior` (reference for tests and benchmarks).

Written independently of the JAX code path: it rebuilds each factor from θ with explicit
loops, forms the 2 × 2 complex covariance per element and uses ``numpy.linalg.solve`` /
``slogdet`` on it (no closed-form inverse). Vectorized over walkers only through numpy
broadcasting; no JAX.
"""

from __future__ import annotations

import numpy as np


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
        matrix = getattr(post, "parameterization", "cholesky") == "matrix"
        for _ in range(6):
            L = np.zeros((n, n))
            for i in range(n):
                for j in range(i + 1):
                    L[i, j] = abs(theta[k]) if i == j and not matrix else theta[k]
                    k += 1
            mats.append(L + L.T - np.diag(np.diag(L)) if matrix else L @ L.T)
        MH, BH, KH, MM, BM, KM = mats
        S = s[:, None, None]
        ZH = MH * S**2 + BH * S + KH
        ZT = ZH + MM * S**2 + BM * S + KM
        r = np.stack([ZH - ZH_d, ZT - ZT_d], axis=-1)  # (N, n, n, 2)
        if post.model_error:
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
        if post.model_error:
            z = (xs[w, p:] - post.log_tau_mean) / post.log_tau_sd
            lp += np.sum(-0.5 * z**2 - np.log(post.log_tau_sd * np.sqrt(2 * np.pi)))
        if (
            matrix
            and post.psd_constraint
            and min(np.linalg.eigvalsh(A)[0] for A in mats)
            < -1e-12 * max(np.abs(np.linalg.eigvalsh(A)).max() for A in mats)
        ):
            lp = -np.inf
        v = ll + lp
        out[w] = v if np.isfinite(v) else -np.inf
    return out
