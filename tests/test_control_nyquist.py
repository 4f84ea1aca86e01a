"""Generalized Nyquist verdict vs closed-loop state-space poles; singular I + PG; loci."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from oracle_loop import analyze_loop

import hapid  # noqa: F401  (float64)
from hapid.control import StateSpace, characteristic_loci, closed_loop_poles


def _random_A(rng, nx, n_unstable):
    """Real A (nx × nx) with ``n_unstable`` RHP eigenvalues (fewer if a pair does not fit);
    modes 1–100 rad/s, damping ≥ 0.05, mixed by a random similarity."""
    blocks, k, flips = [], 0, 0
    while k < nx:
        if nx - k >= 2 and rng.random() < 0.6:
            w, z = 10 ** rng.uniform(0, 2), rng.uniform(0.05, 0.9)
            wd = w * np.sqrt(1 - z * z)
            b = np.array([[-z * w, wd], [-wd, -z * w]])
        else:
            b = np.array([[-(10 ** rng.uniform(0, 2))]])
        m = b.shape[0]
        if n_unstable - flips >= m:
            b, flips = b - 2 * np.trace(b) / m * np.eye(m), flips + m  # mirror into the RHP
        blocks.append(b)
        k += m
    A, i = np.zeros((nx, nx)), 0
    for b in blocks:
        m = b.shape[0]
        A[i : i + m, i : i + m] = b
        i += m
    T = rng.standard_normal((nx, nx)) + 2 * np.eye(nx)
    return np.linalg.solve(T, A @ T)


def _freq_resp(A, B, C, D, w):
    nx = A.shape[0]
    if nx == 0:
        return np.broadcast_to(D.astype(complex), (len(w),) + D.shape).copy()
    X = np.linalg.solve(
        1j * w[:, None, None] * np.eye(nx) - A, np.broadcast_to(B, (len(w),) + B.shape)
    )
    return C @ X + D


def _random_loop(rng, n=None):
    """(n, plant, controller): 35 % square plants with RHP modes stabilizable by gain,
    else random plants (20 % with RHP modes); controllers static, low-pass or unstable.
    ``n`` rods (default: random 2–5)."""
    n = int(rng.integers(2, 6)) if n is None else n
    if rng.random() < 0.35:
        A = _random_A(rng, n, int(rng.integers(1, 3)))
        B = rng.standard_normal((n, n)) + 2 * np.eye(n)
        C = (np.eye(n) + 0.2 * rng.standard_normal((n, n))) @ np.linalg.inv(B)
        K, c = np.eye(n), 10 ** rng.uniform(0, 2.5)
    else:
        nx = n + int(rng.integers(0, 4))
        A = _random_A(rng, nx, int(rng.integers(1, 3)) if rng.random() < 0.2 else 0)
        B, C = rng.standard_normal((nx, n)), rng.standard_normal((n, nx))
        K = np.eye(n) + 0.5 * rng.standard_normal((n, n))
        Pw = _freq_resp(A, B, C, np.zeros((n, n)), np.logspace(-2, 3, 100))
        c = 10 ** rng.uniform(-1.5, 1.5) / np.median(np.linalg.norm(Pw, 2, axis=(1, 2)))
    P = (A, B, C, np.zeros((n, n)))
    kind = rng.choice(3, p=[0.45, 0.45, 0.1])
    if kind == 0:
        G = (np.zeros((0, 0)), np.zeros((0, n)), np.zeros((n, 0)), c * K)
    else:  # a/(s + a) K, or an unstable first-order controller
        a = 10 ** rng.uniform(0, 2.5) * (1 if kind == 1 else -0.05)
        G = (-a * np.eye(n), abs(a) * c * K, np.eye(n), np.zeros((n, n)))
    return n, P, G


def _family(n_loops, seed, N):
    """Grouped by n: (P_jw, G_jw, omega, P_ol, Z_ref) stacks; closed-loop poles from
    ``closed_loop_poles`` (state space). Near-marginal loops (a closed-loop pole with
    damping below 1 %) are skipped — neither method can decide those reliably."""
    rng = np.random.default_rng(seed)
    groups, skipped = {}, 0
    poles = jax.jit(closed_loop_poles)
    for _ in range(n_loops):
        n, P, G = _random_loop(rng)
        cl = np.asarray(poles(StateSpace(*P), StateSpace(*G)))
        pol = np.concatenate(
            [np.linalg.eigvals(P[0]), np.linalg.eigvals(G[0]) if G[0].size else []]
        )
        if np.any(np.abs(cl.real) < 0.01 * np.abs(cl)):
            skipped += 1
            continue
        mags = np.abs(np.concatenate([pol, cl]))
        w = np.logspace(np.log10(mags.min()) - 3, np.log10(mags.max()) + 3, N)
        item = (
            _freq_resp(*P, w),
            _freq_resp(*G, w),
            w,
            int(np.sum(pol.real > 0)),
            int(np.sum(cl.real > 0)),
        )
        groups.setdefault(n, []).append(item)
    return groups, skipped


def _check_family(n_loops, seed, N=2500):
    groups, skipped = _family(n_loops, seed, N)
    va = jax.jit(jax.vmap(analyze_loop))
    counts = dict(loops=0, cl_stable=0, cl_unstable=0, ol_unstable=0, ol_unstable_cl_stable=0)
    for _, items in sorted(groups.items()):
        Pj, Gj, W, pol, Z = (np.stack(x) for x in zip(*items, strict=True))
        r = va(Pj, Gj, W, pol)
        assert np.asarray(r.nyquist_resolved).all()
        assert not np.asarray(r.singular).any()
        np.testing.assert_array_equal(np.asarray(r.stable), Z == 0)  # zero disagreements
        np.testing.assert_array_equal(np.asarray(r.n_closed_loop_rhp).astype(int), Z)
        counts["loops"] += len(Z)
        counts["cl_stable"] += int(np.sum(Z == 0))
        counts["cl_unstable"] += int(np.sum(Z > 0))
        counts["ol_unstable"] += int(np.sum(pol > 0))
        counts["ol_unstable_cl_stable"] += int(np.sum((pol > 0) & (Z == 0)))
    assert skipped <= 0.05 * n_loops
    return counts


@pytest.mark.slow  # the hypothesis property (tests/test_properties.py) covers this in the fast suite
def test_nyquist_agrees_with_state_space_poles_small_family():
    c = _check_family(40, seed=1, N=2000)
    assert c["cl_stable"] >= 10 and c["cl_unstable"] >= 10 and c["ol_unstable_cl_stable"] >= 2


@pytest.mark.slow
def test_nyquist_agrees_with_state_space_poles_200_loops():
    c = _check_family(200, seed=0)
    assert c["loops"] >= 190
    assert c["cl_stable"] >= 60 and c["cl_unstable"] >= 60
    assert c["ol_unstable"] >= 50 and c["ol_unstable_cl_stable"] >= 15


def test_singular_I_plus_L_is_flagged_not_silent():
    # L(jω) = −I exactly at one grid frequency: a closed-loop pole on the imaginary axis
    w = np.logspace(-1, 2, 301)
    s = 1j * w
    w0 = w[150]
    # L(s) = w0²/s² I ⇒ L(jw0) = −I
    P = (w0**2 / s**2)[:, None, None] * np.eye(2)
    r = analyze_loop(P, np.broadcast_to(np.eye(2), P.shape), w)
    assert bool(r.singular) and not bool(r.stable)
    np.testing.assert_allclose(float(r.singular_hz), w0 / (2 * np.pi))
    assert np.isnan(float(r.iso_bandwidth_hz)) and float(r.disk_margin) == 0.0


def test_loci_are_tracked_continuously_through_crossings():
    w = jnp.logspace(-1, 1, 400)
    s = 1j * w
    l1, l2 = 1.0 / (s + 1.0), 3.0 / (s + 5.0) ** 1  # magnitudes cross near ω ≈ 1
    Q = jnp.array([[1.0, 0.4], [0.2, 1.0]])
    L = Q @ (jnp.stack([l1, l2], -1)[..., None] * jnp.eye(2)) @ jnp.linalg.inv(Q)
    loci = np.asarray(characteristic_loci(L))
    ref = np.stack([np.asarray(l1), np.asarray(l2)], -1)
    if abs(loci[0, 0] - ref[0, 0]) > abs(loci[0, 0] - ref[0, 1]):
        ref = ref[:, ::-1]
    np.testing.assert_allclose(loci, ref, atol=1e-10)
    greedy = np.asarray(characteristic_loci(L, method="greedy"))
    np.testing.assert_allclose(greedy, loci, atol=1e-10)
