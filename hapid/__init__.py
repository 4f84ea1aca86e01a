"""hapid: differentiable system identification of multi-DOF haptic interfaces (JAX).

Importing hapid switches on float64 (``jax_enable_x64``). The subpackages (``control``,
``device``, ``experiment``, ``fit``, ``uncertainty``) and the names below are imported on
first use, so that a command loads only what it needs.
"""

import importlib

from . import _config  # noqa: F401  (float64 before anything else)

__version__ = "0.1.0"

_SUBPACKAGES = ("control", "device", "experiment", "fit", "uncertainty")
_NAMES = {
    "FRF": "frf",
    "as_frf": "frf",
    "ImpedanceModel": "impedance",
    "SecondOrder": "impedance",
    "plant": "impedance",
    "singular_values": "impedance",
    "span_db": "impedance",
    "clear_programs": "_aot",
}
__all__ = [*_SUBPACKAGES, *_NAMES]


def __getattr__(name: str):
    """Import a subpackage or a top-level name on first access (PEP 562)."""
    if name in _SUBPACKAGES:
        return importlib.import_module(f".{name}", __name__)
    if name in _NAMES:
        return getattr(importlib.import_module(f".{_NAMES[name]}", __name__), name)
    raise AttributeError(f"module 'hapid' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *__all__])
