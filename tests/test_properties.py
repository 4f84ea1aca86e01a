"""Property-based tests (hypothesis): invariants that must hold for every input.

Shapes are fixed per property (n, N constant) so every jitted kernel compiles once; example
counts are modest. Properties:

- the PD parameterization gives symmetric PSD matrices for any θ, and strictly OLHP roots of
  det Ẑ_H, det Ẑ_T once every matrix is PD (``eps > 0``);
- WLS is exact on noise-free second-order data (any real M, B, K, any frequency grid);
- the FRF estimate does not depend on the order of the periods (nor of the experiments);
- T = (I + PG)⁻¹PG → I where PG is large: ‖T − I‖ ≤ 1/(σ̲(PG) − 1);
- the generalized Nyquist verdict of ``analyze_loop`` agrees with the closed-loop poles.
"""

import dataclasses
import functools

import jax.numpy as jnp
import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from oracle_loop import analyze_loop
from test_control_nyquist import _freq_resp
from test_control_nyquist import _random_loop as family_loop

import hapid  # noqa: F401  (float64)
from hapid.control import loop_matrices
from hapid.experiment import Protocol, estimate_frf, periodic_run
from hapid.fit import Scale, n_params, theta_to_model, wls

SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow])

N_ROD = 3
P = n_params(N_ROD)
finite = dict(allow_nan=False, allow_infinity=False)


def _mats(m):
    return [np.asarray(a) for a in (m.hand.M, m.hand.B, m.hand.K, m.mechanism.M, m.mechanism.B,
                                    m.mechanism.K, m.total.M, m.total.B, m.total.K)]  # fmt: skip


# --- PD parameterization ------------------------------------------------------------------


@settings(max_examples=30, **SETTINGS)
@given(
    theta=hnp.arrays(np.float64, P, elements=st.floats(-3.0, 3.0, **finite)),
    log_w=st.floats(-1.0, 3.0),
    log_z=st.floats(-2.0, 4.0),
)
def test_pd_parameterization_gives_psd_matrices(theta, log_w, log_z):
    scale = Scale(jnp.asarray(10.0**log_w), jnp.asarray(10.0**log_z))
    model = theta_to_model(jnp.asarray(theta), scale)
    mats = _mats(model)
    for k, A in enumerate(mats):
        # hand (0–2) and total (6–8) are stored; the mechanism (3–5) is total − hand, so it
        # is PSD only up to rounding of the larger of the two
        ref = max(np.abs(A).max(), np.abs(mats[k + 3]).max() if 3 <= k < 6 else 0.0, 1e-300)
        np.testing.assert_allclose(A, A.T, rtol=0, atol=1e-12 * ref)
        assert np.linalg.eigvalsh(A).min() >= -1e-12 * ref


@settings(max_examples=30, **SETTINGS)
@given(
    theta=hnp.arrays(np.float64, P, elements=st.floats(-3.0, 3.0, **finite)),
    eps=st.floats(1e-3, 1.0),
)
def test_pd_parameterization_with_eps_has_olhp_roots(theta, eps):
    model = theta_to_model(jnp.asarray(theta), eps=eps)
    for so in (model.hand, model.total):
        r = np.asarray(so.roots())
        assert np.all(np.isfinite(r))
        # M, B, K PD ⇒ Re s < 0 for every root (xᴴZ(s)x = 0 has only OLHP solutions)
        assert np.real(r).max() < 0, r
        assert int(so.n_crhp_roots()) == 0


# --- WLS exact on noise-free data ---------------------------------------------------------

N_FREQ = 12


@settings(max_examples=25, **SETTINGS)
@given(
    freq=st.lists(st.floats(0.1, 1000.0), min_size=N_FREQ, max_size=N_FREQ, unique=True),
    seed=st.integers(0, 2**31 - 1),
    log_scales=st.tuples(st.floats(-2, 1), st.floats(-1, 2), st.floats(1, 5)),
)
def test_wls_is_exact_on_noise_free_second_order_data(freq, seed, log_scales):
    f = np.sort(np.asarray(freq))
    assume(np.all(np.diff(np.log(f)) > 1e-3) and f[-1] / f[0] > 3.0)
    rng = np.random.default_rng(seed)
    sm, sb, sk = (10.0**x for x in log_scales)
    # any real (non-symmetric, indefinite) coefficients: WLS is element-wise linear LS
    mk = lambda s: s * rng.standard_normal((2, N_ROD, N_ROD))  # noqa: E731
    M, B, K = mk(sm), mk(sb), mk(sk)
    w = 2 * np.pi * f
    s = 1j * w[:, None, None, None]
    Z = M * s**2 + B * s + K  # (N, 2, n, n)
    frf = hapid.as_frf(f, Z[:, 0], Z[:, 1])
    model = wls(frf)
    for so, k in ((model.hand, 0), (model.total, 1)):
        Zfit = np.asarray(so.at_omega(w))
        assert np.max(np.abs(Zfit - Z[:, k])) <= 1e-9 * np.max(np.abs(Z[:, k]))
        if f[-1] / f[0] > 10.0:  # well-spread grid: the coefficients themselves
            for got, ref in ((so.M, M[k]), (so.B, B[k]), (so.K, K[k])):
                np.testing.assert_allclose(np.asarray(got), ref, atol=1e-6 * np.abs(ref).max())


# --- FRF estimation invariant to the period (and experiment) ordering ----------------------


