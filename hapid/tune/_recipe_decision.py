"""The decision rules of ``robust_design``: which of the start and the tuned g it returns.

* ``training_no_worse(res)``: the tuned g stable on at least as many training loops as the
  start (``(ok, why)``).
* ``no_worse(start, tuned)``: the tuned g no worse than the start on the held-out evidence of
  two :func:`.table_row` rows (``(verdict, why)``).
* the certified fallback (``_certified_fallback``, ``pick_fallback``, ``certified_gain``):
  when the chosen g is not certified by the measured evidence or misses the chance level,
  the start and the tuned g scaled to the largest gain the evidence certifies, re-checked.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..control import Compensator
from ._check import FRF_FLOOR
from ._evidence import KAPPA, certificate
from ._params import ParamMap
from ._tune import largest_gain, scale_gain
from ._validate import table_row, validate


def certified_gain(
    g: Compensator, ev, model, floor: float = 0.5, alpha_min: float = 1e-3, iters: int = 14
) -> float | None:
    """Largest ``α ≤ 1`` (bisection in log α) at which ``g`` with its gain ``k`` scaled by
    ``α`` is certified by the evidence (:func:`._evidence.certificate`: nominal loop stable,
    measured loci ``min |1 + λ| ≥ floor``, loop gain beyond the FRF ≤ κ); ``None`` if not even
    ``alpha_min`` is. Lower gain shrinks the loop everywhere, so the certificate's figures
    improve monotonically in practice (not assumed: the bisection keeps the last certified α)."""
    certified = lambda gg: certificate(ev, model, gg, floor=floor)["certified"]  # noqa: E731
    if certified(g):
        return 1.0
    return largest_gain(g, certified, alpha_min, iters)


def _certified_fallback(out, g0, res, ev, model, hold_models, device, variants, omega_c, req,
                        quantile, *, with_tuned: bool = True, chosen: dict | None = None,
                        ts: float | None = None):  # fmt: skip
    """The chosen design is not certified by the evidence, or fails the held-out draws'
    chance level (``quantile`` of them meeting the margins): the start and the tuned g, each
    with its gain scaled down to the largest value the evidence certifies
    (:func:`certified_gain`), re-checked like the others. A candidate certified *and* at the
    chance level is preferred (the better of two by :func:`no_worse`); when none is, a
    certified ``chosen`` design is kept (``None``: lowering the gain trades one failed
    figure for another — it can move the crossover below the lowest measured frequency,
    where the certificate sees nothing), else the better certified candidate is returned.
    The tuned g only with ``with_tuned`` (it passed :func:`training_no_worse`); a candidate
    that makes the nominal true plant unstable where the ``chosen`` design's row has it
    stable is dropped. ``ts``: the held-out draws' controller rate (:func:`.validate`).
    ``(result, row, decision)`` or ``None``."""
    cands = []
    pairs = (("start", g0), ("tuned", out["candidate"].g)) if with_tuned else (("start", g0),)
    for name, g in pairs:
        a = certified_gain(g, ev, model, floor=FRF_FLOOR)
        if a is None:
            continue
        gs = scale_gain(g, a)
        v = validate(gs, model, samples=hold_models, device=device, variants=variants,
                     omega_c=omega_c, gm_db=req.gm_db, pm_deg=req.pm_deg, p_required=quantile,
                     ts=ts)  # fmt: skip
        row = table_row(v) | certificate(ev, model, gs, floor=FRF_FLOOR)
        if (chosen or {}).get("true_stable") and not row.get("true_stable", True):
            continue
        cands.append((name, a, gs, row))
    best = pick_fallback(cands, chosen, quantile)
    if best is None:
        return None
    name, a, gs, row = best
    pm = ParamMap.from_template(gs)
    head = ("neither the start nor the tuned g is certified by the evidence"
            if not (chosen or {}).get("certified", False)
            else "the chosen g fails the held-out draws' chance level")  # fmt: skip
    why = (f"{head}: returned the "
           f"{name} g with its gain scaled by {a:.3g}, the largest the evidence certifies "
           f"(measured min |1 + λ| {row['frf_min_loci_distance']:.3g}, loop gain beyond "
           f"{row['evidence_hz']:.3g} Hz {row['beyond_loop_gain']:.3g})")  # fmt: skip
    return dataclasses.replace(res, g=gs, x=np.asarray(pm.vector(gs))), row, why


def pick_fallback(cands: list, chosen: dict | None, quantile: float):
    """The fallback's choice among certified candidates ``(name, α, g, row)`` (rows of
    :func:`.table_row` plus the certificate): those whose held-out draws meet the margins at
    the chance level first (of two, the later one when :func:`no_worse` prefers it); none
    such and a certified ``chosen`` row: ``None`` (keep it); else the better of all."""
    good = [c for c in cands if _meets_chance(c[3], quantile)]
    if not good and (chosen or {}).get("certified", False):
        return None
    cands = good or cands
    if not cands:
        return None
    if len(cands) == 2 and no_worse(cands[0][3], cands[1][3])[0]:
        return cands[1]
    return cands[0]


def _meets_chance(row: dict, quantile: float) -> bool:
    """Do the held-out posterior draws of a :func:`.table_row` meet the margins at the
    chance level (True when the row has no posterior draws)?"""
    return row.get("posterior_frac_meeting_margins", 1.0) >= quantile - 1e-9


FRF_KEY = "frf_min_loci_distance"  # the measured-FRF figure rows are compared on (certificate)


def training_no_worse(res) -> tuple[bool, str]:
    """``(ok, why)``: is the tuned g (``res.training``) stable on at least as many training
    loops as the start (``res.training0``), and on all it must be wherever the start is?
    Counted by the analysis' Nyquist rule (:func:`hapid.tune.training_verdict`)."""
    tot = lambda d: sum(v[0] for v in d.values())  # noqa: E731
    enough = lambda d: all(v[0] >= v[1] for v in d.values())  # noqa: E731
    a, b = tot(res.training0), tot(res.training)
    if enough(res.training0) and not enough(res.training):
        return False, (f"kept the start: the tuned g leaves training loops unstable "
                       f"({b} stable against the start's {a})")  # fmt: skip
    if b < a:
        return False, f"kept the start: {b} stable training loops against the start's {a}"
    if not enough(res.training):
        return True, (f"no g found that is stable on the training loops ({b} stable, start "
                      f"{a}): not a valid design")  # fmt: skip
    return True, "stable on the training loops"


