# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Robust-margin check of a fixed controller over a batch of plants.

The controller is designed once from the *nominal* model, ``G(jω) = g(jω) Ẑ_T Ẑ_H⁻¹``, and
held fixed. Every plant of a batch is then analysed with
:func:`hapid.control.loop_metrics` (``vmap``-ed, in chunks): generalized-Nyquist stability
verdict first, then gain/phase margins of the characteristic loci and the isotropic
bandwidth; the balanced disk margin and the peak of σ̄(T) only when asked (``metrics``).

Two kinds of batches, and what each covers:

- **posterior samples** (:class:`PosteriorSamples` or a batched :class:`ImpedanceModel`):
  each ``P̂_s = Ẑ_H,s Ẑ_T,s⁻¹`` is a continuous *second-order* model without delay. This
  covers **parameter uncertainty within the model class only** — not the actuator delay,
  the sampling, or the unmodeled mechanism/hand dynamics that the class cannot represent.
- **device variants** (:func:`device_plants`): the simulated device's true sampled plant
  ``device.sampled_P(ω)`` (ZOH, one-sample delay, extra modes) at other stylus poses and for
  other virtual subjects. This covers delay and unmodeled dynamics, for the simulated
  device's variation only.

Open-loop RHP poles (needed by the Nyquist count): the controller's are the CRHP roots of
det Ẑ_H of the nominal model (:func:`hapid.control.controller_unstable_poles`); a model
plant's are the roots of det Ẑ_T,s with ``Re > 0`` (none for PD matrices); a device's are 0
(passive mechanics).

What is computed. By default only what the verdict (:attr:`RobustReport.passed`) and the
summary need: the Nyquist verdict, the isotropic bandwidth (σ̄(T − I) crossing) and the loci
gain/phase margins. The balanced disk margin (``disk_margin``, ``disk_gm_db``,
``disk_pm_deg``) and the peak of σ̄(T) (``t_peak_db``) cost as much again (one cu5 draw,
1000 frequencies: ≈ 9 ms of ≈ 16 ms) and are computed only when asked:
``robust_check(..., metrics=("disk", "t_peak"))``. A field not computed is NaN in the
per-plant arrays, listed in :attr:`RobustReport.not_computed`, ``None`` in
:meth:`~RobustReport.summary` / :meth:`~RobustReport.rows`, and asking for its quantile
raises; :attr:`RobustReport.worst` then ranks on the computed fields.

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

