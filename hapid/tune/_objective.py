# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""The smooth design problem: maximize a robust isotropic bandwidth under margin constraints.

Decision variables ``z = (x, u)``: ``x`` the log-parameters of g (:class:`.ParamMap`) and
``u = log ω_b`` (rad/s), the bandwidth being claimed. Per scenario ``s`` (loop ``L = g Q_s``,
:class:`.Scenarios`) three smooth constraint values, each ``≤ 0`` when met:

* **bandwidth** — the isotropic bandwidth is a *first crossing* of σ̄(T − I) = σ̄(S) through
  1 − 1/√2, which is not smooth in g. The surrogate claims ω_b and asks that σ̄(S) stay under
  the threshold below it::

      c_bw = (1/β) log Σ_k exp(β [log s_p(S(jω_k)) − log 0.293 + log w_k(u)]),
      w_k(u) = sigmoid((u − log ω_k)/τ + 5)

  (a soft maximum over the grid, windowed to ω ≲ ω_b; ``s_p`` the smooth upper bound of σ̄,
  :func:`.smooth_sigma_max`). The window enters the exponent scaled by β, so above ω_b it
  decays like ``(ω/ω_b)^{−β/τ}`` — faster than any violation can grow (σ̄(S) → 1 at high
  frequency must not leak in) — and the shift 5 puts full weight up to ω_b itself.
  Maximizing ``u`` subject to ``c_bw ≤ 0`` pushes the first crossing up. The soft maximum
  (≥ max), ``s_p`` (≥ σ̄) and the window (full weight at ω_b) all err on the safe side: the
  claimed ω_b is at or below the first crossing.
* **margins** — per characteristic locus ``ℓ_i = g λ_i(Q)`` (exactly the loci
  :func:`hapid.control.loop_metrics` follows), a sensitivity bound ``|1 + ℓ_i(jω)| ≥ 1/M_s``
  at every ω keeps each locus outside the disc of radius ``1/M_s`` around −1, which implies
  ``GM ≥ M_s/(M_s − 1)`` and ``PM ≥ 2 arcsin(1/(2M_s))``. :attr:`Requirements.ms` is the
  largest ``M_s`` giving both required margins (6 dB, 30° → ``M_s = 1.932``: GM ≥ 6.3 dB).
  Smooth form: ``c_ms = (1/β) log Σ_{k,i} exp(−β log|1 + ℓ_i(jω_k)|) − log M_s``. (A crossing
  of the negative real axis *outside* the disc at ``|ℓ| > 1`` — a lower gain margin — is
  not excluded by the disc; validation reports the non-smooth margins.)
* **disk margin** (optional, ``disk_alpha``) — ``σ̄(S − T) ≤ 2/α`` (the MIMO balanced disk
  margin of :func:`hapid.control.disk_margin_from_peak`), same soft maximum over ω.

**Robust aggregation.** Over a family of scenarios a constraint must hold for a fraction
``q`` of them. The aggregate is the conditional value at risk ``CVaR_q`` — the mean of the
``K = ⌈(1 − q) S⌉`` largest values (``jax.lax.top_k``, differentiable almost everywhere):
``CVaR_q ≤ 0`` implies that at most ``K − 1`` scenarios violate, i.e. the ``q``-quantile is met
on the training set. ``q = 1`` (or ``S < 1/(1 − q)``) is the scenario approach: all of them.

The penalized objective (continuation in μ, see :func:`.tune`) is
``f = −u + μ Σ_j max(0, CVaR_j)² + max(μ, 10⁴)·box(x, u) + ρ ‖x − x₀‖²``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from ..control import ISO_THRESHOLD
from ..control._kernels import to_entries
from ..defaults import GM_DB, PM_DEG
from ._evidence import small_gain_constraint
from ._params import ParamMap
from ._response import g_response, smooth_sigma_max_entries
from ._scenarios import Scenarios


@dataclasses.dataclass(frozen=True)
class Requirements:
    """Targets: ``gm_db``, ``pm_deg`` (loci margins), ``threshold`` on σ̄(T − I), optional
    ``disk_alpha`` (MIMO disk margin α), optional ``min_dc_gain`` (lower bound on
    ``|g(0)| = k Π z_j/p_j``: the static force error of the loop is ≈ 1/(1 + |g(0)|) along
    each direction, which the isotropic bandwidth alone does not constrain), soft-max
    sharpness ``beta`` (log units) and bandwidth window width ``tau`` (natural-log
    frequency). ``sg_omega`` (rad/s, a tuple) with ``sg_g_max``: the beyond-evidence
    small-gain condition ``|g(jω)| ≤ sg_g_max`` on those frequencies
    (:mod:`hapid.tune._evidence`)."""

    gm_db: float = GM_DB
    pm_deg: float = PM_DEG
    threshold: float = float(ISO_THRESHOLD)
    disk_alpha: float | None = None
    min_dc_gain: float | None = None
    beta: float = 60.0
    tau: float = 0.02
    sg_omega: tuple | None = None
    sg_g_max: float | None = None
    sg_ts: float | None = None

    @property
    def ms(self) -> float:
        """Largest locus sensitivity peak implying both ``gm_db`` and ``pm_deg``."""
        gm = 10.0 ** (self.gm_db / 20.0)
        ms_gm = gm / (gm - 1.0) if gm > 1.0 else np.inf
        ms_pm = 1.0 / (2.0 * np.sin(np.radians(self.pm_deg) / 2.0)) if self.pm_deg > 0 else np.inf
        return float(min(ms_gm, ms_pm))


