"""Physical parts of a simulated interface: the hand (+ stylus) per Cartesian DOF, the
per-rod mechanism chain, and extra (unmodeled) resonances.

All parameters are per-DOF or per-rod arrays so that a device is an ordinary pytree: it can be
``vmap``-ed over virtual subjects or poses. Units are SI (kg, N/m, N·s/m; kg·m², N·m/rad,
N·m·s/rad for rotational DOF).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from .. import _config  # noqa: F401


class Hand(eqx.Module):
    """Stylus + two-layer hand per Cartesian DOF (Fu & Çavuşoğlu 2012).

    Per DOF ``k``: stylus inertia ``m_s`` –(grasp ``k1 ∥ b1``)– hand inertia ``m_h``
    –(arm/wrist ``k2 ∥ b2``)– ground. All fields are ``(n,)`` arrays.
    """

    m_s: Float[Array, " n"]
    k1: Float[Array, " n"]
    b1: Float[Array, " n"]
    m_h: Float[Array, " n"]
    k2: Float[Array, " n"]
    b2: Float[Array, " n"]

    def impedance(self, s: Complex[Array, " N"]) -> Complex[Array, "N n n"]:
        """Cartesian impedance ``Z_cart(s)`` (force / displacement), diagonal ``(N, n, n)``."""
        s = jnp.asarray(s, dtype=jnp.complex128)[:, None]
        z1 = self.k1 + self.b1 * s
        z2 = self.k2 + self.b2 * s + self.m_h * s**2
        z = self.m_s * s**2 + z1 * z2 / (z1 + z2)
        return jax.vmap(jnp.diag)(z)


# docs/device.md, nominal subject: (M kg, k1 N/m, b1 N·s/m, k2 N/m, b2 N·s/m) per translation axis.
_TRANSLATION = {  # world x = fore-aft (along the stylus at home), y = left-right, z = up-down
    "x": (0.204, 769.9, 0.78, 271.7, 18.06),
    "y": (0.218, 379.5, 1.84, 78.8, 4.65),
    "z": (0.269, 552.4, 3.61, 105.3, 6.43),
}
# Rotation (assumed, docs/device.md): inertia 1.5e-3 kg·m²; grasp 0.6 N·m/rad, 0.004 N·m·s/rad;
# wrist 0.4 N·m/rad, 0.02 N·m·s/rad. Roll about the stylus (6-rod device only) is our own
# assumption: a pen rolls easily in the fingers, so a tenth of those numbers.
_ROTATION = (1.5e-3, 0.6, 0.004, 0.4, 0.02)
_ROLL = (1.5e-4, 0.06, 0.0004, 0.04, 0.002)
STYLUS_MASS = 0.06  # kg, stylus with gimbals
STYLUS_INERTIA = 3e-4  # kg·m² about the grip point (pitch/yaw)
STYLUS_ROLL_INERTIA = 1e-5  # kg·m² about the stylus axis (assumed)


def nominal_hand(translations: int = 3, rotation_axes: tuple[int, ...] = (1, 2)) -> Hand:
    """The nominal subject for a device with the given DOF (stylus axes 0 = roll, 1, 2)."""
    rows, ms = [], []
    for ax in "xyz"[:translations]:
        rows.append(_TRANSLATION[ax])
        ms.append(STYLUS_MASS)
    for ax in rotation_axes:
        rows.append(_ROLL if ax == 0 else _ROTATION)
        ms.append(STYLUS_ROLL_INERTIA if ax == 0 else STYLUS_INERTIA)
    p = np.asarray(rows, dtype=float)
    return Hand(
        m_s=jnp.asarray(ms, dtype=float),
        m_h=jnp.asarray(p[:, 0]),
        k1=jnp.asarray(p[:, 1]),
        b1=jnp.asarray(p[:, 2]),
        k2=jnp.asarray(p[:, 3]),
        b2=jnp.asarray(p[:, 4]),
    )


def virtual_subject(key, hand: Hand, translations: int = 3) -> Hand:
    """Draw a virtual subject: translation-axis hand mass, grasp stiffness and arm damping
    log-uniform over the 95 % ranges of docs/device.md (M 0.02–0.57 kg, k1 228–1043 N/m,
    b2 3.7–27.6 N·s/m); other parameters and rotational DOF stay nominal."""
    k1, k2, k3 = jax.random.split(key, 3)
    t = translations

    def logu(k, lo, hi):
        return jnp.exp(jax.random.uniform(k, (t,), minval=np.log(lo), maxval=np.log(hi)))

    return eqx.tree_at(
        lambda h: (h.m_h, h.k1, h.b2),
        hand,
        (
            hand.m_h.at[:t].set(logu(k1, 0.02, 0.57)),
            hand.k1.at[:t].set(logu(k2, 228.0, 1043.0)),
            hand.b2.at[:t].set(logu(k3, 3.7, 27.6)),
        ),
    )


class Mechanism(eqx.Module):
    """Per-rod chain: actuator → motor/roller mass ``m1`` (drive damping to ground) →
    traction spring ``k_t ∥ b_t`` → rod mass ``m2`` → force-sensor spring ``k_s ∥ b_s`` →
    stylus. All fields ``(n,)``.

    ``b_drive`` is the linear-equivalent drive damping used when Coulomb friction is off;
    with friction on, the drive has viscous ``b_viscous`` plus a smoothed Coulomb force of
    magnitude ``coulomb`` (N), ``coulomb·tanh(v / v_smooth)``.
    """

    m1: Float[Array, " n"]
    b_drive: Float[Array, " n"]
    b_viscous: Float[Array, " n"]
    coulomb: Float[Array, " n"]
    k_t: Float[Array, " n"]
    b_t: Float[Array, " n"]
    m2: Float[Array, " n"]
    k_s: Float[Array, " n"]
    b_s: Float[Array, " n"]
    v_smooth: float = 5e-3


# Changed from the lightly damped starting values (docs/device.md): traction damping 8 → 80 N·s/m
# and sensor + gimbal damping 15 → 40 N·s/m. With the light damping the traction resonance
# (45–62 Hz) stands 15–20 dB above any second-order model in P·P̂⁻¹, and the paper's g(s),
# whose 55 Hz notch removes only 8 dB (ζ1/ζ2 = 0.2/0.5), cannot stabilize the MIMO loop
# (GM −3.9 dB with the WLS model, confirmed by closed-loop eigenvalues). That the paper's
# hand-tuned g worked on the hardware (GM ≈ 5 dB, PM ≈ 20°) says its resonances were no
# sharper than its notches; a roller–rod friction contact is well damped. With 80/40 the
# paper's protocol + WLS + paper g gives iso-bandwidth 2.7 Hz, GM 4.3 dB, PM 28°, T peak
# 6.3 dB at 14 Hz (paper: ≈3 Hz, ≈5 dB, ≈20°, 6 dB near 15 Hz); the plant span (set by
# drive damping and geometry) is unchanged. ``light_damping=True`` restores the light values.
def nominal_mechanism(n: int, light_damping: bool = False) -> Mechanism:
    """The per-rod chain of docs/device.md: 0.40 kg, 30 N·s/m (5 viscous + 1 N Coulomb),
    traction 2.5e4 N/m, rod 0.10 kg, sensor 4e4 N/m, identical for every rod; traction and
    sensor damping 80 and 40 N·s/m (8 and 15 with ``light_damping``)."""
    f = lambda v: jnp.full((n,), float(v))  # noqa: E731
    b_t, b_s = (8.0, 15.0) if light_damping else (80.0, 40.0)
    return Mechanism(
        m1=f(0.40), b_drive=f(30.0), b_viscous=f(5.0), coulomb=f(1.0),
        k_t=f(2.5e4), b_t=f(b_t), m2=f(0.10), k_s=f(4e4), b_s=f(b_s),
    )  # fmt: skip


def compliant_rods(mech: Mechanism, factor: float = 1.0) -> Mechanism:
    """``mech`` with its chain ``factor`` times as compliant: traction and sensor stiffness
    ``k_t``, ``k_s`` divided by ``factor`` (> 0; 1 leaves ``mech`` unchanged)."""
    if not float(factor) > 0.0:
        raise ValueError(f"rod compliance factor must be > 0, got {factor!r}")
    if float(factor) == 1.0:
        return mech
    return eqx.tree_at(lambda m: (m.k_t, m.k_s), mech, (mech.k_t / factor, mech.k_s / factor))


class ExtraModes(eqx.Module):
    """Unmodeled resonances: per mode a mass attached to every rod's motor (``node = 0``) or
    rod (``node = 1``) through a spring-damper tuned to ``f_hz`` with damping ratio ``zeta``.
    Arrays are ``(n_modes,)``; the same modes are added to every rod."""

    f_hz: Float[Array, " m"]
    zeta: Float[Array, " m"]
    mass: Float[Array, " m"]
    node: tuple[int, ...] = eqx.field(static=True, default=())

    @property
    def count(self) -> int:
        return len(self.node)


def no_modes() -> ExtraModes:
    return ExtraModes(jnp.zeros((0,)), jnp.zeros((0,)), jnp.zeros((0,)), ())


def default_modes() -> ExtraModes:
    """cu5's one extra mode: actuator-mount compliance, 30 g at 230 Hz, ζ = 0.03, on the
    motor. Our assumption (docs/device.md leaves "extra modes" open): above the fit band, it
    makes the measured impedances deviate from second order near the top of the protocol."""
    return ExtraModes(jnp.array([230.0]), jnp.array([0.03]), jnp.array([0.03]), (0,))
