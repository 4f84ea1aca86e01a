"""Loop quantities: T → I, isotropic bandwidth closed form, inverse-model loop, jit/vmap."""

import jax
import jax.numpy as jnp
import numpy as np
from oracle_loop import analyze_loop
from oracles import example_model

import hapid  # noqa: F401  (float64)
from hapid.control import (
    ISO_THRESHOLD,
    Compensator,
    DiskMargin,
    Encirclements,
    IsotropicBandwidth,
    LociMargins,
    LoopMatrices,
    characteristic_loci,
    disk_margin_from_peak,
    inverse_model_response,
    isotropic_bandwidth,
    loci_margins,
    loop_matrices,
    nyquist_encirclements,
)

W = np.logspace(-2, 4, 2000)


def _diag_loop(k, a=1.0):
    """L(jω) = diag(k_i/(jω + a)) on W, (N, n, n)."""
    s = 1j * W
    return (np.asarray(k)[None, :] / (s[:, None] + a))[..., None] * np.eye(len(k))


def test_T_tends_to_identity_where_PG_is_large():
    L = _diag_loop([1e3, 3e3, 1e4])
    _, S, T = loop_matrices(jnp.asarray(L), jnp.broadcast_to(jnp.eye(3), L.shape))
    low = W < 1.0
    err = np.linalg.norm(np.asarray(T)[low] - np.eye(3), 2, axis=(1, 2))
    sig_min = np.linalg.svd(L[low], compute_uv=False)[:, -1]
    assert np.all(err <= 1.0 / (sig_min - 1.0) + 1e-12)  # ‖T − I‖ = ‖(I+L)⁻¹‖ ≤ 1/(σ̲(L) − 1)
    assert err.max() < 2e-3


def test_isotropic_bandwidth_of_diagonal_loop_matches_closed_form():
    k, a = np.array([20.0, 50.0, 200.0]), 1.0
    L = _diag_loop(k, a)
    r = analyze_loop(L, np.broadcast_to(np.eye(3), L.shape), W)
    assert bool(r.stable) and int(r.n_encirclements) == 0
    # |S_i(jω)| = |jω + a| / |jω + a + k_i| reaches thr first for the smallest k
    thr, kk = ISO_THRESHOLD, k.min()
    w_bw = np.sqrt((thr**2 * (a + kk) ** 2 - a**2) / (1 - thr**2))
    np.testing.assert_allclose(float(r.iso_bandwidth_hz) * 2 * np.pi, w_bw, rtol=2e-4)
    np.testing.assert_allclose(float(r.iso_bandwidth_literal_hz), float(r.iso_bandwidth_hz))
    # disk margin of a first-order loop: α = 2/‖S − T‖∞ with ‖S − T‖∞ = 1 (at ω → ∞)
    np.testing.assert_allclose(float(r.disk_margin), 2.0, rtol=1e-3)
    # T peak at DC: k/(k + a) for the smallest k
    np.testing.assert_allclose(10 ** (float(r.t_peak_db) / 20), 1.0 * 200 / 201, rtol=1e-3)
    np.testing.assert_allclose(
        np.asarray(r.sv_T_minus_I)[:, 0], np.abs((1j * W + a) / (1j * W + a + kk)), rtol=1e-10
    )


def test_literal_bandwidth_differs_when_curve_dips_back():
    w = np.logspace(0, 2, 201)
    x = 0.1 + 0.5 * np.exp(
        -((np.log(w / 10.0)) ** 2) / 0.02
    )  # a bump above the threshold around ω = 10
    x = np.where(w > 50, 0.9, x)  # and above for good beyond 50
    lo, lit = isotropic_bandwidth(jnp.asarray(x)[:, None], jnp.asarray(w))
    assert 5 < float(lo) < 10 and 10 < float(lit) <= 50.0
    lo, lit = isotropic_bandwidth(jnp.full((5, 1), 0.1), jnp.arange(1.0, 6.0))
    assert np.isinf(float(lo)) and np.isinf(float(lit))
    lo, lit = isotropic_bandwidth(jnp.full((5, 1), 0.5), jnp.arange(1.0, 6.0))
    assert float(lo) == 0.0 and float(lit) == 0.0


def test_inverse_model_loop_on_its_own_model_is_g_times_identity():
    m, g = example_model(4, seed=3), Compensator.paper()
    w = np.logspace(-1, 3.5, 1500)
    P = m.P(1j * w)
    G = inverse_model_response(m, g, w)
    r = analyze_loop(P, G, w)
    gj = np.asarray(g.at_omega(w))
    np.testing.assert_allclose(np.asarray(r.loci), np.repeat(gj[:, None], 4, axis=1), rtol=1e-8)
    np.testing.assert_allclose(np.asarray(r.cond_L), 1.0, rtol=1e-6)
    sv = np.abs(1.0 / (1.0 + gj))
    np.testing.assert_allclose(np.asarray(r.sv_T_minus_I), np.repeat(sv[:, None], 4, 1), rtol=1e-8)


def test_jit_vmap_over_batch_of_models_matches_singles():
    w = jnp.logspace(-1, 3.5, 600)
    g = Compensator.paper()
    truths = [example_model(3, seed=s) for s in range(3)]
    models = [example_model(3, seed=s + 10) for s in range(3)]
    P = jnp.stack([t.P(1j * w) for t in truths])
    G = jnp.stack([inverse_model_response(mm, g, w) for mm in models])
    batched = jax.jit(jax.vmap(analyze_loop, in_axes=(0, 0, None, None)))(P, G, w, 0)
    for i in range(3):
        single = analyze_loop(P[i], G[i], w, 0)
        for name, v in single.numbers().items():
            if isinstance(v, str):  # status
                assert batched.numbers()[name][i] == v
            else:
                np.testing.assert_allclose(batched.numbers()[name][i], v, rtol=1e-9, equal_nan=True)
        np.testing.assert_allclose(np.asarray(batched.loci[i]), np.asarray(single.loci), rtol=1e-9)


def test_building_blocks_return_named_results_that_jit_and_vmap():
    L = jnp.asarray(_diag_loop([20.0, 50.0]))
    eye = jnp.broadcast_to(jnp.eye(2), L.shape)
    lm = jax.jit(loop_matrices)(L, eye)
    assert isinstance(lm, LoopMatrices) and lm.L.shape == lm.S.shape == lm.T.shape == L.shape
    np.testing.assert_array_equal(np.asarray(lm.S + lm.T), np.asarray(eye))
    sv = jnp.linalg.svd(lm.S, compute_uv=False)
    bw = jax.jit(isotropic_bandwidth)(sv, jnp.asarray(W))
    assert isinstance(bw, IsotropicBandwidth) and float(bw.lowest) == float(bw.literal) > 0
    dm = jax.vmap(disk_margin_from_peak)(jnp.array([0.5, 1.0, 4.0]))
    assert isinstance(dm, DiskMargin) and dm.disk_margin.shape == (3,)
    np.testing.assert_allclose(np.asarray(dm.disk_margin), [4.0, 2.0, 0.5])
    assert np.isinf(float(dm.disk_gm_db[0])) and abs(float(dm.disk_pm_deg[1]) - 90.0) < 1e-12
    det = jnp.linalg.det(eye + L)
    enc = jax.jit(jax.vmap(nyquist_encirclements))(jnp.stack([det, det]))
    assert isinstance(enc, Encirclements) and enc.n.shape == (2,) and bool(enc.resolved.all())
    mg = jax.jit(loci_margins)(characteristic_loci(L), jnp.asarray(W))
    assert isinstance(mg, LociMargins) and np.isinf(float(mg.gm_db))  # no phase crossover