Compute path. ``backend="metrics"`` (the default): every plant is analysed by
:func:`hapid.control.loop_metrics`'s program (XLA small-matrix kernels for det/inverse/σ̄ and
the eigenvalues of the loci, no LAPACK inside; exact values only where the cheap bounds do
not decide; refined crossings) in its two passes (:mod:`hapid.control._metrics`): the
grid pass (every frequency) once per plant — the plain jitted program, no ``vmap`` — and the
refinement pass (a few small sequential root-finding steps per plant) once per chunk of
``chunk`` plants, ``vmap``-ed, so its step count is paid once per chunk instead of once per
plant (``vectorize=False``, the default); or the whole analysis ``vmap``-ed over chunks
(``vectorize=True``; the last chunk padded, ``p_ol`` an array: one compile). Measured on the
2-core machine, the grid pass per plant is the faster: under ``vmap`` the batch axis sits in
front of the kernels' entry-major ``(n, n, N)`` layout and the grid kernels cost 2–3× more
per plant (det/inverse 7.3 vs 2.6 ms per plant at 8 plants × 1000 frequencies). Same
verdicts as the reference on 1000 cu5 posterior draws
(benchmarks/bench_fast.py, tests/test_control_metrics.py). ``backend="reference"``:
:func:`hapid.control.analyze_loop` (the LAPACK reference, grid values) once per plant.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _config, _distributed  # noqa: F401  (float64)
from .._grids import continuous_grid as posterior_omega
from .._grids import sampled_grid as robust_omega
from ..control import Compensator, MetricsSpec, analyze_loop
from ..control._metrics import grid_pass, metrics_screened, refine_many
from ..defaults import GM_DB, PM_DEG
from ..fit._pd import theta_to_model
from ..impedance import ImpedanceModel
from ..verdict import Check, Verdict
from ._cover import EvidenceCover, cover_check
from ._samples import PosteriorSamples

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
    :class:`hapid.control.LoopReport`); ``labels`` (optional names per plant);
    requirements ``gm_req_db``, ``pm_req_deg``, ``p_stable_required``; ``computed``: the
    fields of :data:`FIELDS` that were computed (the others are NaN and not reported — see
    "What is computed" in the module docstring; default: all).
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
    gm_req_db: float = 6.0
    pm_req_deg: float = 30.0
    p_stable_required: float = 0.95
    labels: tuple | None = None
    computed: tuple = FIELDS
    gm_freq_hz: np.ndarray | None = None
    pm_freq_hz: np.ndarray | None = None
    cover: EvidenceCover | None = None
    loop: str = ""
    uncovered: tuple = ()

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
        why = self.reasons()
        if why:
            return Check(Verdict.FAILED, reason="; ".join(why), name=name)
        if self.uncovered:
            return Check(Verdict.NOT_ESTABLISHED, reason=self.uncovered[0],
                         remedy=self.uncovered[1], name=name)  # fmt: skip
        return Check(Verdict.PASSED, name=name)

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

    def summary(self) -> dict:
        """Plain-python summary: P(stable), 5 %/50 % quantiles, worst plant, pass/fail;
        fields not computed are ``None`` and listed under ``not_computed``."""
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
        return out

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


_KEYS = ("stable", "n_closed_loop_rhp") + FIELDS + ("gm_freq_hz", "pm_freq_hz")


def _spec(metrics: tuple) -> MetricsSpec:
    """The :class:`~hapid.control.MetricsSpec` of a robust check: verdict, bandwidth and
    margins always; the peak of σ̄(T) and the disk margin when ``metrics`` asks for them."""
    return MetricsSpec(bandwidth=True, margins=True, t_peak="t_peak" in metrics,
                       disk="disk" in metrics)  # fmt: skip


def _fields(m: dict, spec: MetricsSpec) -> dict:
    keys = ("stable", "n_closed_loop_rhp", "gm_db", "pm_deg", "iso_bandwidth_hz", "gm_freq_hz",
            "pm_freq_hz")  # fmt: skip
    out = {k: m[k] for k in keys}
    nan = jnp.full_like(m["gm_db"], jnp.nan)
    out["t_peak_db"] = m["t_peak_db"] if spec.t_peak else nan
    if spec.disk:  # loop_metrics fills the disk margin's GM/PM (0 when not stable)
        out |= {k: m[k] for k in ("disk_margin", "disk_gm_db", "disk_pm_deg")}
    else:
        out["disk_margin"] = out["disk_gm_db"] = out["disk_pm_deg"] = nan
    return out


@eqx.filter_jit
def _reference_one(P, p_ol, G, omega):
    r = analyze_loop(P, G, omega, p_ol)
    return {k: getattr(r, k) for k in _KEYS}


def _reference_chunk(P, p_ol, G, omega):
    """The LAPACK reference, one plant per call of a jitted ``analyze_loop`` (grid values)."""
    outs = [_reference_one(P[i], p_ol[i], G, omega) for i in range(P.shape[0])]
    return {k: np.stack([np.asarray(o[k]) for o in outs]) for k in _KEYS}


@eqx.filter_jit
def _metrics_chunk(P, p_ol, G, omega, spec):
    def one(P_, p_):
        return _fields(metrics_screened(P_, G, omega, p_, None, spec), spec)

    return jax.vmap(one)(P, p_ol)


def grid_pass_one(P, i, p_ol, G, omega, spec):
    """The grid pass of plant ``i`` of a chunk (the chunk stays on the device: no slice is
    dispatched from Python)."""
    return grid_pass(P[i], G, omega, p_ol[i], spec)


