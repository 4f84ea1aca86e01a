"""The rule constructors and value tests of the command-line checks (``hapid._cli_checks``).

A rule is ``(test, allowed)``: ``test(value) -> bool`` and ``allowed`` the text after "must be"
(e.g. ``gt(0, " Hz")`` accepts finite numbers > 0 and reads ``> 0 Hz``). A file rule is an
``_In`` (an input file that must exist, with one of its suffixes) or an ``_Out`` (an output file
or folder whose place must be writable); ``_check_in``/``_check_out`` raise ``ValueError``
naming the option. Also the limits shared by the option and scene-key rules
(``MOVE_LIMIT_M``, ``ROT_LIMIT_RAD``) and the preset names/Nyquist frequency they are checked
against.
"""

from __future__ import annotations

import inspect
import math
from pathlib import Path

from .device._presets import PRESETS

# ---- value tests ----------------------------------------------------------------------------


def _num(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def gt(lo, unit=""):
    return (lambda v: _num(v) and v > lo), f"> {lo:g}{unit}"


def ge(lo, unit=""):
    return (lambda v: _num(v) and v >= lo), f"≥ {lo:g}{unit}"


def between(lo, hi, unit="", lo_open=False, hi_open=False):
    def test(v):
        return _num(v) and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)

    a, b = "(" if lo_open else "[", ")" if hi_open else "]"
    u = unit.strip()
    sep = "" if u in ("°", "") else " "
    return test, f"in {a}{lo:g}{sep}{u}, {hi:g}{sep}{u}{b}"


def int_ge(lo):
    return (lambda v: _int(v) and v >= lo), f"an integer ≥ {lo}"


def int_between(lo, hi):
    return (lambda v: _int(v) and lo <= v <= hi), f"an integer in [{lo}, {hi}]"


def one_of(choices):
    choices = tuple(choices)
    return (lambda v: v in choices), f"one of {', '.join(map(str, choices))}"


ANY = (lambda v: True), "anything"
FLAG = (lambda v: isinstance(v, bool)), "true or false"
SEED = int_between(0, 2**32 - 1)
MOVE_LIMIT_M = 0.2  # the base hexagon's radius: the stylus stays inside the rods' reach
ROT_LIMIT_RAD = 0.5


def _presets():
    return tuple(sorted(PRESETS))


def _nyquist_hz(preset: str = "cu5") -> float:
    return 0.5 * float(inspect.signature(PRESETS[preset]).parameters["fs_hz"].default)


# ---- files ----------------------------------------------------------------------------------
class _In:
    """An input file: must exist, be a file, and have one of ``ext`` (None = any)."""

    def __init__(self, what, ext=None):
        self.what, self.ext = what, ext


class _Out:
    """An output file (``ext``) or folder (``ext`` None): its place must be writable."""

    def __init__(self, what, ext=None):
        self.what, self.ext = what, ext


def _check_in(opt, path, rule: _In):
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{opt}: {p}: no such file (expected {rule.what})")
    if p.is_dir():
        raise ValueError(f"{opt}: {p} is a folder; expected {rule.what}")
    if rule.ext and p.suffix.lower() not in rule.ext:
        raise ValueError(
            f"{opt}: {p} has suffix {p.suffix or '(none)'!r}; expected {rule.what} "
            f"({', '.join(rule.ext)})"
        )


def _check_out(opt, path, rule: _Out):
    p = Path(path)
    if str(path).strip() == "":
        raise ValueError(f"{opt} must be a path, got an empty string")
    if rule.ext is None:
        if p.exists() and not p.is_dir():
            raise ValueError(f"{opt}: {p} is a file; expected {rule.what}")
    else:
        if p.is_dir():
            raise ValueError(f"{opt}: {p} is a folder; expected {rule.what}")
        if p.suffix.lower() not in rule.ext:
            raise ValueError(
                f"{opt}: {p} has suffix {p.suffix or '(none)'!r}; expected {rule.what} "
                f"({', '.join(rule.ext)})"
            )
    for parent in p.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"{opt}: cannot write {p}: {parent} is a file, not a folder")
            break
