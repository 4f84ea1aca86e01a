"""Virtual-wall rendering through the sampled force loop (issue 4, item 4)."""

import equinox as eqx
import numpy as np
import pytest

from hapid.control import (
    Compensator,
    discretize_compensator,
    discretize_controller,
    discretize_siso_controller,
    max_siso_gain,
)
from hapid.device import SecondOrderDevice, cu5, tripod3
from hapid.experiment import Protocol, estimate_frf, periodic_run
from hapid.fit import fit_nls
from hapid.scene import analysis_grid, merge
from hapid.wall import (
    WallUnstableWarning,
    closed_loop_wall_steady_state,
    ideal_wall,
    max_wall_stiffness,
    perfect_control_wall,
    render_wall,
    wall_metrics,
)

K_WALL, PUSH = 200.0, 2.0


@pytest.fixture(scope="module")
def loops():
    dev = cu5()
    frf = estimate_frf(periodic_run(dev, Protocol()))
    model = fit_nls(frf).model
    g = Compensator.paper()
    mimo = discretize_controller(model, g, dev.ts)
    omega = analysis_grid(merge({})["analysis"], dev.fs_hz)
    gd = discretize_compensator(g, dev.ts)
    c = float(
        max_siso_gain(
            np.asarray(dev.sampled_P(omega)), omega, np.asarray(gd.at_omega(omega)).reshape(-1)
        )
    )
    return dev, mimo, discretize_siso_controller(g, c, dev.ts, dev.n)


@pytest.mark.parametrize("make", [cu5, tripod3])
def test_perfect_control_on_a_rigid_chain_renders_the_designers_wall(make):
    """With rigid traction/sensor springs the encoder estimate is the stylus position, so the
    device statics under perfect force tracking (a linear solve on the full state space) must
    equal the closed-form two-layer-hand wall — in every Cartesian direction, any n. This pins
    the signs of R_D = −J⁻ᵀ F_d, the user-force input and the stylus coordinates."""
    dev = make()
    rigid = eqx.tree_at(lambda d: (d.mechanism.k_t, d.mechanism.k_s), dev,
                        (dev.mechanism.k_t * 1e7, dev.mechanism.k_s * 1e7))  # fmt: skip
    for ax in range(dev.n):
        e = np.eye(dev.n)[ax]
        ref = ideal_wall(rigid, e, K_WALL, PUSH)
        got = perfect_control_wall(rigid, e, K_WALL, PUSH)
        assert ref > 0
        np.testing.assert_allclose(got.penetration, ref, rtol=1e-5)
        np.testing.assert_allclose(got.estimate, ref, rtol=1e-5)
    # the real (compliant) chain: encoders under-read the stylus, the wall renders softer
    real = perfect_control_wall(dev, np.eye(dev.n)[0], K_WALL, PUSH)
    assert real.estimate < real.penetration


def test_steady_state_solve_equals_a_long_simulation(loops):
    dev, mimo, _ = loops
    e = np.eye(dev.n)[2]
    ss = closed_loop_wall_steady_state(dev, mimo, e, K_WALL, PUSH)
    sim = render_wall(dev, mimo, e, k_wall=K_WALL, push=PUSH, duration=30.0)
    assert ss.spectral_radius < 1
    np.testing.assert_allclose(wall_metrics(sim).penetration, ss.penetration, rtol=1e-3)


def test_mimo_wall_has_less_force_error_and_directional_distortion_than_siso(loops):
    """A probing hand (ramp + 30 % wobble at 1.5 Hz) against a 200 N/m wall along x, y, z:
    the inverse-model loop tracks the wall force better, and with no more leakage of force
    into the directions along the wall, than the SISO loop at its design-rule gain."""
    dev, mimo, siso = loops
    for ax in range(3):
        e = np.eye(dev.n)[ax]
        m = wall_metrics(
            render_wall(dev, mimo, e, k_wall=K_WALL, push=PUSH, duration=6.0, wobble=0.3)
        )
        s = wall_metrics(
            render_wall(dev, siso, e, k_wall=K_WALL, push=PUSH, duration=6.0, wobble=0.3)
        )
        print(f"axis {ax}: force error MIMO {m.force_error:.4f} SISO {s.force_error:.4f}; "
              f"off-axis force MIMO {m.off_axis_force:.2e} SISO {s.off_axis_force:.2e}")  # fmt: skip
        assert m.force_error < s.force_error
        assert m.off_axis_force <= s.off_axis_force + 1e-4
        # within a few percent of what perfect force control renders on this chain
        pc = perfect_control_wall(dev, e, K_WALL, PUSH).penetration
        ss = closed_loop_wall_steady_state(dev, mimo, e, K_WALL, PUSH).penetration
        assert abs(ss / pc - 1) < 0.05


@pytest.mark.slow
def test_too_stiff_wall_is_flagged_and_the_limit_is_a_stability_boundary(loops):
    dev, mimo, _ = loops
    e = np.eye(dev.n)[1]
    k_lim = max_wall_stiffness(dev, mimo, e, rtol=1e-4)
    assert 0 < k_lim < 1e6
    rho = lambda k: closed_loop_wall_steady_state(dev, mimo, e, k, 1.0).spectral_radius  # noqa: E731
    assert rho(0.99 * k_lim) < 1 <= rho(1.01 * k_lim)
    with pytest.warns(WallUnstableWarning, match="unstable"):
        render_wall(dev, mimo, e, k_wall=3 * k_lim, duration=0.5)


def test_bad_wall_input_is_a_clear_error(loops):
    dev, mimo, _ = loops
    with pytest.raises(ValueError, match="n = 5"):
        render_wall(dev, mimo, np.ones(3))
    with pytest.raises(ValueError, match="non-zero"):
        render_wall(dev, mimo, np.zeros(5))
    with pytest.raises(ValueError, match="k_wall"):
        render_wall(dev, mimo, np.eye(5)[0], k_wall=np.nan)
    so = SecondOrderDevice(dev.rigid_model().hand, dev.rigid_model().mechanism, delay_samples=1)
    with pytest.raises(TypeError, match="ParallelDevice"):
        render_wall(so, mimo, np.eye(5)[0])
