"""Stage ``frf → model``: any estimator by name with its options.

``fit(frf, "nls", f_max_hz=30.0, rtol=1e-9)`` → :class:`Fit`. Estimators live in
:data:`ESTIMATORS` (``wls``, ``wls+positize``, ``nls``, ``ml``); another module adds one with a
single line, as ``ml`` is added here::

    ESTIMATORS["name"] = lambda frf, **o: Fit.from_nls(my_fit(frf, **o), "name")

``ml`` (sample maximum likelihood) works on the periodic run, not on an FRF.

Options use the scene's units (Hz): ``omega_c_hz`` (paper weight corner) and ``f_max_hz``
(fit band) for every estimator; the NLS ones are those of :func:`hapid.fit.fit_nls`
(``weight``, ``max_steps``, ``ftol``, ``patience``, ``blend_floor``, ``p_weight``,
``pd_eps``, ``init_floor``, ``use_P_residual``, ``boundary_rtol``) and the solver as the
scenes write it: ``solver`` a name of :data:`hapid.fit.SOLVERS` with ``rtol``, ``atol`` and
``linear_solver`` (mapped to the object by :func:`hapid.fit.solver_from`; defaults
:mod:`hapid.defaults`), or a solver object alone. Numeric options may be traced scalars (one
compile serves a sweep over them); ``max_steps`` is static (a python int).
Every estimator is jittable and vmappable.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Int

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from .._grids import NYQUIST_F_MIN_HZ
from .._plain import jsonable
from ..control import controller_is_stable
from ..fit import crhp_report, fit_ml, fit_nls, positize, solver_from, wls
from ..fit._problem import PD_EPS
from ..fit._result import FitStatus


class Fit(eqx.Module):
    """Result of the ``frf → model`` stage.

    ``model`` (:class:`hapid.impedance.ImpedanceModel`); ``ok`` (bool: converged / closed
    form); ``crhp_hand``, ``crhp_total`` (closed-RHP roots of det Ẑ_H, det Ẑ_T of ``model``;
    roots of det Ẑ_H are poles of the inverse-model controller); ``crhp_hand_raw``,
    ``crhp_total_raw`` (before positizing, WLS only; else equal); ``result`` (the full
    :class:`hapid.fit.NLSResult` for iterative fits, else ``None``); ``estimator`` (name).
    """

    model: object
    ok: Bool[Array, ""]
    crhp_hand: Int[Array, ""]
    crhp_total: Int[Array, ""]
    crhp_hand_raw: Int[Array, ""]
    crhp_total_raw: Int[Array, ""]
    result: object = None
    estimator: str = eqx.field(static=True, default="")

    @property
    def status(self) -> FitStatus:
        """:class:`~hapid.fit.FitStatus`: ``CLOSED_FORM``, or the iterative fit's status
        (outside ``jit``)."""
        return FitStatus.CLOSED_FORM if self.result is None else self.result.status

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, ``estimator``, the closed-RHP root counts
        (``crhp_hand``, ``crhp_total`` and before positizing ``crhp_hand_raw``,
        ``crhp_total_raw``) and the iterative fit's own summary (``result``, or ``None``)."""
        out = {"status": self.status, "ok": self.ok, "estimator": self.estimator}
        out |= {k: getattr(self, k) for k in ("crhp_hand", "crhp_total", "crhp_hand_raw",
                                              "crhp_total_raw")}  # fmt: skip
        out["result"] = None if self.result is None else self.result.summary()
        return jsonable(out)

    @classmethod
    def closed_form(cls, model, raw=None, estimator: str = "") -> Fit:
        after = crhp_report(model)
        before = after if raw is None else crhp_report(raw)
        return cls(model, jnp.asarray(True), after.hand, after.total, before.hand, before.total,
                   None, estimator)  # fmt: skip

    @classmethod
    def from_nls(cls, res, estimator: str = "nls") -> Fit:
        r = crhp_report(res.model)
        return cls(res.model, res.ok, r.hand, r.total, r.hand, r.total, res, estimator)


