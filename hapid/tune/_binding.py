"""Which constraint binds a tuned g(s): exact constraint values at a design and where they act.

The tuner (:func:`hapid.tune.tune`) maximizes the claimed robust bandwidth ``u = ln ω_b``
under smooth constraints (soft maxima, :mod:`._objective`). At its optimum the bandwidth is
held back by the *active* ones. :func:`binding_constraints` evaluates each of them exactly
(true maxima, no soft max) at a given g on the tuner's own scenarios, says where it acts
(the frequency, the scenarios) and, given the tuner's final smooth values, the quadratic
penalty's multiplier estimate ``λ_j = 2 μ max(0, c_j)`` — for ``f = −u + μ Σ max(0, c_j)²``
the first-order gain in ``ln ω_b`` per unit (log) relaxation of constraint ``j`` (zero for a
constraint the penalty optimum leaves slack). Constraints, all ``≤ 0`` when met, natural-log
units:

* ``<family>/ms`` — loci disc ``max −ln|1 + g λ_i| − ln M_s``: per scenario its maximum over
  the training grid and the family's dense grid (:attr:`.Family.dense`); over the family the
  mean of the ``K`` worst scenarios (the CVaR the tuner uses, ``K = 1`` for a strict family);
  ``where_hz`` the frequencies of those worst points.
* ``evidence/small_gain`` — ``max_ω ln(|g(jω)| / g_max)`` on :attr:`.Requirements.sg_omega`.
* ``g/dc`` — ``ln(min_dc_gain / |g(0)|)``.
* ``box`` — the smallest distance (log units) of a parameter to the soft box of
  :meth:`.Box.default`, negated (``≥ 0``: at or beyond the edge).
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from .._plain import jsonable
from ._objective import Box, Requirements
from ._params import ParamMap
from ._response import g_response

ACTIVE_TOL = 0.01
"""A constraint within this (log units, ≈ 1 %) of its bound counts as active."""


class BindingStatus(enum.StrEnum):
    """Whether every constraint is met at the design (value ≤ 0)."""

    MET = "met"
    VIOLATED = "violated"


@dataclasses.dataclass(frozen=True)
class Constraint:
    """One constraint of the design problem at ``g`` (log units, ``value ≤ 0`` met).

    - ``value``: the exact value; ``active``: ``value > −ACTIVE_TOL``.
    - ``smooth_value``, ``multiplier``: the tuner's final smooth value and the penalty's
      multiplier estimate (``None`` unless the tuner's values were given).
    - loci disc (``<family>/ms``): ``K`` the scenarios averaged, ``where_hz`` (Hz) and
      ``values_there`` at the worst points, ``n_violating`` scenarios with ``value > 0``.
    - small gain: ``where_hz`` the frequency of the largest ``|g|``.
    - ``g/dc``: ``dc_gain`` ``|g(0)|`` and its ``floor``.
    - ``box``: the ``parameter`` nearest an ``edge`` (``"upper"``/``"lower"``).
    """

    value: float
    active: bool
    smooth_value: float | None = None
    multiplier: float | None = None
    K: int | None = None
    where_hz: list[float] | None = None
    values_there: list[float] | None = None
    n_violating: int | None = None
    dc_gain: float | None = None
    floor: float | None = None
    parameter: str | None = None
    edge: str | None = None

    def summary(self) -> dict:
        """The fields that apply (``None`` ones left out), strict JSON."""
        return jsonable({k: v for k, v in dataclasses.asdict(self).items() if v is not None})


@dataclasses.dataclass(frozen=True)
class Binding:
    """Every constraint of the design problem at one ``g`` (:func:`binding_constraints`):
    ``constraints`` maps each name (``<family>/ms``, ``evidence/small_gain``, ``g/dc``,
    ``box``) to its :class:`Constraint`; ``b[name]`` reads one."""

    constraints: dict[str, Constraint]

    def __getitem__(self, name: str) -> Constraint:
        return self.constraints[name]

    def __contains__(self, name: str) -> bool:
        return name in self.constraints

    @property
    def active(self) -> list[str]:
        """Names of the active constraints (those that hold the bandwidth back)."""
        return [k for k, c in self.constraints.items() if c.active]

    @property
    def ok(self) -> bool:
        """Every constraint met (``value ≤ 0``)."""
        return all(c.value <= 0.0 for c in self.constraints.values())

    @property
    def status(self) -> BindingStatus:
        """:class:`BindingStatus`: ``MET`` (:attr:`ok`) or ``VIOLATED``."""
        return BindingStatus.MET if self.ok else BindingStatus.VIOLATED

    def summary(self) -> dict:
        """Strict-JSON summary: status, ok, the active names and every constraint's fields."""
        return {"status": self.status.value, "ok": self.ok, "active": self.active,
                "constraints": {k: c.summary() for k, c in self.constraints.items()}}  # fmt: skip


def locus_distance(g, sc) -> np.ndarray:
    """``(S, N)``: ``min_i |1 + g(jω) λ_i(Q_s(jω))|`` on the scenarios' grid."""
    gam = np.asarray(g_response(g, sc.omega, sc.ts))
    return np.abs(1.0 + gam[None, :, None] * np.asarray(sc.lam)).min(axis=-1)


def _family_margin(g, fam, ms: float, n_where: int) -> dict:
    grids = [fam.scenarios] + ([fam.dense] if fam.dense is not None else [])
    vals, freqs = [], []
    for sc in grids:
        d = locus_distance(g, sc)
        vals.append(-np.log(d) - np.log(ms))  # (S, N)
        freqs.append(np.asarray(sc.omega) / TWO_PI)
    v = np.concatenate(vals, axis=1)
    f = np.concatenate(freqs)
    per = v.max(axis=1)
    K = fam.k_worst()
    S = per.size
    if S == 1:  # one plant: its worst local maxima over frequency
        o = np.argsort(f)
        vs = v[0, o]
        pad = np.concatenate([[-np.inf], vs, [-np.inf]])
        peaks = np.nonzero((vs >= pad[:-2]) & (vs >= pad[2:]))[0]
        order = o[peaks[np.argsort(vs[peaks])[::-1]][:n_where]]
        return {"value": float(per[0]), "K": 1, "where_hz": [float(f[i]) for i in order],
                "values_there": [float(v[0, i]) for i in order],
                "n_violating": int(per[0] > 0)}  # fmt: skip
    top = np.argsort(per)[::-1][:K]
    return {"value": float(per[top].mean()), "K": int(K),
            "where_hz": [float(f[v[s].argmax()]) for s in top],
            "values_there": [float(per[s]) for s in top],
            "n_violating": int(np.sum(per > 0))}  # fmt: skip


def binding_constraints(g, families, req: Requirements, *, f_max_hz: float,
                        constraints: dict | None = None, mu: float | None = None,
                        n_where: int = 4, active_tol: float = ACTIVE_TOL) -> Binding:  # fmt: skip
    """:class:`Binding`: every constraint of the design problem at ``g`` (see the module
    docstring). ``families``: the tuner's :class:`.Family` list; ``f_max_hz``: the top of g's
    frequency box the tuner used; ``constraints`` and ``mu`` (optional): the tuner's final
    smooth values (:attr:`TuneResult.constraints`) and penalty weight, for the multiplier
    estimates (:class:`Constraint`)."""
    out = {}
    ms = req.ms
    for fam in families:
        if fam.margins:
            out[f"{fam.name}/ms"] = _family_margin(g, fam, ms, n_where)
    if req.sg_omega is not None:
        om = np.asarray(req.sg_omega, dtype=float)
        lg = np.abs(np.asarray(g_response(g, om, req.sg_ts)))
        i = int(lg.argmax())
        out["evidence/small_gain"] = {"value": float(np.log(lg[i] / req.sg_g_max)),
                                      "where_hz": [float(om[i] / TWO_PI)]}  # fmt: skip
    if req.min_dc_gain is not None:
        dc = float(np.abs(np.asarray(g(np.array([0.0])))[0]))
        out["g/dc"] = {"value": float(np.log(req.min_dc_gain / dc)), "dc_gain": dc,
                       "floor": float(req.min_dc_gain)}  # fmt: skip
    pm = ParamMap.from_template(g)
    x = np.asarray(pm.vector(g))
    box = Box.default(pm, f_max_hz)
    lo, hi = x - box.lo, box.hi - x
    j = int(np.minimum(lo, hi).argmin())
    out["box"] = {"value": float(-min(lo[j], hi[j])), "parameter": pm.names[j],
                  "edge": "upper" if hi[j] < lo[j] else "lower"}  # fmt: skip
    entries = {}
    for name, e in out.items():
        e["active"] = bool(e["value"] > -active_tol)
        if constraints is not None and name in constraints:
            c = float(constraints[name])
            e["smooth_value"] = c
            if mu is not None:
                e["multiplier"] = float(2.0 * mu * max(0.0, c))
        entries[name] = Constraint(**e)
    return Binding(entries)
