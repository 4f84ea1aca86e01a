"""The one state space (hapid.lti): frequency response, ZOH / Tustin / matched discretization
and feedback, checked against scipy.signal and python-control."""

import sys
from pathlib import Path

import control as ct
import jax
import numpy as np
import pytest
from scipy import signal

from hapid import lti
from hapid.closed_loop import closed_loop
from hapid.control import Compensator, discretize_compensator
from hapid.device import StateSpace as DeviceStateSpace

sys.path.insert(0, str(Path(__file__).parent))
from helpers import second_order_device  # noqa: E402

TS = 1e-3


def _random_ss(rng, nx=4, p=2, m=3, stable=True):
    A = rng.normal(size=(nx, nx))
    if stable:
        A = A - (np.max(np.linalg.eigvals(A).real) + 1.0) * np.eye(nx)
    return (
        rng.normal(size=(nx, nx)) * 0 + A,
        rng.normal(size=(nx, m)),
        rng.normal(size=(p, nx)),
        rng.normal(size=(p, m)),
    )


def test_device_and_controller_share_the_one_state_space():
    import hapid.control

    assert hapid.control.StateSpace is lti.StateSpace is DeviceStateSpace
    assert hapid.control.DiscreteStateSpace is lti.StateSpace


def test_response_matches_python_control():
    A, B, C, D = _random_ss(np.random.default_rng(0))
    om = np.geomspace(0.1, 300.0, 40)
    ref = ct.ss(A, B, C, D).frequency_response(om)
    H = np.asarray(lti.StateSpace(A, B, C, D).response(om))
    assert H.shape == (40, 2, 3)
    np.testing.assert_allclose(H, np.moveaxis(ref.complex, -1, 0), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("method", ["zoh", "bilinear"])
def test_discretization_matches_scipy_cont2discrete(method):
    A, B, C, D = _random_ss(np.random.default_rng(1))
    sys_c = lti.StateSpace(A, B, C, D)
    ts = 0.05
    sys_d = lti.zoh(sys_c, ts) if method == "zoh" else lti.tustin(sys_c, ts)
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((A, B, C, D), ts, method=method)
    assert sys_d.ts == ts
    # realizations may differ by a state transform: compare A's spectrum and the response
    np.testing.assert_allclose(
        np.sort_complex(np.asarray(sys_d.poles())),
        np.sort_complex(np.linalg.eigvals(Ad)),
        rtol=1e-10,
    )
    om = np.geomspace(0.1, 0.99 * np.pi / ts, 30)
    ref = ct.ss(Ad, Bd, Cd, Dd, ts).frequency_response(om)
    np.testing.assert_allclose(
        np.asarray(sys_d.response(om)), np.moveaxis(ref.complex, -1, 0), rtol=1e-9, atol=1e-12
    )


@pytest.mark.slow
def test_prewarped_tustin_matches_python_control_and_is_exact_at_the_prewarp_frequency():
    A, B, C, D = _random_ss(np.random.default_rng(2))
    ts, w0 = 0.05, 20.0
    sys_c = lti.StateSpace(A, B, C, D)
    sys_d = lti.tustin(sys_c, ts, prewarp=w0)
    ref = ct.sample_system(ct.ss(A, B, C, D), ts, method="tustin", prewarp_frequency=w0)
    om = np.array([1.0, 5.0, w0, 50.0])
    np.testing.assert_allclose(
        np.asarray(sys_d.response(om)),
        np.moveaxis(ref.frequency_response(om).complex, -1, 0),
        rtol=1e-9,
    )
    np.testing.assert_allclose(
        np.asarray(sys_d.response([w0])), np.asarray(sys_c.response([w0])), rtol=1e-10
    )


def test_matched_g_matches_python_control_and_its_closed_form():
    g = Compensator.paper()
    om = np.geomspace(0.1, 0.999 * np.pi / TS, 200)
    gd = lti.matched(g, TS, infinite_zeros="delay")  # python-control keeps the zeros at ∞
    z, p, k = g.zpk()
    ref = ct.sample_system(ct.zpk(z, p, k), TS, method="matched")
    got = np.asarray(gd.response(om))[:, 0, 0]
    np.testing.assert_allclose(got, ref.frequency_response(om).complex.reshape(-1), rtol=1e-7)
    # the closed form evaluates the same discretization (the tuner's gradient path)
    np.testing.assert_allclose(np.asarray(lti.matched_response(g, om, TS, "delay")), got, rtol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("iz", lti.INFINITE_ZEROS)
def test_matched_closed_form_equals_its_realization(iz):
    g = Compensator.paper()
    om = np.geomspace(0.1, 0.999 * np.pi / TS, 200)
    sys_d = lti.matched(g, TS, iz)
    H = np.asarray(sys_d.response(om))[:, 0, 0]
    np.testing.assert_allclose(np.asarray(lti.matched_response(g, om, TS, iz)), H, rtol=1e-9)
    dc = abs(complex(np.asarray(sys_d.response(np.array([0.0])))[0, 0, 0]))
    assert dc == pytest.approx(abs(complex(np.asarray(g.at_omega(np.array([0.0])))[0])), rel=1e-9)
    assert discretize_compensator(g, TS, iz).A.shape == sys_d.A.shape


def test_matched_is_differentiable_in_g():
    g = Compensator.paper()

    def f(k):
        return jax.numpy.abs(lti.matched_response(Compensator.paper(k=k), [10.0], TS)[0])

    d = jax.grad(f)(float(g.k))
    assert np.isfinite(d) and d == pytest.approx(float(f(float(g.k))) / float(g.k), rel=1e-9)


@pytest.mark.parametrize("ts", [None, pytest.param(0.01, marks=pytest.mark.slow)])
def test_feedback_matches_python_control(ts):
    rng = np.random.default_rng(3)
    Ap, Bp, Cp, Dp = _random_ss(rng, 4, 2, 2)
    Ag, Bg, Cg, Dg = _random_ss(rng, 3, 2, 2)
    if ts is not None:
        Ap, Ag = 0.3 * np.eye(4) + 0.05 * Ap, 0.2 * np.eye(3) + 0.05 * Ag
    P, G = lti.StateSpace(Ap, Bp, Cp, Dp, ts=ts), lti.StateSpace(Ag, Bg, Cg, Dg, ts=ts)
    cl = lti.feedback(P, G)
    dt = 0 if ts is None else ts
    Pc, Gc = ct.ss(Ap, Bp, Cp, Dp, dt), ct.ss(Ag, Bg, Cg, Dg, dt)
    T = ct.feedback(Pc * Gc, np.eye(2))  # r → y
    om = np.geomspace(0.1, 100.0, 25)
    np.testing.assert_allclose(
        np.asarray(cl.response(om))[:, :2],
        np.moveaxis(T.frequency_response(om).complex, -1, 0),
        rtol=1e-8,
        atol=1e-10,
    )
    np.testing.assert_allclose(
        np.sort_complex(np.asarray(lti.closed_loop_poles(P, G))),
        np.sort_complex(T.poles()),
        rtol=1e-8,
        atol=1e-10,
    )
    assert bool(lti.closed_loop_is_stable(P, G)) == bool(
        np.all(np.abs(T.poles()) < 1) if ts else np.all(T.poles().real < 0)
    )


def test_sampled_loop_without_delay_matches_python_control():
    """closed_loop(device with delay 0, controller with feedthrough): the algebraic loop is
    solved by lti.feedback (the earlier copy inverted I + D_P D_G instead of I + D_G D_P)."""
    n = 3
    dev = second_order_device(n, delay_samples=0)
    rng = np.random.default_rng(1)
    Ac = 0.5 * np.eye(4) + 0.1 * rng.normal(size=(4, 4))
    ctrl = lti.StateSpace(
        Ac, rng.normal(size=(4, n)), rng.normal(size=(n, 4)), rng.normal(size=(n, n)), ts=dev.ts
    )
    d = dev.discrete()
    P = ct.ss(
        np.asarray(d.A),
        np.asarray(d.B)[:, :n],
        np.asarray(d.C)[n:],
        np.asarray(d.D)[n:, :n],
        dev.ts,
    )
    G = ct.ss(*(np.asarray(x) for x in (ctrl.A, ctrl.B, ctrl.C, ctrl.D)), dev.ts)
    ref = np.sort_complex(ct.feedback(P * G, np.eye(n)).poles())
    got = np.sort_complex(np.linalg.eigvals(np.asarray(closed_loop(dev, ctrl).A)))
    np.testing.assert_allclose(got, ref, rtol=1e-9)


def test_discrete_stability_uses_the_unit_circle():
    s = lti.StateSpace(
        np.diag([0.5, -0.9]), np.ones((2, 1)), np.ones((1, 2)), np.zeros((1, 1)), ts=0.1
    )
    assert bool(s.is_stable()) and int(s.n_unstable_poles()) == 0
    c = lti.StateSpace(np.diag([0.5, -0.9]), np.ones((2, 1)), np.ones((1, 2)), np.zeros((1, 1)))
    assert not bool(c.is_stable()) and int(c.n_unstable_poles()) == 1


def test_bad_connections_are_clear_errors():
    a = lti.StateSpace(np.eye(1), np.ones((1, 1)), np.ones((1, 1)), np.zeros((1, 1)))
    b = lti.StateSpace(np.eye(1), np.ones((1, 1)), np.ones((1, 1)), np.zeros((1, 1)), ts=0.1)
    with pytest.raises(ValueError, match="sampling periods"):
        lti.series(a, b)
    with pytest.raises(ValueError, match="already discrete"):
        lti.zoh(b, 0.1)
    with pytest.raises(ValueError, match="inconsistent shapes"):
        lti.StateSpace(np.eye(2), np.ones((1, 1)), np.ones((1, 2)), np.zeros((1, 1)))
