"""Names of a package that load on first use (PEP 562).

``__getattr__, __dir__ = lazy_names(__name__, {"name": "_submodule", ...})`` in a package's
``__init__``: ``package.name`` imports ``package._submodule`` the first time it is read, so a
command that never reads it does not pay that submodule's imports.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable


def lazy_names(package: str, names: dict[str, str]) -> tuple[Callable, Callable]:
    """``(__getattr__, __dir__)`` of ``package`` (its ``__name__``), where ``names`` maps each
    lazy public name to the relative submodule that defines it (``"_files"``). ``__getattr__``
    raises ``AttributeError`` for any other name; ``__dir__`` lists the module's own names and
    the lazy ones."""

    def __getattr__(name: str):
        if name in names:
            return getattr(importlib.import_module(f".{names[name]}", package), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__():
        return sorted({*vars(sys.modules[package]), *names})

    return __getattr__, __dir__