_grid_one = partial(jax.jit, static_argnames="spec")(grid_pass_one)


@partial(jax.jit, static_argnames="spec")
def _refine_chunk(grids, spec):
    """The refinement pass of every plant of a chunk at once (vmapped: its sequential steps
    are shared by the chunk instead of paid per plant)."""
    out, tasks = jax.tree.map(lambda *x: jnp.stack(x), *grids)
    return _fields(refine_many(out, tasks, None, spec), spec)


def _analyze_chunk(P, p_ol, G, omega, vectorize, spec):
    """Per-plant fields of a (padded) chunk: :func:`~hapid.control.loop_metrics`'s program
    vmapped over the chunk (``vectorize=True``), or its grid pass once per plant and its
    refinement pass vmapped over the chunk (default)."""
    if vectorize:
        return {k: np.asarray(v) for k, v in _metrics_chunk(P, p_ol, G, omega, spec).items()}
    # the grid pass per plant, not vmapped: a vmapped program keeps the batch axis in front
    # of the kernels' entry-major layout (measured ~2-3x slower per plant); the refinement
    # is a few small sequential steps, whose cost is their count, so it is shared
    grids = [_grid_one(P, np.int32(i), p_ol, G, omega, spec) for i in range(P.shape[0])]
    return {k: np.asarray(v) for k, v in _refine_chunk(grids, spec).items()}


def _pad(x, size):
    """Pad the leading axis to ``size`` with copies of the last row (no recompile for the
    last chunk)."""
    m = x.shape[0]
    if m == size:
        return x
    return jnp.concatenate([x, jnp.broadcast_to(x[-1:], (size - m,) + x.shape[1:])])


@eqx.filter_jit
def _model_plants(theta, scale, omega):
    def one(t):
        m = theta_to_model(t, scale)
        return _plant_and_poles(m, omega)

    return jax.vmap(one)(theta)


@eqx.filter_jit
def _models_plants(models, omega):
    return jax.vmap(lambda m: _plant_and_poles(m, omega))(models)


def _plant_and_poles(m: ImpedanceModel, omega):
    P = m.P(1j * omega)
    r = m.total.roots()
    n_rhp = jnp.sum(jnp.real(r) > 0) + jnp.sum(~jnp.isfinite(r))
    return P, n_rhp


def controller_response(controller, omega):
    """``(G (N, n, n), open-loop RHP poles of G)`` from ``(nominal model, g)`` or an array."""
    omega = jnp.asarray(omega, dtype=jnp.float64)
    if isinstance(controller, tuple) and len(controller) == 2:
        model, g = controller
        if not isinstance(model, ImpedanceModel) or not isinstance(g, Compensator):
            raise ValueError(
                "controller must be (nominal ImpedanceModel, Compensator) or G (N, n, n)"
            )
        from ..pipeline import controller as make_controller

        ctrl = make_controller(model, g)  # continuous inverse-model controller (hapid.pipeline)
        return ctrl.response(omega), int(ctrl.p_rhp)
    G = jnp.asarray(controller, dtype=jnp.complex128)
    if G.ndim != 3 or G.shape[0] != omega.shape[0] or G.shape[1] != G.shape[2]:
        raise ValueError(f"G must be ({omega.shape[0]}, n, n), got shape {G.shape}")
    return G, 0