ESTIMATORS: dict[str, Callable[..., Fit]] = {}


def register(name: str):
    """Decorator: ``@register("name")`` on ``fn(frf, **options) -> Fit``."""

    def deco(fn):
        ESTIMATORS[name] = fn
        return fn

    return deco


def _omega_c(o):
    return TWO_PI * jnp.asarray(o.pop("omega_c_hz", 7.0), dtype=jnp.float64)


@register("wls")
def _wls(frf, **o) -> Fit:
    omega_c = _omega_c(o)
    f_max = o.pop("f_max_hz", None)
    _no_more(o, "wls")
    return Fit.closed_form(wls(frf, omega_c=omega_c, f_max_hz=f_max), estimator="wls")


@register("wls+positize")
def _wls_positize(frf, **o) -> Fit:
    omega_c = _omega_c(o)
    f_max = o.pop("f_max_hz", None)
    mode = o.pop("mode", "modulus")
    _no_more(o, "wls+positize")
    raw = wls(frf, omega_c=omega_c, f_max_hz=f_max)
    return Fit.closed_form(positize(raw, mode=mode), raw, estimator="wls+positize")


def _solver_option(o: dict) -> dict:
    """``o`` with the scene's solver options (``solver`` a name, ``rtol``, ``atol``,
    ``linear_solver``) replaced by the solver object (:func:`hapid.fit.solver_from`); a solver
    object passes as it is. Raises ``ValueError`` for an unknown name, or for tolerances given
    with an object (it carries its own)."""
    o = dict(o)
    tol = {k: o.pop(k) for k in ("rtol", "atol", "linear_solver") if k in o}
    solver = o.pop("solver", None)
    if solver is None or isinstance(solver, str):
        o["solver"] = solver_from(*(() if solver is None else (solver,)), **tol)
    elif tol:
        raise ValueError(f"options {sorted(tol)} go with a solver name; a solver object "
                         "carries its own")  # fmt: skip
    else:
        o["solver"] = solver
    if "max_steps" in o:
        o["max_steps"] = int(o["max_steps"])
    return o


@register("nls")
def _nls(frf, **o) -> Fit:
    o = _solver_option(o)
    omega_c = _omega_c(o)
    return Fit.from_nls(fit_nls(frf, omega_c=omega_c, **o))


@register("ml")
def _ml(run, **o) -> Fit:
    """Sample maximum likelihood (:func:`hapid.fit.fit_ml`): needs the periodic *run* (the
    experiment stage's output), not an FRF; ``omega_c_hz`` is ignored."""
    o = _solver_option(o)
    o.pop("omega_c_hz", None)
    return Fit.from_nls(fit_ml(run, **o), estimator="ml")


def _no_more(o, name):
    if o:
        raise ValueError(f"estimator {name!r} has no option(s) {sorted(o)}")


def fit(frf, estimator: str = "nls", **options) -> Fit:
    """Fit ``frf`` with the named estimator (module docstring; ``"ml"`` takes the periodic
    run instead of the FRF). ``ValueError`` names the known estimators for an unknown one."""
    try:
        fn = ESTIMATORS[estimator]
    except KeyError:
        raise ValueError(
            f"unknown estimator {estimator!r}; known: {', '.join(sorted(ESTIMATORS))}"
        ) from None
    return fn(frf, **dict(options))


def _ready(model) -> Bool[Array, ""]:
    """:func:`controller_ready` as a jittable bool array."""
    return controller_is_stable(model, tol=TWO_PI * NYQUIST_F_MIN_HZ)


