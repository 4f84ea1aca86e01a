"""The ``--device`` options of the ``hapid`` command, defined once: every subcommand that
simulates or validates on a preset device (simulate, demo, plant, analyze, robust, tune) adds
them with :func:`add_device_args` and builds the device with :func:`device_from_args`, which
goes through the scene's device stage (:func:`hapid.pipeline.device`), so
``hapid plant --device cu5 --delay 2`` and a scene with ``[device] preset = "cu5"``,
``delay_samples = 2`` build the same device."""

from __future__ import annotations

#: the preset names (hapid.device.PRESETS; a test checks they agree) for help texts and errors
PRESET_NAMES = ("cu5", "tripod3", "quad4", "hexapod6", "cu5_soft")
PRESETS_TEXT = ", ".join(PRESET_NAMES)
#: the destinations :func:`add_device_args` adds besides ``device``
VARIANT_DESTS = ("delay", "rod_compliance", "move")


def add_device_args(p, *, default: str | None = "cu5", device_group=None, what: str = "") -> None:
    """Add ``--device PRESET``, ``--delay SAMPLES``, ``--rod-compliance F`` and
    ``--move DX DY DZ`` to the (sub)parser ``p``. ``default``: the preset when ``--device``
    is not given (``None``: no device unless asked); ``device_group``: a group of ``p`` that
    ``--device`` joins (e.g. mutually exclusive with ``--frf``); ``what``: what the device
    is for (help text)."""
    g = p.add_argument_group("device", "a simulated preset device and its variant")
    (device_group or g).add_argument(
        "--device", default=default, metavar="PRESET",
        help=f"preset device{what}: {PRESETS_TEXT}"
        + (f" (default: {default})" if default else ""),
    )  # fmt: skip
    g.add_argument("--delay", type=int, metavar="SAMPLES",
                   help="actuator delay in samples (integer ≥ 0; default: the preset's, 1 for "
                   "cu5, 2 for cu5_soft)")  # fmt: skip
    g.add_argument("--rod-compliance", type=float, metavar="F",
                   help="chain compliance factor > 0: traction and sensor springs divided by F "
                   "(default: the preset's, 1 for cu5, 2 for cu5_soft)")  # fmt: skip
    g.add_argument("--move", type=float, nargs=3, metavar=("DX", "DY", "DZ"),
                   help="move the stylus from home by DX DY DZ metres (default: home)")  # fmt: skip


def device_options(a) -> dict:
    """The scene-style ``[device]`` options of the parsed ``--device`` arguments (the scene
    defaults for everything the command line does not set)."""
    from .scene import DEFAULTS  # local: CLI start-up (hapid.io, equinox)

    o = dict(DEFAULTS["device"])
    o.update(preset=a.device, delay_samples=a.delay, rod_compliance=a.rod_compliance,
             move=list(a.move) if a.move else list(o["move"]))  # fmt: skip
    return o


def device_from_args(a, fs_hz: float | None = None):
    """The device of the parsed ``--device/--delay/--rod-compliance/--move`` arguments
    (:func:`hapid.pipeline.device` of :func:`device_options`); ``fs_hz``: the sampling rate
    (Hz; default the preset's)."""
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    return pipeline.device(device_options(a), fs_hz=fs_hz)


def variant_flags(a) -> list[str]:
    """The variant options given on the command line (``--delay``, …), for the rule that they
    need ``--device``."""
    flags = {"delay": "--delay", "rod_compliance": "--rod-compliance", "move": "--move"}
    return [flags[d] for d in VARIANT_DESTS if getattr(a, d, None) is not None]


def describe(a) -> str:
    """``cu5`` or ``cu5 (delay 2 samples, rod compliance 2, moved by …)`` for reports."""
    parts = []
    if a.delay is not None:
        parts.append(f"delay {a.delay} samples")
    if a.rod_compliance is not None:
        parts.append(f"rod compliance {a.rod_compliance:g}")
    if a.move:
        parts.append("moved by " + " ".join(f"{x:g}" for x in a.move) + " m")
    return a.device + (f" ({', '.join(parts)})" if parts else "")