def no_worse(start: dict, tuned: dict) -> tuple[bool, str]:
    """Is the tuned design no worse than the start on the held-out evidence of two
    :func:`.table_row` rows? ``(verdict, one-line reason)``. Evidence, in order: the nominal
    true plant stays stable (when present); for each family (posterior, variants) the
    fraction of plants meeting the margins does not drop, and it either rises or, equal, the
    median isotropic bandwidth rises — a tuned g that improves nothing is not returned. With
    ``frf_min_loci_distance`` in both rows (:func:`._evidence.certificate`, the measured FRF)
    the tuned g may not bring the loop on the data closer to −1 than the start when it falls
    below ``FRF_FLOOR``. With ``certified`` in both rows (:func:`._evidence.certificate`:
    evidence) the evidence decides first: a certified start is never traded for an
    uncertified g, and a certified tuned g replaces an uncertified start. When *neither* is
    certified, both are judged on the same evidence figures: the tuned g must be no worse on
    each (stable on the model's own plant if the start is, measured return difference not
    lower, beyond-band gain bound not above ``max(start, κ)``) and then better on the held-out
    draws; otherwise the start is kept and the reason says which figure decided."""
    if start.get("true_stable") and not tuned.get("true_stable", True):
        return False, "kept the start: the tuned g makes the nominal true plant unstable"
    c = "certified"
    if c in start and c in tuned:
        if start[c] and not tuned[c]:
            return False, ("kept the start: it holds on the evidence (measured FRF, small gain "
                           "beyond it) and the tuned g does not")  # fmt: skip
        if tuned[c] and not start[c]:
            return True, ("tuned g kept: it holds on the evidence (measured FRF min |1 + λ| "
                          f"{tuned[FRF_KEY]:.3g}, loop gain beyond "
                          f"{tuned['evidence_hz']:.3g} Hz ≤ {tuned['beyond_loop_gain']:.3g}) and the "
                          f"start does not (min |1 + λ| {start[FRF_KEY]:.3g}, gain "
                          f"beyond {start['beyond_loop_gain']:.3g})")  # fmt: skip
        if not tuned[c]:  # neither certified: the tuned g must be no worse on each figure
            if start.get("nominal_stable", True) and not tuned.get("nominal_stable", True):
                return False, ("kept the start: neither is certified, and the tuned g is not stable "
                               "on the model's own plant while the start is")  # fmt: skip
            if tuned["beyond_loop_gain"] > max(start["beyond_loop_gain"], KAPPA) + 1e-9:
                return False, (f"kept the start: neither is certified, and beyond the evidence "
                               f"({tuned['evidence_hz']:.3g} Hz) the tuned loop gain bound "
                               f"{tuned['beyond_loop_gain']:.3g} exceeds the start's "
                               f"{start['beyond_loop_gain']:.3g}")  # fmt: skip
            k = FRF_KEY
            if tuned[k] < start[k] - 1e-9:
                return False, (f"kept the start: neither is certified, and on the measured FRF the "
                               f"tuned loop comes closer to −1 (min |1 + λ| {tuned[k]:.3g} against "
                               f"{start[k]:.3g})")  # fmt: skip
    k = FRF_KEY
    if k in start and k in tuned and tuned[k] < min(start[k], FRF_FLOOR) - 1e-9:
        return False, (f"kept the start: on the data's own FRF the tuned g brings the loop closer to "
                       f"−1 (min |1 + λ| {tuned[k]:.3g} against {start[k]:.3g} for the start)")  # fmt: skip
    gains = []
    for fam in ("posterior", "variants"):
        key = f"{fam}_frac_meeting_margins"
        if key not in start:
            continue
        a, b = start[key], tuned[key]
        if b < a - 1e-9:
            return False, (f"kept the start: on held-out {fam} plants the tuned g meets the margins "
                           f"on {100 * b:.1f} % against {100 * a:.1f} % for the start")  # fmt: skip
        bw_a, bw_b = start[f"{fam}_iso_bandwidth_hz_q50"], tuned[f"{fam}_iso_bandwidth_hz_q50"]
        if b <= a + 1e-9 and not bw_b > bw_a + 1e-6:
            return False, (f"kept the start: no improvement on held-out {fam} plants (margins met on "
                           f"{100 * b:.1f} % vs {100 * a:.1f} %, median bandwidth {bw_b:.3g} vs "
                           f"{bw_a:.3g} Hz)")  # fmt: skip
        gains.append(f"{fam}: margins met {100 * a:.1f} → {100 * b:.1f} %, median bandwidth "
                     f"{bw_a:.3g} → {bw_b:.3g} Hz")  # fmt: skip
    if not gains:
        return True, "no held-out evidence to compare on: tuned g returned unchecked"
    return True, "tuned g kept (no worse than the start on held-out plants): " + "; ".join(gains)