def robust_check(
    plants,
    controller,
    omega=None,
    *,
    p_ol_rhp=None,
    controller_rhp: int | None = None,
    gm_db: float = GM_DB,
    pm_deg: float = PM_DEG,
    p_stable_required: float = 0.95,
    chunk: int = 250,
    max_samples: int | None = 1000,
    seed: int = 0,
    labels=None,
    vectorize: bool = False,
    backend: str = "metrics",
    metrics: tuple = (),
) -> RobustReport:
    """Analyse the loop of a fixed controller with every plant of a batch.

    - ``plants``: :class:`PosteriorSamples` (at most ``max_samples`` random draws, ``seed``),
      a batched :class:`ImpedanceModel` (leading axis S), or plant responses ``(S, N, n, n)``
      on ``omega`` (then ``p_ol_rhp`` — int or ``(S,)`` — gives their open-loop RHP poles,
      default 0).
    - ``controller``: ``(nominal_model, g)`` (G = g Ẑ_T Ẑ_H⁻¹, its RHP poles counted from
      the nominal model) or a response ``G (N, n, n)`` (pass ``controller_rhp`` if G has
      RHP poles).
    - ``omega``: grid in rad/s (default: :func:`posterior_omega`, 0.005 Hz – 5 kHz, for
      model plants; :func:`robust_omega`, 0.05–450 Hz, for sampled plant arrays).
    - ``gm_db``, ``pm_deg``, ``p_stable_required``: requirements for ``passed``.
    - ``chunk``: plants per vmapped batch (memory: chunk × N × n² complex per array).
    - ``backend``: ``"metrics"`` (default): :func:`~hapid.control.loop_metrics` (XLA
      kernels, refined crossings); ``"reference"``: :func:`~hapid.control.analyze_loop` once
      per plant (LAPACK, grid values). See "Compute path".
    - ``vectorize`` (``backend="metrics"``): ``False`` (default) runs the grid pass once per
      plant and the refinement vmapped over each chunk; ``True`` vmaps the whole analysis
      over each chunk (slower on CPU for large chunks).
    - ``metrics``: what to compute beyond the verdict, the isotropic bandwidth and the loci
      GM/PM (which ``passed`` uses): any of ``"disk"`` (balanced disk margin, its GM/PM) and
      ``"t_peak"`` (peak of σ̄(T)), or ``"all"``. Fields not asked for are NaN and listed in
      :attr:`RobustReport.not_computed` (module docstring, "What is computed").

    Returns a :class:`RobustReport`.
    """
    if backend not in ("metrics", "reference"):
        raise ValueError(f"robust_check: backend must be 'metrics' or 'reference', got {backend!r}")
    metrics = (
        tuple(METRICS)
        if metrics == "all"
        else ((metrics,) if isinstance(metrics, str) else tuple(metrics))
    )
    bad = [m for m in metrics if m not in METRICS]
    if bad:
        raise ValueError(
            f"robust_check: metrics must be among {tuple(METRICS)} or 'all', got {bad}"
        )
    spec = _spec(metrics)
    computed = tuple(
        f for f in FIELDS if not any(f in METRICS[k] for k in METRICS if k not in metrics)
    )
    if omega is None:
        omega = (
            posterior_omega()
            if isinstance(plants, PosteriorSamples | ImpedanceModel)
            else robust_omega()
        )
    omega = np.asarray(omega, dtype=float)
    if omega.ndim != 1 or np.any(np.diff(omega) <= 0) or np.any(omega <= 0):
        raise ValueError("omega must be a strictly increasing (N,) array of positive rad/s")
    om = jnp.asarray(omega)
    G, c_rhp = controller_response(controller, om)
    if controller_rhp is not None:
        c_rhp = int(controller_rhp)
    if isinstance(plants, PosteriorSamples):
        theta = plants.theta
        if max_samples is not None and theta.shape[0] > max_samples:
            idx = np.random.default_rng(seed).choice(theta.shape[0], max_samples, replace=False)
            theta = theta[np.sort(idx)]
        S = theta.shape[0]

        def get(i, j):
            th = _pad(jnp.asarray(theta[i:j]), min(chunk, S))
            return tuple(a[: j - i] for a in _model_plants(th, plants.scale, om))

    elif isinstance(plants, ImpedanceModel):
        if np.ndim(plants.hand.M) != 3:
            raise ValueError("robust_check: a batched ImpedanceModel (S, n, n) is required")
        S = int(np.shape(plants.hand.M)[0])
        get = lambda i, j: _models_plants(jax.tree.map(lambda a: a[i:j], plants), om)  # noqa: E731
    else:
        P = jnp.asarray(plants, dtype=jnp.complex128)
        if P.ndim != 4 or P.shape[1:] != G.shape:
            raise ValueError(f"plants must be (S, {G.shape[0]}, n, n) matching G, got {P.shape}")
        S = P.shape[0]
        pol = jnp.broadcast_to(jnp.asarray(0 if p_ol_rhp is None else p_ol_rhp), (S,))
        get = lambda i, j: (P[i:j], pol[i:j])  # noqa: E731
    if S == 0:
        raise ValueError("robust_check: no plants")
    if G.shape[-1] != (
        plants.n if isinstance(plants, PosteriorSamples | ImpedanceModel) else G.shape[-1]
    ):
        raise ValueError(
            f"controller is {G.shape[-1]}×{G.shape[-1]} but the plants have n = {plants.n}"
        )
    parts = []
    chunk = max(1, min(int(chunk), S))
    for i in _distributed.local_chunks(S, chunk):  # all chunks, or this process's block
        j = min(S, i + chunk)
        Pc, pc = get(i, j)  # (not `pol`: the array path's `get` reads that name)
        pc = jnp.asarray(pc, dtype=jnp.float64) + c_rhp
        if backend == "metrics":
            r = _analyze_chunk(_pad(Pc, chunk), _pad(pc, chunk), G, om, vectorize, spec)
        else:  # analyze_loop computes every field: keep the asked ones, as the default backend
            r = _reference_chunk(Pc, pc, G, om)
            r |= {f: np.full_like(r[f], np.nan, dtype=float) for f in FIELDS if f not in computed}
        parts.append({k: v[: j - i] for k, v in r.items()})
    res = _distributed.gather(parts)  # every process's chunks, in order (one process: concat)
    if labels is not None and len(labels) != S:
        raise ValueError(f"{len(labels)} labels for {S} plants")
    return RobustReport(
        **res,
        gm_req_db=float(gm_db),
        pm_req_deg=float(pm_deg),
        p_stable_required=float(p_stable_required),
        labels=None if labels is None else tuple(labels),
        computed=computed,
    )