@functools.lru_cache(maxsize=1)
def _noisy_run():
    from helpers import second_order_device

    prot = Protocol(n_periods=5, force_noise=0.05, position_noise=1e-6, encoder_resolution=0.0,
                    pattern="hadamard")  # fmt: skip
    return periodic_run(second_order_device(3, seed=2), prot)


@settings(max_examples=20, **SETTINGS)
@given(order=st.permutations(range(5)), exps=st.permutations(range(4)))
def test_frf_estimate_is_invariant_to_period_order(order, exps):
    run = _noisy_run()
    E, T, n = run.R_A.shape
    Tp = run.period_samples

    def permute(x):
        x = x.reshape(E, T // Tp, Tp, n)[:, list(order)].reshape(E, T, n)
        return x[list(exps)]

    ref = estimate_frf(run)
    got = estimate_frf(dataclasses.replace(run, R_A=permute(run.R_A), R_I=permute(run.R_I),
                                           L=permute(run.L)))  # fmt: skip
    for a, b in ((got.Z_H, ref.Z_H), (got.Z_T, ref.Z_T), (got.Z_H_std, ref.Z_H_std),
                 (got.Z_T_std, ref.Z_T_std)):  # fmt: skip
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-9,
                                   atol=1e-12 * np.abs(np.asarray(b)).max())  # fmt: skip


# --- T → I where PG is large --------------------------------------------------------------


@settings(max_examples=30, **SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), log_gain=st.floats(1.0, 8.0))
def test_T_tends_to_identity_where_PG_is_large(seed, log_gain):
    rng = np.random.default_rng(seed)
    shape = (8, N_ROD, N_ROD)
    X = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
    X = X + 3 * np.eye(N_ROD)  # keep σ̲ away from 0 so "large" is meaningful
    Pm = (10.0**log_gain) * X
    _, S, T = loop_matrices(jnp.asarray(Pm), jnp.broadcast_to(jnp.eye(N_ROD), shape))
    smin = np.linalg.svd(Pm, compute_uv=False)[:, -1]
    assume(np.all(smin > 2.0))
    err = np.linalg.norm(np.asarray(T) - np.eye(N_ROD), 2, axis=(1, 2))
    assert np.all(err <= (1.0 / (smin - 1.0)) * (1 + 1e-8) + 1e-13)
    np.testing.assert_allclose(np.asarray(S + T), np.broadcast_to(np.eye(N_ROD), shape),
                               atol=1e-12)  # fmt: skip


# --- generalized Nyquist vs closed-loop poles -----------------------------------------------

N_GRID = 1500


def _random_loop(rng):
    """(P, G) state-space matrices ``(A, B, C, D)``, n = 3, from the seeded family of
    test_control_nyquist (plants with 0–2 RHP modes; static, low-pass or unstable
    first-order G)."""
    _, P, G = family_loop(rng, N_ROD)
    return P, G


def _closed_loop_A(P, G):
    """State matrix of the negative-feedback loop of ``P`` and ``G`` (``(A, B, C, D)`` numpy
    tuples; ``u = G(−y)``), in closed form — the independent reference (no hapid, and no
    program compiled for every random state count)."""
    Ap, Bp, Cp, Dp = (np.atleast_2d(np.asarray(m, dtype=float)) for m in P)
    Ag, Bg, Cg, Dg = (np.asarray(m, dtype=float) for m in G)
    m = Bp.shape[1]
    ng = Ag.shape[0] if Ag.size else 0
    Ag, Bg, Cg = Ag.reshape(ng, ng), Bg.reshape(ng, Cp.shape[0]), Cg.reshape(m, ng)
    Dg = Dg.reshape(m, Cp.shape[0])
    X = np.linalg.inv(np.eye(m) + Dg @ Dp)  # u = X (Cg x_G − Dg Cp x_P)
    ux, ug = -X @ Dg @ Cp, X @ Cg
    yx, yg = Cp + Dp @ ux, Dp @ ug
    return np.block([[Ap + Bp @ ux, Bp @ ug], [-Bg @ yx, Ag - Bg @ yg]])


@settings(max_examples=12, **SETTINGS)
@given(seed=st.integers(0, 2**31 - 1))
def test_nyquist_verdict_agrees_with_closed_loop_poles(seed):
    # the responses on the grid come from numpy (StateSpace.at_omega has its own test against
    # python-control in test_lti): its program would recompile for every random state count
    rng = np.random.default_rng(seed)
    P, G = _random_loop(rng)
    cl = np.linalg.eigvals(_closed_loop_A(P, G))
    ol = np.concatenate([np.linalg.eigvals(P[0]), np.linalg.eigvals(G[0]) if G[0].size else []])
    assume(not np.any(np.abs(cl.real) < 0.01 * np.abs(cl)))  # near-marginal: undecidable
    mags = np.abs(np.concatenate([ol, cl]))
    w = np.logspace(np.log10(mags.min()) - 3, np.log10(mags.max()) + 3, N_GRID)
    P_ol = int(np.sum(ol.real > 0))
    r = analyze_loop(_freq_resp(*P, w), _freq_resp(*G, w), jnp.asarray(w), P_ol)
    n_rhp = int(np.sum(cl.real > 0))
    assert bool(r.nyquist_resolved)
    assert bool(r.stable) == (n_rhp == 0)
    assert int(r.n_closed_loop_rhp) == n_rhp
