"""The ONE table of command-line checks, applied by ``hapid.cli.main`` after parsing and before
any work: every option of every subcommand has a rule (a test enforces it), and a value out
of range is one line naming the option, the value and what is allowed, e.g.
``--fs must be > 0 Hz, got 0``. Scene files (``run``, ``sweep``, ``paper --scene``) are checked
key by key with the same rules (``check_scene``).

A rule is ``(test, allowed)``: ``test(value) -> bool`` and ``allowed`` the text after
"must be". ``None`` values (an option not given) are never checked.

This module applies the checks (``check_args``, ``check_option``, ``options``). The rules live
in ``_cli_checks_rules`` (constructors, file rules), ``_cli_checks_table`` (the option table,
``rule_for``), ``_cli_checks_cross`` (cross-option rules), ``_cli_checks_scene`` (scene keys)
and ``_cli_checks_io`` (checks that read the files named).
"""

from __future__ import annotations

from ._cli_checks_cross import _CROSS
from ._cli_checks_io import check_out_not_input
from ._cli_checks_rules import _check_in, _check_out, _In, _num, _Out
from ._cli_checks_scene import check_scene, load_scene_checked
from ._cli_checks_table import COMMON, PER_COMMAND, rule_for

__all__ = [
    "MAGNITUDE_MAX",
    "check_args",
    "check_option",
    "check_scene",
    "load_scene_checked",
    "options",
    "rule_for",
]

#: no numeric option is larger in size than this (a value such as 1e300 is a typo, and would
#: overflow the simulation or the fit)
MAGNITUDE_MAX = 1e12


def _show(v) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, list | tuple):
        return " ".join(_show(x) for x in v)
    return str(v)


def check_option(command: str, opt: str, dest: str, value) -> None:
    """Raise ``ValueError`` if ``value`` breaks the rule of ``dest`` (``opt``: its flag)."""
    if value is None:
        return
    rule = rule_for(command, dest)
    if isinstance(rule, _In):
        for v in value if isinstance(value, list) else [value]:
            _check_in(opt, v, rule)
        return
    if isinstance(rule, _Out):
        _check_out(opt, value, rule)
        return
    test, allowed = rule
    if not test(value):
        raise ValueError(f"{opt} must be {allowed}, got {_show(value)}")
    for v in value if isinstance(value, list | tuple) else [value]:
        if _num(v) and abs(v) > MAGNITUDE_MAX:
            raise ValueError(
                f"{opt} must be at most {MAGNITUDE_MAX:g} in size (no physical value is larger), "
                f"got {_show(value)}"
            )


def options(parser, command: str):
    """``[(dest, flag)]`` of every option and positional of ``command``'s subparser."""
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    out = []
    for act in sub._actions:
        if act.dest == "help":
            continue
        flag = max(act.option_strings, key=len) if act.option_strings else act.dest
        out.append((act.dest, flag))
    return out


def check_args(parser, a) -> None:
    """Check every option of the parsed command ``a`` (then scene files and cross-option
    rules); raise ``ValueError`` naming the first problem. Does no work beyond reading small
    text files (scenes)."""
    cmd = a.command
    outs, ins = {}, {}
    for dest, flag in options(parser, cmd):
        check_option(cmd, flag, dest, getattr(a, dest, None))
        rule = PER_COMMAND.get(cmd, {}).get(dest) or COMMON.get(dest)
        if isinstance(rule, _Out) and rule.ext is not None:
            outs[flag] = getattr(a, dest, None)
        elif isinstance(rule, _In):
            ins[flag] = getattr(a, dest, None)
    check_out_not_input(outs, ins)
    extra = _CROSS.get(cmd)
    if extra is not None:
        extra(a)