@eqx.filter_jit
def _sampled_P(device, omega):
    return device.sampled_P(omega)


def device_plants(
    device, omega=None, *, poses=(), n_subjects: int = 0, key=0, include_nominal: bool = True
):
    """True sampled plants of a simulated device's variants: ``(labels, P (S, N, n, n))``.

    - ``device``: a :class:`hapid.device.ParallelDevice` (e.g. ``cu5()``).
    - ``poses``: :class:`hapid.device.Pose` objects (other stylus poses, nominal subject).
    - ``n_subjects``: virtual subjects (:func:`hapid.device.virtual_subject`) at the device's
      pose, drawn from ``key`` (JAX key or int).
    - ``include_nominal``: the device itself first.

    Pass the result to :func:`robust_check` (``p_ol_rhp`` 0: passive mechanics).
    """
    from ..device import virtual_subject

    omega = jnp.asarray(robust_omega() if omega is None else omega, dtype=jnp.float64)
    labels, Ps = [], []
    if include_nominal:
        labels.append("nominal")
        Ps.append(_sampled_P(device, omega))
    for k, pose in enumerate(poses):
        d = eqx.tree_at(lambda x: x.pose, device, pose)
        c = np.asarray(pose.center) - np.asarray(device.pose.center)
        labels.append(f"pose {k}: d = ({c[0]:+.3f}, {c[1]:+.3f}, {c[2]:+.3f}) m")
        Ps.append(_sampled_P(d, omega))
    if n_subjects:
        key = jax.random.PRNGKey(key) if isinstance(key, int) else key
        for k, sk in enumerate(jax.random.split(key, n_subjects)):
            d = eqx.tree_at(lambda x: x.hand, device, virtual_subject(sk, device.hand))
            labels.append(f"subject {k}")
            Ps.append(_sampled_P(d, omega))
    if not Ps:
        raise ValueError("device_plants: nothing selected (no nominal, poses or subjects)")
    return labels, jnp.stack(Ps)
