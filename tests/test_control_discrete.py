"""Discrete controller vs continuous up to fs/2, within the tolerances stated in _discrete."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from oracles import example_model

import hapid  # noqa: F401  (float64)
from hapid.control import (
    Compensator,
    discretize_controller,
    discretize_state_space,
    impedance_ratio_state_space,
    inverse_model_response,
)

TS = 1e-3
W = np.logspace(-1, np.log10(np.pi / TS), 800)


def _norm(A):
    return np.linalg.norm(A, 2, axis=(1, 2))


@pytest.mark.parametrize("n,seed", [(3, 0), (5, 3)])
def test_discrete_controller_matches_continuous_to_nyquist(n, seed):
    m, g = example_model(n, seed), Compensator.paper()
    G = np.asarray(inverse_model_response(m, g, W))
    nG, peak = _norm(G), _norm(G).max()
    # matrix part alone (Tustin): 1 % relative below fs/10, 5 % up to fs/2
    R = impedance_ratio_state_space(m)
    Rc, Rd = np.asarray(R.at_omega(W)), np.asarray(discretize_state_space(R, TS).at_omega(W))
    lo = W < 2 * np.pi * 100
    assert np.all(_norm(Rd - Rc)[lo] <= 0.01 * _norm(Rc)[lo])
    assert np.all(_norm(Rd - Rc) <= 0.05 * _norm(Rc))
    # whole controller, matched g (the paper's): 0.25 ω t_s relative + 1 % of the peak
    D = discretize_controller(m, g, TS)
    assert bool(D.is_stable())
    e = _norm(np.asarray(D.at_omega(W)) - G)
    assert np.all(e <= 0.25 * W * TS * nG + 0.01 * peak)
    assert np.all(e <= 0.02 * peak)
    # whole controller, Tustin g
    Dt = discretize_controller(m, g, TS, g_method="tustin")
    e = _norm(np.asarray(Dt.at_omega(W)) - G)
    assert np.all(e[W < 2 * np.pi * 30] <= 0.01 * nG[W < 2 * np.pi * 30])
    assert np.all(e <= 0.02 * peak)


def test_discrete_step_in_scan_reproduces_frequency_response():
    m, g = example_model(3, 2), Compensator.paper()
    D = discretize_controller(m, g, TS, infinite_zeros="all_but_one")
    f = 7.0
    t = np.arange(4000) * TS
    u = np.zeros((len(t), 3))
    u[:, 1] = np.cos(2 * np.pi * f * t)

    def body(x, uk):
        return D.step(x, uk)

    _, y = jax.lax.scan(body, D.initial_state(), jnp.asarray(u))
    y = np.asarray(y)[-1000:]  # steady state: 7 periods
    tt = t[-1000:]
    Hd = np.asarray(D.at_omega(jnp.array([2 * np.pi * f])))[0][:, 1]
    ref = np.real(Hd[None, :] * np.exp(1j * 2 * np.pi * f * tt)[:, None])
    np.testing.assert_allclose(y, ref, atol=1e-6 * np.abs(Hd).max())


def test_siso_controller_is_c_times_the_sampled_g_on_the_diagonal():
    from hapid.control import discretize_compensator, discretize_siso_controller

    g, ts, c, n = Compensator.paper(), 1e-3, 0.37, 4
    omega = 2 * np.pi * np.geomspace(0.1, 450, 60)
    G = np.asarray(discretize_siso_controller(g, c, ts, n).at_omega(omega))
    gd = np.asarray(discretize_compensator(g, ts).at_omega(omega)).reshape(-1)
    np.testing.assert_allclose(G, c * gd[:, None, None] * np.eye(n), rtol=1e-10, atol=1e-12)
