# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""The result of :func:`hapid.uncertainty.robust_check`: :class:`RobustReport`, per-plant
arrays ``(S,)`` of the loop figures (``FIELDS``) and their summary (quantiles, verdict,
reasons, rows).

Summary statistics. An unstable sample counts as the worst possible value of every margin
(``−inf`` dB/deg, disk margin 0) and of the bandwidth (0 Hz), so a 5 % quantile is only
finite when fewer than 5 % of the samples are unstable. ``passed``: ``P(stable) ≥
p_stable_required`` and the 5 % quantiles of GM and PM meet ``gm_db`` / ``pm_deg``;
:meth:`RobustReport.reasons` says which requirement failed and by how much.

**Margin sign convention** (the same as :func:`hapid.control.max_siso_gain`). The raw
``gm_db``/``pm_deg`` of a plant are *signed* (``pm = ∠λ + 180°`` wrapped to [−180°, 180°) at
the gain crossing nearest −1; a negative value means the locus crosses beyond −180°, a
conditionally stable crossing that a phase *lead* or gain *decrease* would destabilize).
Stability is decided by the generalized Nyquist count, not by the sign; on a loop that count
calls stable, the margin is the size of the smallest perturbation that reaches −1, i.e.
``|GM|`` and ``|PM|``. Quantiles and ``passed`` therefore use ``|GM|``, ``|PM|`` of stable
plants (unstable: ``−inf``); :meth:`RobustReport.rows` keeps the signed values.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._plain import jsonable
from ..defaults import GM_DB, PM_DEG
from ..verdict import Check, Verdict
from ._cover import EvidenceCover, cover_check

