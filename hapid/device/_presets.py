"""Preset devices: ``cu5`` (docs/device.md), a 3-rod tripod and a 6-rod hexapod."""

from __future__ import annotations

from ._device import ParallelDevice
from ._geometry import Pose, cu5_geometry, hexapod_geometry, tripod_geometry
from ._parts import default_modes, no_modes, nominal_hand, nominal_mechanism


def _parallel(geometry, hand, pose, extra_modes, delay_samples, fs_hz, light_damping=False,
              encoder="motor") -> ParallelDevice:  # fmt: skip
    return ParallelDevice(
        geometry=geometry,
        pose=pose if pose is not None else Pose(),
        hand=hand,
        mechanism=nominal_mechanism(geometry.n, light_damping),
        modes=default_modes() if extra_modes else no_modes(),
        fs_hz=fs_hz,
        delay_samples=delay_samples,
        encoder=encoder,
    )


def cu5(pose: Pose | None = None, *, extra_modes: bool = True, delay_samples: int = 1,
        fs_hz: float = 1000.0, light_damping: bool = False,
        encoder: str = "motor") -> ParallelDevice:  # fmt: skip
    """The default 5-rod device of docs/device.md (3 translations + 2 rotations of the stylus).

    ``encoder="motor"`` (default) reads rod length at the motor/roller, so the measured Z_H
    includes the traction and sensor compliance; ``"rod"`` reads the rod itself.
    """
    return _parallel(cu5_geometry(), nominal_hand(3, (1, 2)), pose, extra_modes, delay_samples,
                     fs_hz, light_damping, encoder)  # fmt: skip


def tripod3(pose: Pose | None = None, *, extra_modes: bool = True, delay_samples: int = 1,
            fs_hz: float = 1000.0) -> ParallelDevice:  # fmt: skip
    """A 3-rod translational device with cu5's chain and the nominal hand's translations."""
    return _parallel(tripod_geometry(), nominal_hand(3, ()), pose, extra_modes, delay_samples, fs_hz)


def hexapod6(pose: Pose | None = None, *, extra_modes: bool = True, delay_samples: int = 1,
             fs_hz: float = 1000.0) -> ParallelDevice:  # fmt: skip
    """A 6-rod, 6-DOF device (roll about the stylus controlled too)."""
    return _parallel(hexapod_geometry(), nominal_hand(3, (0, 1, 2)), pose, extra_modes,
                     delay_samples, fs_hz)  # fmt: skip


PRESETS = {"cu5": cu5, "tripod3": tripod3, "hexapod6": hexapod6}


def preset(name: str, **kwargs) -> ParallelDevice:
    """A preset device by name (``cu5``, ``tripod3``, ``hexapod6``)."""
    try:
        return PRESETS[name](**kwargs)
    except KeyError:
        raise ValueError(f"unknown device preset {name!r}; choose one of {sorted(PRESETS)}") from None
