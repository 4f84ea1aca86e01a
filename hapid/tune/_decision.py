"""Which g :func:`.robust_design` returns: the start, the tuned g, or one of them with its gain
scaled to what the evidence certifies — one typed :class:`Decision` with its reason.

The comparison of the start and the tuned g is a decision *table* (:data:`RULES`): rows are
tried in order on the two designs' re-check rows (:func:`.table_row` plus the evidence
:func:`.certificate`), and the first row that has an opinion decides. Before it,
:func:`training_decision` checks the tuned g on the training loops; after it, when the chosen
design is not certified or misses the chance level, :func:`certified_fallback` scales the
gains down (:func:`certified_gain`).
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable

from ..control import Compensator
from ._check import FRF_FLOOR
from ._evidence import KAPPA, certificate
from ._tune import largest_gain, scale_gain
from ._validate import table_row, validate

FRF_KEY = "frf_min_loci_distance"  # the measured-FRF figure rows are compared on (certificate)
_EPS = 1e-9


class Choice(enum.StrEnum):
    """The design :func:`.robust_design` returns."""

    TUNED = "tuned"
    START = "start"
    SCALED_START = "scaled start"  # the start with its gain scaled by the evidence
    SCALED_TUNED = "scaled tuned"  # the tuned g with its gain scaled by the evidence


@dataclasses.dataclass(frozen=True)
class Decision:
    """A choice and why: ``rule`` names the row of :data:`RULES` (or ``"training"``,
    ``"fallback"``, ``"not validated"``) that decided, ``reason`` is one line for the user,
    ``gain_scale`` the factor applied to ``k`` (1 unless the choice is scaled)."""

    choice: Choice
    reason: str
    rule: str
    gain_scale: float = 1.0

    @property
    def keeps_tuned(self) -> bool:
        """The tuned g (possibly scaled) is returned."""
        return self.choice in (Choice.TUNED, Choice.SCALED_TUNED)

    def summary(self) -> dict:
        """Strict-JSON: ``choice``, ``rule``, ``reason``, ``gain_scale``."""
        return {"choice": self.choice.value, "rule": self.rule, "reason": self.reason,
                "gain_scale": float(self.gain_scale)}  # fmt: skip

    def __str__(self) -> str:
        return self.reason


def _start(rule: str, reason: str) -> Decision:
    return Decision(Choice.START, "kept the start: " + reason, rule)


def _tuned(rule: str, reason: str) -> Decision:
    return Decision(Choice.TUNED, reason, rule)


def training_decision(res) -> Decision:
    """Is the tuned g (``res.training``) stable on at least as many training loops as the
    start (``res.training0``), and on all it must be wherever the start is? Counted by the
    analysis' Nyquist rule (:func:`hapid.tune.training_verdict`). ``TUNED`` (go on to the
    held-out comparison) or ``START``."""
    tot = lambda d: sum(v[0] for v in d.values())  # noqa: E731
    enough = lambda d: all(v[0] >= v[1] for v in d.values())  # noqa: E731
    a, b = tot(res.training0), tot(res.training)
    if enough(res.training0) and not enough(res.training):
        return _start("training", f"the tuned g leaves training loops unstable ({b} stable "
                      f"against the start's {a})")  # fmt: skip
    if b < a:
        return _start("training", f"{b} stable training loops against the start's {a}")
    if not enough(res.training):
        return _tuned("training", f"no g found that is stable on the training loops ({b} "
                      f"stable, start {a}): not a valid design")  # fmt: skip
    return _tuned("training", "stable on the training loops")


# --- the decision table: each row (start, tuned) -> Decision | None (no opinion) -----------


def _true_plant(s: dict, t: dict) -> Decision | None:
    if s.get("true_stable") and not t.get("true_stable", True):
        return _start("true plant", "the tuned g makes the nominal true plant unstable")
    return None


def _certificate(s: dict, t: dict) -> Decision | None:
    c = "certified"
    if c not in s or c not in t:
        return None
    if s[c] and not t[c]:
        return _start("certificate", "it holds on the evidence (measured FRF, small gain beyond "
                      "it) and the tuned g does not")  # fmt: skip
    if t[c] and not s[c]:
        return _tuned("certificate", f"tuned g kept: it holds on the evidence (measured FRF "
                      f"min |1 + λ| {t[FRF_KEY]:.3g}, loop gain beyond {t['evidence_hz']:.3g} Hz "
                      f"≤ {t['beyond_loop_gain']:.3g}) and the start does not (min |1 + λ| "
                      f"{s[FRF_KEY]:.3g}, gain beyond {s['beyond_loop_gain']:.3g})")  # fmt: skip
    return None


def _neither_certified(s: dict, t: dict) -> Decision | None:
    """Neither certified: the tuned g must be no worse on each evidence figure."""
    if s.get("certified", True) or t.get("certified", True):
        return None
    if s.get("nominal_stable", True) and not t.get("nominal_stable", True):
        return _start("evidence figures", "neither is certified, and the tuned g is not stable "
                      "on the model's own plant while the start is")  # fmt: skip
    if t["beyond_loop_gain"] > max(s["beyond_loop_gain"], KAPPA) + _EPS:
        return _start("evidence figures", f"neither is certified, and beyond the evidence "
                      f"({t['evidence_hz']:.3g} Hz) the tuned loop gain bound "
                      f"{t['beyond_loop_gain']:.3g} exceeds the start's "
                      f"{s['beyond_loop_gain']:.3g}")  # fmt: skip
    if t[FRF_KEY] < s[FRF_KEY] - _EPS:
        return _start("evidence figures", f"neither is certified, and on the measured FRF the "
                      f"tuned loop comes closer to −1 (min |1 + λ| {t[FRF_KEY]:.3g} against "
                      f"{s[FRF_KEY]:.3g})")  # fmt: skip
    return None


def _measured_floor(s: dict, t: dict) -> Decision | None:
    if FRF_KEY in s and FRF_KEY in t and t[FRF_KEY] < min(s[FRF_KEY], FRF_FLOOR) - _EPS:
        return _start("measured FRF", f"on the data's own FRF the tuned g brings the loop "
                      f"closer to −1 (min |1 + λ| {t[FRF_KEY]:.3g} against {s[FRF_KEY]:.3g} "
                      "for the start)")  # fmt: skip
    return None


def _held_out(s: dict, t: dict) -> Decision:
    """Last row, always decides: per held-out family the fraction meeting the margins may not
    drop, and it rises or (equal) the median isotropic bandwidth rises."""
    gains = []
    for fam in ("posterior", "variants"):
        key = f"{fam}_frac_meeting_margins"
        if key not in s:
            continue
        a, b = s[key], t[key]
        if b < a - _EPS:
            return _start("held out", f"on held-out {fam} plants the tuned g meets the margins "
                          f"on {100 * b:.1f} % against {100 * a:.1f} % for the start")  # fmt: skip
        bw_a, bw_b = s[f"{fam}_iso_bandwidth_hz_q50"], t[f"{fam}_iso_bandwidth_hz_q50"]
        if b <= a + _EPS and not bw_b > bw_a + 1e-6:
            return _start("held out", f"no improvement on held-out {fam} plants (margins met "
                          f"on {100 * b:.1f} % vs {100 * a:.1f} %, median bandwidth {bw_b:.3g} "
                          f"vs {bw_a:.3g} Hz)")  # fmt: skip
        gains.append(f"{fam}: margins met {100 * a:.1f} → {100 * b:.1f} %, median bandwidth "
                     f"{bw_a:.3g} → {bw_b:.3g} Hz")  # fmt: skip
    if not gains:
        return _tuned("held out", "no held-out evidence to compare on: tuned g returned unchecked")
    return _tuned("held out", "tuned g kept (no worse than the start on held-out plants): "
                  + "; ".join(gains))  # fmt: skip


RULES: tuple[tuple[str, Callable[[dict, dict], Decision | None]], ...] = (
    ("true plant", _true_plant),  # a stable true plant stays stable
    ("certificate", _certificate),  # the evidence decides first
    ("evidence figures", _neither_certified),  # neither certified: no worse on each figure
    ("measured FRF", _measured_floor),  # not closer to −1 on the data below the floor
    ("held out", _held_out),  # better on the held-out plants
)


def compare(start: dict, tuned: dict) -> Decision:
    """The tuned g against the start on two re-check rows (:func:`.table_row`, plus the
    :func:`.certificate` when there is evidence): the first row of :data:`RULES` with an
    opinion decides. ``TUNED`` or ``START``, with the reason."""
    for _, rule in RULES:
        d = rule(start, tuned)
        if d is not None:
            return d
    raise AssertionError("the last rule always decides")  # pragma: no cover


# --- the certified fallback ----------------------------------------------------------------


def certified_gain(
    g: Compensator, ev, model, floor: float = 0.5, alpha_min: float = 1e-3, iters: int = 14
) -> float | None:
    """Largest ``α ≤ 1`` (bisection in log α) at which ``g`` with its gain ``k`` scaled by
    ``α`` is certified by the evidence (:func:`._evidence.certificate`: nominal loop stable,
    measured loci ``min |1 + λ| ≥ floor``, loop gain beyond the FRF ≤ κ); ``None`` if not even
    ``alpha_min`` is. The bisection keeps the last certified α (monotonicity is not assumed)."""
    certified = lambda gg: certificate(ev, model, gg, floor=floor).certified  # noqa: E731
    if certified(g):
        return 1.0
    return largest_gain(g, certified, alpha_min, iters)


def meets_chance(row: dict, quantile: float) -> bool:
    """Do the held-out posterior draws of a :func:`.table_row` meet the margins at the
    chance level (True when the row has no posterior draws)?"""
    return row.get("posterior_frac_meeting_margins", 1.0) >= quantile - _EPS


def pick_fallback(cands: list, chosen: dict | None, quantile: float):
    """The fallback's choice among certified candidates ``(name, α, g, row)``: those whose
    held-out draws meet the margins at the chance level first (of two, the later one when
    :func:`compare` prefers it); none such and a certified ``chosen`` row: ``None`` (keep
    it); else the better of all."""
    good = [c for c in cands if meets_chance(c[3], quantile)]
    if not good and (chosen or {}).get("certified", False):
        return None
    cands = good or cands
    if not cands:
        return None
    if len(cands) == 2 and compare(cands[0][3], cands[1][3]).keeps_tuned:
        return cands[1]
    return cands[0]


def certified_fallback(candidates, ev, model, check, *, chosen: dict, quantile: float):
    """The chosen design is not certified by the evidence ``ev`` or misses the chance level:
    each of ``candidates`` (``(name, g)``, name ``"start"`` or ``"tuned"``) with its gain
    scaled to the largest value the evidence certifies, re-checked by ``check(g) -> row``. A
    candidate that makes the nominal true plant unstable where ``chosen`` has it stable is
    dropped. ``(Decision, g, row)``, or ``None`` to keep the chosen design (:func:`pick_fallback`).
    """
    cands = []
    for name, g in candidates:
        a = certified_gain(g, ev, model, floor=FRF_FLOOR)
        if a is None:
            continue
        gs = scale_gain(g, a)
        row = check(gs) | certificate(ev, model, gs, floor=FRF_FLOOR).figures()
        if chosen.get("true_stable") and not row.get("true_stable", True):
            continue
        cands.append((name, a, gs, row))
    best = pick_fallback(cands, chosen, quantile)
    if best is None:
        return None
    name, a, gs, row = best
    head = ("neither the start nor the tuned g is certified by the evidence"
            if not chosen.get("certified", False)
            else "the chosen g fails the held-out draws' chance level")  # fmt: skip
    why = (f"{head}: returned the {name} g with its gain scaled by {a:.3g}, the largest the "
           f"evidence certifies (measured min |1 + λ| {row[FRF_KEY]:.3g}, loop gain beyond "
           f"{row['evidence_hz']:.3g} Hz {row['beyond_loop_gain']:.3g})")  # fmt: skip
    choice = Choice.SCALED_TUNED if name == "tuned" else Choice.SCALED_START
    return Decision(choice, why, "fallback", gain_scale=float(a)), gs, row


def holdout_check(model, hold_models, device, variants, omega_c, req, quantile, ts):
    """``g -> row``: the held-out re-check of :func:`.validate` as a :func:`.table_row`."""

    def check(g):
        return table_row(validate(g, model, samples=hold_models, device=device,
                                  variants=variants, omega_c=omega_c, gm_db=req.gm_db,
                                  pm_deg=req.pm_deg, p_required=quantile, ts=ts))  # fmt: skip

    return check
