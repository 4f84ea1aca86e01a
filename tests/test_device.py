"""The simulated devices: geometry, impedances, presets."""

import jax
import numpy as np
import pytest
from helpers import rel_err, second_order_device

import hapid
from hapid.device import Pose, cu5, cu5_geometry, hexapod6, preset, quad4, tripod3


def test_import_switches_on_float64():
    assert jax.config.jax_enable_x64
    assert hapid.SecondOrder(np.eye(2), np.eye(2), np.eye(2))(np.array([1j])).dtype == np.complex128


@pytest.mark.parametrize("make", [tripod3, quad4, cu5, hexapod6])
def test_jacobian_matches_finite_difference_of_rod_lengths(make):
    """J = dL/dx: compare with central differences of the rod lengths along each DOF."""
    dev = make(Pose().moved(0.01, -0.02, 0.015, dyaw=0.1, dpitch=-0.05))
    g, pose = dev.geometry, dev.pose
    J = np.asarray(g.jacobian(pose))
    h = 1e-6
    dof = np.asarray(g.dof)
    R = np.asarray(pose.R)
    for k in range(g.n):
        v, w_body = dof[:3, k], dof[3:, k]
        w = R @ w_body

        # rotate about the grip point by a small angle h around w, translate by h v
        def moved(sign, v=v, w=w):
            from scipy.spatial.transform import Rotation

            Rw = Rotation.from_rotvec(sign * h * w).as_matrix() if np.any(w) else np.eye(3)
            c = np.asarray(pose.center) + sign * h * v
            a = c + (Rw @ (R @ np.asarray(g.attach).T)).T
            return np.linalg.norm(a - np.asarray(g.base), axis=1)

        fd = (moved(1) - moved(-1)) / (2 * h)
        np.testing.assert_allclose(J[:, k], fd, rtol=1e-6, atol=1e-8)


def test_cu5_geometry_matches_device_md():
    g = cu5_geometry()
    L = np.asarray(g.rod_lengths(Pose()))
    assert np.all((L > 0.62) & (L < 0.66))  # "rod lengths at home ≈ 0.63–0.65 m"
    J = np.asarray(g.jacobian(Pose()))
    Js = J @ np.diag([1, 1, 1, 10.0, 10.0])  # rotations scaled by 0.1 m
    assert 4.0 < np.linalg.cond(Js) < 8.0  # "cond(J) ≈ 6"


def test_cu5_plant_span_matches_paper_section_4_3():
    """P = Z_H Z_T⁻¹ singular-value span 25–50 dB over 1–30 Hz (paper 4.3, docs/device.md)."""
    f = np.linspace(1.0, 30.0, 300)
    sv = np.linalg.svd(np.asarray(cu5().P(2j * np.pi * f)), compute_uv=False)
    span = 20 * np.log10(sv[:, 0] / sv[:, -1])
    assert span.min() >= 25.0 and span.max() <= 50.0, (span.min(), span.max())


@pytest.mark.parametrize("n", [3, 5, 6])
def test_second_order_device_impedances_are_exact(n):
    dev = second_order_device(n, seed=n)
    s = 2j * np.pi * np.array([0.5, 3.0, 40.0, 200.0])
    Z_H, Z_T = dev.impedances(s)
    ref_H = np.asarray(dev.hand(s))
    ref_T = np.asarray((dev.hand + dev.mechanism)(s))
    assert rel_err(Z_H, ref_H) < 1e-10
    assert rel_err(Z_T, ref_T) < 1e-10
    # P = Z_H Z_T⁻¹ is the command-to-sensor transfer
    assert rel_err(dev.P(s), ref_H @ np.linalg.inv(ref_T)) < 1e-10


def test_rigid_chain_device_reduces_to_jacobian_mapped_hand():
    """With a (nearly) rigid chain, no modes and no delay, the measured Z_H → J⁻ᵀ Z_cart J⁻¹
    and Z_M → (m1 + m2) s² + b s."""
    import equinox as eqx

    dev = cu5(extra_modes=False, delay_samples=0)
    dev = eqx.tree_at(lambda d: (d.mechanism.k_t, d.mechanism.k_s), dev,
                      (dev.mechanism.k_t * 1e6, dev.mechanism.k_s * 1e6))  # fmt: skip
    s = 2j * np.pi * np.array([1.0, 5.0, 20.0])
    assert rel_err(dev.Z_H(s), dev.hand_rod_impedance(s)) < 1e-4
    mech = np.asarray(dev.Z_M(s))
    expected = (0.5 * s**2 + 30.0 * s)[:, None, None] * np.eye(5)
    assert rel_err(mech, expected) < 1e-4


def test_delay_appears_in_Z_T_and_P_only():
    d0, d1 = cu5(delay_samples=0), cu5(delay_samples=1)
    s = 2j * np.pi * np.array([10.0, 50.0])
    assert rel_err(d1.Z_H(s), d0.Z_H(s)) < 1e-12
    ph = np.exp(s * 1e-3)[:, None, None]
    assert rel_err(d1.Z_T(s), ph * np.asarray(d0.Z_T(s))) < 1e-12


def test_pose_changes_the_plant():
    s = 2j * np.pi * np.array([5.0])
    P0 = np.asarray(cu5().P(s))
    P1 = np.asarray(cu5(Pose().moved(0.05, 0.0, 0.0)).P(s))
    assert rel_err(P1, P0) > 1e-2


def test_unknown_preset_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown device preset"):
        preset("cu7")
