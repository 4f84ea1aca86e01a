"""Grid exchange: the margin constraints hold between the training grid's points too.

The smooth design problem (:mod:`._objective`) imposes ``|1 + g λ_i(Q)| ≥ 1/M_s`` on the
training grid only — a semi-infinite constraint sampled at ``N`` points. A lightly damped
plant mode between two points (cu5's chain mode at ≈ 171 Hz: the tuner's 300-point grid
steps 2.9 %) is invisible to it: the paper scene's tuner once returned a g that met the
constraint at every training point and had GM 2.0 dB on *every* training plant on the
analysis grid.

The exchange method closes that gap. A family may carry the same scenarios on a denser grid
(:attr:`.Family.dense`); after each continuation stage :func:`violations` evaluates the
margin constraint there exactly (no soft max) and :func:`exchange` moves the dense
frequencies where it is violated — and worse than anywhere on the training grid — into the
training grid; :func:`hapid.tune.tune` then repeats the stage. A family whose dense check
finds nothing keeps its grid, so designs that were right stay bit for bit the same.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from ._response import g_response
from ._scenarios import Scenarios

TOL = 0.01
"""Violation (natural-log units of ``|1 + ℓ|``, ≈ 0.09 dB) that counts on the dense grid."""
MAX_ADD = 24
"""Most dense frequencies added to one family per exchange (the worst local maxima)."""


def locus_violation(g, sc: Scenarios, ms: float) -> np.ndarray:
    """``(S, N)``: ``max_i −log|1 + g λ_i(jω)| − log M_s`` (≤ 0 met) on ``sc``'s grid."""
    gam = np.asarray(g_response(g, sc.omega, sc.ts))
    d = np.abs(1.0 + gam[None, :, None] * np.asarray(sc.lam))
    return -np.log(np.min(d, axis=-1)) - np.log(ms)


def violations(g, family, ms: float, tol: float = TOL) -> np.ndarray:
    """Indices into ``family.dense.omega`` to add to the training grid (sorted, at most
    :data:`MAX_ADD`): frequencies where some scenario violates the margin constraint by more
    than ``tol`` and by more than ``tol`` beyond that scenario's worst training-grid value,
    at the local maxima (over frequency) of the worst such excess. Empty when the training
    grid saw everything, or the family has no dense grid or no margin constraint."""
    dense = family.dense
    if dense is None or not family.margins:
        return np.zeros(0, int)
    v_tr = locus_violation(g, family.scenarios, ms).max(axis=1)  # (S,)
    v = locus_violation(g, dense, ms)  # (S, Nd)
    excess = np.where(v > np.maximum(v_tr, 0.0)[:, None] + tol, v, -np.inf).max(axis=0)
    if not np.any(np.isfinite(excess)):
        return np.zeros(0, int)
    have = np.isin(np.asarray(dense.omega), np.asarray(family.scenarios.omega))
    excess = np.where(have, -np.inf, excess)
    pad = np.concatenate([[-np.inf], excess, [-np.inf]])
    peak = np.isfinite(excess) & (excess >= pad[:-2]) & (excess >= pad[2:])
    idx = np.nonzero(peak)[0]
    idx = idx[np.argsort(excess[idx])[::-1][:MAX_ADD]]
    return np.sort(idx)


def at_freqs(sc: Scenarios, idx) -> Scenarios:
    """``sc`` restricted to the frequencies ``idx`` (same scenarios)."""
    idx = np.asarray(idx)
    return dataclasses.replace(sc, omega=sc.omega[idx], lam=sc.lam[:, idx], V=sc.V[:, idx],
                               Vi=sc.Vi[:, idx])  # fmt: skip


def merge_freqs(train: Scenarios, dense: Scenarios, idx) -> Scenarios:
    """The training scenarios with ``dense``'s frequencies ``idx`` added (grid sorted)."""
    add = at_freqs(dense, idx)
    omega = jnp.concatenate([train.omega, add.omega])
    order = np.argsort(np.asarray(omega), kind="stable")
    cat = lambda a, b: jnp.concatenate([a, b], axis=1)[:, order]  # noqa: E731
    return dataclasses.replace(train, omega=omega[order], lam=cat(train.lam, add.lam),
                               V=cat(train.V, add.V), Vi=cat(train.Vi, add.Vi))  # fmt: skip


def exchange(g, families, ms: float, tol: float = TOL):
    """``(families, added)``: every family with the dense frequencies :func:`violations`
    finds merged into its training grid; ``added`` the number of frequencies per family."""
    out, added = [], []
    for f in families:
        idx = violations(g, f, ms, tol)
        added.append(int(idx.size))
        out.append(f if idx.size == 0 else
                   dataclasses.replace(f, scenarios=merge_freqs(f.scenarios, f.dense, idx)))  # fmt: skip
    return out, added