@dataclasses.dataclass(frozen=True)
class Family:
    """Scenarios with their required fraction ``quantile`` and which constraints apply.

    ``bw_quantile`` (default ``quantile``): the fraction of scenarios that must reach the
    claimed bandwidth (e.g. 0.5: the median scenario's bandwidth is maximized while the
    margins hold for ``quantile`` of them). ``dense`` (optional): the same scenarios on a
    denser grid; :func:`.tune` checks the margin constraint there after each stage and adds
    the violated frequencies to the training grid (:mod:`._exchange`), and counts the
    Nyquist encirclements there. ``contour`` (default True): the grid is a Nyquist contour
    (low enough and high enough for the count); False for a measured FRF's points, whose
    scenarios are then judged on the margin disc only."""

    scenarios: Scenarios
    quantile: float = 0.95
    bandwidth: bool = True
    margins: bool = True
    name: str = "scenarios"
    bw_quantile: float | None = None
    dense: Scenarios | None = None
    contour: bool = True

    def __post_init__(self):
        for q in (self.quantile, self.bw_quantile):
            if q is not None and not 0.0 < q <= 1.0:
                raise ValueError(f"Family: quantiles must be in (0, 1], got {q}")

    def k_worst(self, q: float | None = None) -> int:
        """``K = ⌈(1 − q) S⌉`` (at least 1) for quantile ``q`` (default :attr:`quantile`)."""
        q = self.quantile if q is None else q
        S = self.scenarios.n_scenarios
        return int(min(S, max(1, int(np.ceil((1.0 - q) * S - 1e-9)))))


def _lse(a, axis, beta, log_w=None):
    if log_w is not None:
        return jax.nn.logsumexp(beta * a + log_w, axis=axis) / beta
    return jax.nn.logsumexp(beta * a, axis=axis) / beta


def scenario_constraints(g, sc: Scenarios, u, req: Requirements) -> dict[str, jax.Array]:
    """Per-scenario smooth constraint values ``(S,)`` (≤ 0 when met): ``bw``, ``ms`` and, with
    ``disk_alpha``, ``disk``. ``g`` is a Compensator, ``u = log ω_b``."""
    gam = g_response(g, sc.omega, sc.ts)
    gl = gam[None, :, None] * sc.lam
    d = 1.0 + gl
    # S = V diag(1/d) V⁻¹, entry-major (n, n, S, N): see smooth_sigma_max_entries
    Ve, Vie = to_entries(sc.V), to_entries(sc.Vi)
    r = jnp.moveaxis(1.0 / d, -1, 0)
    hS = smooth_sigma_max_entries(jnp.sum(Ve[:, :, None] * r[None, :, None] * Vie[None], axis=1))
    lw = jnp.log(sc.omega)
    log_w = jax.nn.log_sigmoid((u - lw) / req.tau + 5.0)
    out = {"bw": _lse(hS - np.log(req.threshold) + log_w[None, :], -1, req.beta)}
    loc = -jnp.log(jnp.abs(d))
    out["ms"] = _lse(loc.reshape(loc.shape[0], -1), -1, req.beta) - np.log(req.ms)
    if req.disk_alpha is not None:
        rd = jnp.moveaxis((1.0 - gl) / d, -1, 0)
        SmT = jnp.sum(Ve[:, :, None] * rd[None, :, None] * Vie[None], axis=1)
        out["disk"] = _lse(smooth_sigma_max_entries(SmT), -1, req.beta) - np.log(
            2.0 / req.disk_alpha
        )
    return out


def cvar(c, k: int):
    """Mean of the ``k`` largest entries of ``c`` (``(S,)``)."""
    return jnp.mean(jax.lax.top_k(c, k)[0])


def masked_cvar(c, k: int, counted):
    """Chance-constraint CVaR with scenarios left out: ``counted`` (``(S,)`` bool) marks the
    scenarios the constraint is evaluated on; each one left out (an unstable closed loop,
    already a violator) uses one of the ``k`` allowed slots, so the mean is over the
    ``max(1, k − #left out)`` largest counted values (``k`` static, the count traced)."""
    n_out = jnp.sum(~counted)
    k_eff = jnp.maximum(1, k - n_out)
    top = jax.lax.top_k(jnp.where(counted, c, -1e6), k)[0]
    w = (jnp.arange(k) < k_eff).astype(top.dtype)
    return jnp.sum(top * w) / k_eff