def controller_ready(model) -> bool:
    """Is the inverse-model controller ``g Ẑ_T Ẑ_H⁻¹`` of ``model`` proper and strictly
    stable: every root of det Ẑ_H finite, with Re < −2π·10⁻³ rad/s (slower than the analysis
    grid's lowest frequency, :data:`hapid._grids.NYQUIST_F_MIN_HZ`)? A root closer to the
    imaginary axis acts as an integrator the loop analysis cannot resolve; a root at ∞ (a
    singular M̂_H) makes the controller improper. At the edge (python bool)."""
    return bool(_ready(model))


def _select(c, a, b):
    """``a`` where the bool ``c`` holds, else ``b``, leaf by leaf (same tree structure)."""
    return jax.tree.map(lambda x, y: jnp.where(c, x, y) if eqx.is_array(x) else x, a, b)


class ControlFit(eqx.Module):
    """Result of :func:`control_fit`: the NLS fit for control use and whether it was refitted.

    ``fit`` (:class:`Fit`); ``refitted`` (bool array, ``(B,)`` when vmapped): the boundary
    fit was refitted with ``pd_eps = PD_EPS``. ``model``, ``status`` and ``ok`` are the fit's;
    :attr:`refit_pd_eps` is the edge form of ``refitted``.
    """

    fit: Fit
    refitted: Bool[Array, ...]

    @property
    def model(self):
        return self.fit.model

    @property
    def ok(self):
        return self.fit.ok

    @property
    def status(self) -> FitStatus:
        """The fit's :class:`~hapid.fit.FitStatus` (outside ``jit``)."""
        return self.fit.status

    @property
    def refit_pd_eps(self) -> float | None:
        """``PD_EPS`` when the boundary fit was refitted, else ``None`` (at the edge: a
        concrete, unbatched result)."""
        return float(PD_EPS) if bool(self.refitted) else None

    def summary(self) -> dict:
        """Strict-JSON dict: the fit's :meth:`Fit.summary` and ``refitted``."""
        return self.fit.summary() | {"refitted": jsonable(self.refitted)}


def control_fit(frf, *, boundary_refit: bool = True, **options) -> ControlFit:
    """THE NLS fit for control use (:class:`ControlFit`: the fit and whether it was
    refitted), shared by ``hapid fit``, ``hapid posterior``, scenes and sweeps. The fit is
    :func:`fit` with ``"nls"`` and ``options``; with ``pd_eps = 0`` (the default) a fit that
    lands on the PSD boundary with a root of det Ẑ_H at ∞ or on the imaginary axis
    (:func:`controller_ready` false: hexapod6, whose hand acts on 3 of its 6 rod directions)
    is refitted from the same start with ``pd_eps = PD_EPS`` (every matrix strictly PD; ≤ 0.3
    dB of P·P̂⁻¹ band) and ``refitted`` (a bool array) is true. The loops the paper's
    controller would close through the boundary fit cannot be certified by any analysis.
    ``boundary_refit=False`` (static) keeps the boundary fit.

    Jittable and vmappable. At the edge (concrete data) the refit runs only when needed;
    traced (a sweep's ``vmap``) both fits run and the result is selected per element (where
    no refit is needed the second fit repeats the first, discarded: a warm start from the
    bare optimum was measured 8× slower, its L Lᵀ boundary crawl running to the patience
    stop)."""
    f = fit(frf, "nls", **options)
    if not boundary_refit:
        return ControlFit(f, jnp.asarray(False))
    pd_eps = options.get("pd_eps", 0.0)
    need = (jnp.asarray(pd_eps) == 0.0) & ~_ready(f.model)
    if not isinstance(need, jax.core.Tracer):
        if bool(need):
            return ControlFit(fit(frf, "nls", **(dict(options) | {"pd_eps": PD_EPS})),
                              jnp.asarray(True))  # fmt: skip
        return ControlFit(f, jnp.asarray(False))
    o = dict(options) | {"pd_eps": jnp.where(need, PD_EPS, pd_eps)}
    return ControlFit(_select(need, fit(frf, "nls", **o), f), need)
