"""Preset devices: ``cu5`` (docs/device.md), a 3-rod tripod, a 4-rod ``quad4``, a 6-rod
hexapod and ``cu5_soft`` (cu5 with 1 ms more delay and compliant rods).

Every preset takes the same keywords: ``pose``, ``extra_modes``, ``delay_samples`` (actuator
delay, samples), ``fs_hz``, ``light_damping``, ``encoder`` and ``rod_compliance`` (the
chain's compliance factor, :func:`compliant_rods`)."""

from __future__ import annotations

from ._device import ParallelDevice
from ._geometry import Pose, cu5_geometry, hexapod_geometry, quad_geometry, tripod_geometry
from ._parts import compliant_rods, default_modes, no_modes, nominal_hand, nominal_mechanism


def _parallel(geometry, hand, pose, extra_modes, delay_samples, fs_hz, light_damping=False,
              encoder="motor", rod_compliance=1.0) -> ParallelDevice:  # fmt: skip
    return ParallelDevice(
        geometry=geometry,
        pose=pose if pose is not None else Pose(),
        hand=hand,
        mechanism=compliant_rods(nominal_mechanism(geometry.n, light_damping), rod_compliance),
        modes=default_modes() if extra_modes else no_modes(),
        fs_hz=fs_hz,
        delay_samples=delay_samples,
        encoder=encoder,
    )


def cu5(pose: Pose | None = None, *, extra_modes: bool = True, delay_samples: int = 1,
        fs_hz: float = 1000.0, light_damping: bool = False,
        encoder: str = "motor", rod_compliance: float = 1.0) -> ParallelDevice:  # fmt: skip
    """The default 5-rod device of docs/device.md (3 translations + 2 rotations of the stylus).

    ``encoder="motor"`` (default) reads rod length at the motor/roller, so the measured Z_H
    includes the traction and sensor compliance; ``"rod"`` reads the rod itself.
    ``rod_compliance`` multiplies the chain's compliances (traction and sensor springs
    divided by it, :func:`compliant_rods`).
    """
    return _parallel(cu5_geometry(), nominal_hand(3, (1, 2)), pose, extra_modes, delay_samples,
                     fs_hz, light_damping, encoder, rod_compliance)  # fmt: skip


CU5_SOFT_DELAY = 2  # samples at 1 kHz: 1 ms more than cu5
CU5_SOFT_COMPLIANCE = 2.0


def cu5_soft(pose: Pose | None = None, *, extra_modes: bool = True,
             delay_samples: int = CU5_SOFT_DELAY, fs_hz: float = 1000.0,
             light_damping: bool = False, encoder: str = "motor",
             rod_compliance: float = CU5_SOFT_COMPLIANCE) -> ParallelDevice:  # fmt: skip
    """cu5 with 1 ms more actuator delay (2 samples at 1 kHz) and compliant rods (traction
    and sensor springs halved: traction resonance ≈ 80 → 56 Hz). The held-out device of the
    robust-design check: never used to choose tuning settings."""
    return cu5(pose, extra_modes=extra_modes, delay_samples=delay_samples, fs_hz=fs_hz,
               light_damping=light_damping, encoder=encoder, rod_compliance=rod_compliance)  # fmt: skip


def tripod3(pose: Pose | None = None, *, extra_modes: bool = True, delay_samples: int = 1,
            fs_hz: float = 1000.0, light_damping: bool = False, encoder: str = "motor",
            rod_compliance: float = 1.0) -> ParallelDevice:  # fmt: skip
    """A 3-rod translational device with cu5's chain and the nominal hand's translations."""
    return _parallel(tripod_geometry(), nominal_hand(3, ()), pose, extra_modes, delay_samples,
                     fs_hz, light_damping, encoder, rod_compliance)  # fmt: skip


def quad4(pose: Pose | None = None, *, extra_modes: bool = True, delay_samples: int = 1,
          fs_hz: float = 1000.0, light_damping: bool = False, encoder: str = "motor",
          rod_compliance: float = 1.0) -> ParallelDevice:  # fmt: skip
    """A 4-rod device with cu5's chain and hand: cu5 without its 240° rod, controlling the 3
    translations + pitch (rotation about the stylus' ŷ axis; :func:`quad_geometry`)."""
    return _parallel(quad_geometry(), nominal_hand(3, (1,)), pose, extra_modes, delay_samples,
                     fs_hz, light_damping, encoder, rod_compliance)  # fmt: skip


def hexapod6(pose: Pose | None = None, *, extra_modes: bool = True, delay_samples: int = 1,
             fs_hz: float = 1000.0, light_damping: bool = False, encoder: str = "motor",
             rod_compliance: float = 1.0) -> ParallelDevice:  # fmt: skip
    """A 6-rod, 6-DOF device (roll about the stylus controlled too)."""
    return _parallel(hexapod_geometry(), nominal_hand(3, (0, 1, 2)), pose, extra_modes,
                     delay_samples, fs_hz, light_damping, encoder, rod_compliance)  # fmt: skip


PRESETS = {
    "cu5": cu5,
    "tripod3": tripod3,
    "quad4": quad4,
    "hexapod6": hexapod6,
    "cu5_soft": cu5_soft,
}


def preset(name: str, **kwargs) -> ParallelDevice:
    """A preset device by name (``cu5``, ``tripod3``, ``quad4``, ``hexapod6``, ``cu5_soft``)
    with the preset's keywords (``delay_samples``, ``rod_compliance``, ``pose``, …: the module
    docstring)."""
    if name not in PRESETS:
        raise ValueError(f"unknown device preset {name!r}; choose one of {sorted(PRESETS)}")
    return PRESETS[name](**kwargs)
