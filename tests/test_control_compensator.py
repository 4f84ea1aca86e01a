"""g(s): python-control references, realization, gradients, matched pole-zero."""

import control as ct
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hapid  # noqa: F401  (float64)
from hapid.control import Compensator, discretize_compensator

W = np.logspace(-1, 4, 800)


def _rel(a, b):
    return np.max(np.abs(np.asarray(a) - b) / np.abs(b))


def test_paper_defaults():
    g = Compensator.paper()
    assert float(g.k) == 0.85
    np.testing.assert_allclose(g.lag_poles, [1.2 * np.pi])
    np.testing.assert_allclose(g.lag_zeros, [60 * np.pi])
    np.testing.assert_allclose(g.notch_omega / (2 * np.pi), [17, 55, 100])
    np.testing.assert_allclose(g.lowpass / (2 * np.pi), [100, 200])
    assert g.order == 1 + 6 + 2 and g.relative_degree == 2
    # DC gain k z1/p1 (notches and low-pass poles have unit DC gain)
    np.testing.assert_allclose(abs(complex(g(jnp.array([0.0]))[0])), 0.85 * 50.0, rtol=1e-12)


@pytest.mark.parametrize(
    "g",
    [
        Compensator.paper(),
        Compensator(
            k=2.0, notch_omega=[30.0, 300.0], notch_zeta_num=[0.05, 0.3], notch_zeta_den=0.7
        ),
        Compensator(
            k=0.5, lag_zeros=[10.0, 5.0], lag_poles=[1.0, 50.0], lowpass=[400.0, 900.0, 2e3]
        ),
        Compensator(k=3.0),
    ],
)
def test_response_matches_python_control(g):
    num, den = g.tf_coefficients()
    ref = ct.tf(num, den)(1j * W)
    assert _rel(g.at_omega(W), ref) < 1e-10
    ss = g.state_space()
    assert ss.n_states == g.order
    assert _rel(ss.at_omega(W)[:, 0, 0], ref) < 1e-10
    z, p, k = g.zpk()
    assert _rel(ct.zpk(z, p, k)(1j * W), ref) < 1e-9
    assert bool(ss.is_stable())


def test_gradient_in_parameters_matches_finite_differences():
    g0 = Compensator.paper()
    w = jnp.array([2 * np.pi * 3.0, 2 * np.pi * 20.0, 2 * np.pi * 60.0])

    def f(g):  # log-magnitude sum: smooth in all parameters
        return jnp.sum(jnp.log(jnp.abs(g.at_omega(w))))

    f = jax.jit(f)
    grads = jax.jit(jax.grad(f))(g0)
    for name, idx in [
        ("k", ()),
        ("notch_omega", (1,)),
        ("lag_poles", (0,)),
        ("lowpass", (0,)),
        ("notch_zeta_den", (2,)),
    ]:
        x = getattr(g0, name)
        h = 1e-6 * max(1.0, abs(float(x[idx])))
        gp = eqx_set(g0, name, x.at[idx].add(h))
        gm = eqx_set(g0, name, x.at[idx].add(-h))
        fd = (f(gp) - f(gm)) / (2 * h)
        np.testing.assert_allclose(getattr(grads, name)[idx], fd, rtol=1e-5, atol=1e-9)
    # the state-space realization is differentiable too
    gs = jax.jit(jax.grad(lambda g: jnp.sum(jnp.abs(g.state_space().at_omega(w)))))(g0)
    assert np.all(np.isfinite(np.asarray(gs.notch_omega)))


def eqx_set(module, name, value):
    return eqx.tree_at(lambda m: getattr(m, name), module, value)


def test_matched_pole_zero_matches_python_control_and_dc():
    g = Compensator.paper()
    ts = 1e-3
    num, den = g.tf_coefficients()
    ref_sys = ct.sample_system(ct.tf(num, den), ts, method="matched")
    w = W[W < np.pi / ts]
    gd = discretize_compensator(g, ts, infinite_zeros="delay")  # python-control's convention
    assert _rel(gd.at_omega(w)[:, 0, 0], ref_sys(np.exp(1j * w * ts))) < 1e-6
    for iz in ("minus_one", "all_but_one", "delay"):
        gd = discretize_compensator(g, ts, infinite_zeros=iz)
        dc = complex(gd(jnp.array([1.0 + 0j]))[0, 0, 0])
        np.testing.assert_allclose(dc, float(g.k) * 50.0, rtol=1e-10)
        assert bool(gd.is_stable())
        # poles are exactly e^{p ts}
        _, p, _ = g.zpk()
        np.testing.assert_allclose(
            np.sort_complex(np.asarray(gd.poles())), np.sort_complex(np.exp(p * ts)), rtol=1e-9
        )
    # Franklin's rule: zeros at infinity → z = −1, so the response vanishes at Nyquist
    gd = discretize_compensator(g, ts)
    assert abs(complex(gd.at_omega(jnp.array([np.pi / ts]))[0, 0, 0])) < 1e-12
    assert float(gd.D[0, 0]) != 0.0
    assert float(discretize_compensator(g, ts, "all_but_one").D[0, 0]) == 0.0