FIELDS = (
    "gm_db",
    "pm_deg",
    "disk_margin",
    "disk_gm_db",
    "disk_pm_deg",
    "iso_bandwidth_hz",
    "t_peak_db",
)
# robust_check(metrics=...) name → the report fields it fills
METRICS = {"disk": ("disk_margin", "disk_gm_db", "disk_pm_deg"), "t_peak": ("t_peak_db",)}
_WORST = {"gm_db": -np.inf, "pm_deg": -np.inf, "disk_margin": 0.0, "disk_gm_db": 0.0,
          "disk_pm_deg": 0.0, "iso_bandwidth_hz": 0.0, "t_peak_db": np.inf}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class RobustReport:
    """Per-plant results (arrays ``(S,)``) and their summary.

    ``stable``, ``n_closed_loop_rhp``, ``gm_db``, ``pm_deg``, ``disk_margin``, ``disk_gm_db``,
    ``disk_pm_deg``, ``iso_bandwidth_hz``, ``t_peak_db`` (raw values of
    :class:`hapid.control.LoopMetrics`); ``labels`` (optional names per plant);
    requirements ``gm_req_db``, ``pm_req_deg``, ``p_stable_required``; ``computed``: the
    fields of :data:`FIELDS` that were computed (the others are NaN and not reported — see
    "What is computed" in the module docstring; default: all). ``draws``: which family of
    plants was checked and how it was drawn (plain values; e.g. the loop GP of
    :func:`hapid.robust.loop_gp_check`), or ``None``.
    """

    stable: np.ndarray
    n_closed_loop_rhp: np.ndarray
    gm_db: np.ndarray
    pm_deg: np.ndarray
    disk_margin: np.ndarray
    disk_gm_db: np.ndarray
    disk_pm_deg: np.ndarray
    iso_bandwidth_hz: np.ndarray
    t_peak_db: np.ndarray
    gm_req_db: float = GM_DB
    pm_req_deg: float = PM_DEG
    p_stable_required: float = 0.95
    labels: tuple | None = None
    computed: tuple = FIELDS
    gm_freq_hz: np.ndarray | None = None
    pm_freq_hz: np.ndarray | None = None
    cover: EvidenceCover | None = None
    loop: str = ""
    uncovered: tuple = ()
    nyquist_resolved: np.ndarray | None = None
    draws: dict | None = None

    @property
    def check(self) -> Check:
        """The three-valued verdict (:class:`hapid.verdict.Check`): ``failed`` when the
        requirements fail on the plants (:meth:`reasons`); with :attr:`cover` (draws
        conditioned on a measured band) ``not established`` when the evidence does not cover
        the frequencies that decide it (:func:`hapid.uncertainty._cover.cover_check`); else
        ``passed``; ``uncovered`` ``(reason, remedy)``: what the plants do not cover (e.g.
        parameter draws of a model class that may be wrong) — then a check the plants pass
        is ``not established``. Its ``name`` states the requirements and :attr:`loop`."""
        name = f"GM ≥ {self.gm_req_db:g} dB, PM ≥ {self.pm_req_deg:g}°" + (
            f" ({self.loop})" if self.loop else "")  # fmt: skip
        if self.cover is not None:
            return cover_check(self, self.cover, name)
        failed = self.failed_check(name)
        if failed is not None:
            return failed
        if self.uncovered:
            return Check(Verdict.NOT_ESTABLISHED, reason=self.uncovered[0],
                         remedy=self.uncovered[1], name=name)  # fmt: skip
        return Check(Verdict.PASSED, name=name)

    def failed_check(self, name: str = "") -> Check | None:
        """The check when the requirements fail on the plants, else None: ``failed`` with
        :meth:`reasons`, or ``not established`` when the failure rests on plants whose
        Nyquist count the frequency grid did not resolve (:attr:`nyquist_resolved` False:
        they count as unstable, but would pass were every one of them stable with ample
        margins). Resolving them needs a denser grid (``hapid robust --n-freq``)."""
        why = self.reasons()
        if not why:
            return None
        unres = (np.zeros(self.n, bool) if self.nyquist_resolved is None
                 else ~np.asarray(self.nyquist_resolved, bool))  # fmt: skip
        if unres.any():
            best = {f: np.where(unres, np.inf, getattr(self, f)) for f in ("gm_db", "pm_deg")}
            hopeful = dataclasses.replace(
                self, stable=np.asarray(self.stable, bool) | unres, nyquist_resolved=None,
                cover=None, uncovered=(), **best,
            )  # fmt: skip
            if not hopeful.reasons():
                k = int(unres.sum())
                return Check(
                    Verdict.NOT_ESTABLISHED, name=name,
                    reason=f"{k} of {self.n} plants have a Nyquist count the frequency grid "
                    f"does not resolve; counted unstable they fail the check ({why[0]}), "
                    "counted stable they would not",
                    remedy="a denser frequency grid (hapid robust --n-freq, e.g. twice the "
                    "points) to resolve their loci",
                )  # fmt: skip
        return Check(Verdict.FAILED, reason="; ".join(why), name=name)

    @property
    def not_computed(self) -> tuple:
        """Fields of :data:`FIELDS` that were not computed (NaN arrays, ``None`` in
        :meth:`summary` and :meth:`rows`)."""
        return tuple(f for f in FIELDS if f not in self.computed)

    def _require(self, name: str):
        if name not in self.computed:
            ask = next(k for k, v in METRICS.items() if name in v)
            raise ValueError(f"RobustReport: {name} was not computed "
                             f"(robust_check(..., metrics=({ask!r},)))")  # fmt: skip

    @property
    def n(self) -> int:
        return int(self.stable.shape[0])

    @property
    def p_stable(self) -> float:
        return float(np.mean(self.stable))

    def penalized(self, name: str) -> np.ndarray:
        """Field ``name`` with unstable plants set to the worst value; GM and PM as
        magnitudes ``|GM|``, ``|PM|`` (module docstring, "Margin sign convention").
        Raises ``ValueError`` for a field that was not computed."""
        self._require(name)
        v = np.asarray(getattr(self, name), dtype=float)
        if name in ("gm_db", "pm_deg"):
            v = np.abs(v)
        return np.where(self.stable, v, _WORST[name])

    def quantile(self, name: str, q: float) -> float:
        v = self.penalized(name)
        # inverted-CDF quantiles: no interpolation between ±inf (which would give NaN)
        if name == "t_peak_db":  # larger is worse: the q-quantile of badness
            return float(np.quantile(v, 1.0 - q, method="inverted_cdf"))
        return float(np.quantile(v, q, method="inverted_cdf"))

    @property
    def worst(self) -> int:
        """Index of the worst plant: unstable first, then smallest disk margin, then |GM|;
        without the disk margin (not computed): unstable first, then smallest |GM|, then |PM|."""
        if "disk_margin" in self.computed:
            keys = (self.penalized("gm_db"), self.penalized("disk_margin"), self.stable)
        else:
            keys = (self.penalized("pm_deg"), self.penalized("gm_db"), self.stable)
        return int(np.lexsort(keys)[0])

    @property
    def passed(self) -> bool:
        """:attr:`check` passed (a failed or not-established check is not passed)."""
        return self.check.ok

    def reasons(self) -> list[str]:
        """Why the check did not pass — one line per failed requirement, with how far the
        5 % quantile (or ``P(stable)``) is from the requirement and what fraction of plants
        miss it; empty when it passed."""
        out = []
        if self.p_stable < self.p_stable_required:
            n_bad = int(np.sum(~np.asarray(self.stable, bool)))
            out.append(f"P(stable) {self.p_stable:.3f} < required {self.p_stable_required:.3f} "
                       f"({n_bad} of {self.n} plants unstable)")  # fmt: skip
        for name, req, unit, label in (("gm_db", self.gm_req_db, "dB", "|GM|"),
                                       ("pm_deg", self.pm_req_deg, "°", "|PM|")):  # fmt: skip
            q = self.quantile(name, 0.05)
            if not q >= req:
                frac = float(np.mean(self.penalized(name) < req))
                short = (
                    "unstable plants" if not np.isfinite(q) else f"short by {req - q:.3g} {unit}"
                )
                out.append(f"{label} 5 % quantile {q:.4g} {unit} < required {req:g} {unit} ({short}; "
                           f"{100 * frac:.1f} % of plants below {req:g} {unit})")  # fmt: skip
        return out

    @property
    def ok(self) -> bool:
        """The check passed (:attr:`check`): the requirements are met on the plants *and*
        the evidence covers them."""
        return self.check.ok

    @property
    def status(self) -> Verdict:
        """The verdict of :attr:`check`: passed / failed / not established."""
        return self.check.verdict

    def numbers(self) -> dict:
        """Plain-python summary: P(stable), 5 %/50 % quantiles, worst plant, pass/fail, the
        check (``verdict``, ``reason``, ``remedy``), ``status`` (its value) and ``ok``, then
        :attr:`draws` when set; fields not computed are ``None`` and listed under
        ``not_computed``. Non-finite quantiles (an unstable plant's ``-inf`` margin) stay
        ``±inf`` (for arithmetic; :meth:`summary` is the JSON form)."""
        w = self.worst
        out = {"n": self.n, "p_stable": self.p_stable}
        for f in FIELDS:
            ok = f in self.computed
            out[f"{f}_q05"] = self.quantile(f, 0.05) if ok else None
            out[f"{f}_q50"] = self.quantile(f, 0.50) if ok else None
        out["worst_index"] = w
        out["worst_label"] = None if self.labels is None else self.labels[w]
        out["worst"] = {f: self._value(f, w) for f in FIELDS} | {"stable": bool(self.stable[w])}
        out["not_computed"] = list(self.not_computed)
        out["requirements"] = {"gm_db": self.gm_req_db, "pm_deg": self.pm_req_deg,
                               "p_stable": self.p_stable_required}  # fmt: skip
        out["passed"] = self.passed
        out["reasons"] = self.reasons()
        ck = self.check
        out |= {"verdict": ck.verdict.value, "reason": ck.reason, "remedy": ck.remedy,
                "check": ck.name, "loop": self.loop}  # fmt: skip
        out["evidence"] = None if self.cover is None else self.cover.summary()
        out |= {"status": self.status.value, "ok": self.ok}
        return out if self.draws is None else out | {"draws": self.draws}

    def summary(self) -> dict:
        """Strict-JSON dict: :meth:`numbers` with non-finite values as ``None``."""
        return jsonable(self.numbers())

    def rows(self) -> list[dict]:
        """One dict per plant (label, stable, margins, bandwidth; ``None``: not computed)."""
        rows = []
        for i in range(self.n):
            r = {
                "label": None if self.labels is None else self.labels[i],
                "stable": bool(self.stable[i]),
            }
            r |= {f: self._value(f, i) for f in FIELDS}
            rows.append(r)
        return rows

    def _value(self, name: str, i: int):
        return float(getattr(self, name)[i]) if name in self.computed else None