def aggregate(g, families, u, req: Requirements, counted=None) -> dict[str, jax.Array]:
    """``{"<family>/<constraint>": CVaR}`` over every family (the constraints of the problem),
    plus ``"g/dc"`` with ``min_dc_gain`` and ``"evidence/small_gain"`` with ``sg_omega``.

    ``counted`` (optional, one ``(S,)`` bool array or ``None`` per family): scenarios whose
    closed loop is unstable at the current stage are left out of the margin CVaR and count as
    violators (:func:`masked_cvar`); ``"<family>/unstable"`` then reports
    ``#unstable − (K − 1)`` (> 0: more unstable scenarios than the quantile allows; no
    gradient — a loop becomes stable only by a locus crossing −1)."""
    out = {}
    counted = [None] * len(families) if counted is None else counted
    if req.min_dc_gain is not None:
        log_dc = jnp.log(g.k) + jnp.sum(jnp.log(g.lag_zeros)) - jnp.sum(jnp.log(g.lag_poles))
        out["g/dc"] = np.log(req.min_dc_gain) - log_dc
    if req.sg_omega is not None:
        out["evidence/small_gain"] = small_gain_constraint(g, np.asarray(req.sg_omega), req.sg_g_max,
                                                           req.beta, req.sg_ts)  # fmt: skip
    for fam, cnt in zip(families, counted, strict=True):
        c = scenario_constraints(g, fam.scenarios, u, req)
        if fam.bandwidth:
            out[f"{fam.name}/bw"] = cvar(c["bw"], fam.k_worst(fam.bw_quantile))
        if fam.margins:
            k = fam.k_worst()
            if cnt is None:
                out[f"{fam.name}/ms"] = cvar(c["ms"], k)
            else:
                out[f"{fam.name}/ms"] = masked_cvar(c["ms"], k, cnt)
                out[f"{fam.name}/unstable"] = (jnp.sum(~cnt) - (k - 1)).astype(float)
            if "disk" in c:
                out[f"{fam.name}/disk"] = cvar(c["disk"], k)
    return out


F_MIN_HZ = 0.05
"""Lowest frequency (Hz) of g's poles and zeros: 10× above the continuous analysis grid's
0.005 Hz, so that the loop has settled at the grid's low end and every Nyquist count (the
tuner's guard, the re-check, the nominal-loop certificate) sees the same low-frequency
phase. Used by :meth:`Box.default`. Why: docs/robust-design.md, Evidence E12."""


@dataclasses.dataclass(frozen=True)
class Box:
    """Soft box in log coordinates: ``lo ≤ x ≤ hi`` (penalized quadratically outside)."""

    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def default(cls, pm: ParamMap, f_max_hz: float, f_min_hz: float = F_MIN_HZ) -> Box:
        """Frequencies in [f_min, f_max] Hz, damping ratios in [0.02, 2], gain in [1e-3, 1e3]."""
        lo, hi = [], []
        for name, isf in zip(pm.names, pm.is_frequency, strict=True):
            if isf:
                lo.append(np.log(TWO_PI * f_min_hz))
                hi.append(np.log(TWO_PI * f_max_hz))
            elif name.startswith("notch ζ"):
                lo.append(np.log(0.02))
                hi.append(np.log(2.0))
            else:
                lo.append(np.log(1e-3))
                hi.append(np.log(1e3))
        return cls(np.asarray(lo), np.asarray(hi))

    def penalty(self, x):
        return jnp.sum(jax.nn.relu(x - self.hi) ** 2 + jax.nn.relu(self.lo - x) ** 2)


BOX_WEIGHT = 1e4
"""Minimum weight of the box penalty (kept large from the first stage: the box is not a
design trade-off but the domain where g is meaningful)."""


def penalized(z, mu, pm: ParamMap, families, req: Requirements, box: Box, x0, rho: float,
              counted=None):  # fmt: skip
    """The penalized objective of the module docstring at ``z = (x, u)``. ``u`` is boxed to
    the first family's grid (beyond it the bandwidth claim would be unbounded). ``counted``:
    see :func:`aggregate` (the ``/unstable`` entries are constants and not penalized)."""
    return penalized_parts(z, mu, pm, families, req, box, x0, rho, counted)[0]


def penalized_parts(z, mu, pm: ParamMap, families, req: Requirements, box: Box, x0, rho: float,
                    counted=None):  # fmt: skip
    """``(objective, constraints)``: :func:`penalized`'s value and the :func:`aggregate` dict
    it was built from (≤ 0 met), for progress reports."""
    x, u = z[:-1], z[-1]
    g = pm.compensator(x)
    cons = aggregate(g, families, u, req, counted)
    pen = sum(jax.nn.relu(v) ** 2 for k, v in cons.items() if not k.endswith("/unstable"))
    lw = jnp.log(families[0].scenarios.omega)
    u_box = jax.nn.relu(u - lw[-1]) ** 2 + jax.nn.relu(lw[0] - u) ** 2
    wbox = jnp.maximum(mu, BOX_WEIGHT)
    obj = -u + mu * pen + wbox * (box.penalty(x) + u_box) + rho * jnp.sum((x - x0) ** 2)
    return obj, cons
