# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Stage ``controller + plant → loop metrics``.

:class:`Plant` is a plant response on a grid plus what the Nyquist count needs to know
about it: its own open-loop right-half-plane poles (``p_rhp``) and whether it is sampled
(``ts`` seconds; the contour then ends at the Nyquist frequency π/ts) or continuous
(``ts=None``).

:func:`loop` closes ``L = P G`` and returns the loop metrics. Their ``stable`` is the one
verdict rule of every analysis (:func:`hapid.control.nyquist_verdict`, re-exported as
:func:`verdict`): the loop is stable iff the Nyquist count was resolved (per
determinant *and* per characteristic locus), ``I + L`` is nonsingular on the grid, and the
number of clockwise encirclements equals ``−(p_rhp of the plant + p_rhp of the controller)``
— the controller's own RHP poles included (positizing can leave roots of det Ẑ_H in the
right half plane, which are poles of ``G = g Ẑ_T Ẑ_H⁻¹``).

The numerics go through ONE adapter, :func:`_backend`: :func:`hapid.control.loop_metrics`
(refined crossings, so every command gives one answer per quantity whatever its grid).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float, Int

from .. import _config  # noqa: F401  (float64)
from .._aot import cached_jit
from .._constants import TWO_PI
from ..control import MetricsSpec, loop_metrics
from ..control import nyquist_verdict as verdict  # noqa: F401  (re-exported: the one stability rule)

#: What each caller asks for (one spec per use; the verdict is always computed).
#: A single loop is analysed once per process, so its program's compile (or cache load)
#: is most of the cost: single loops use LAPACK's ``eigvals``/``svd``/LU, whose program
#: compiles ≈ 4× faster than the unrolled XLA kernels and loads faster from the cache
#: (benchmarks/README.md, "Single loops on LAPACK"). Batches of loops (sweeps, robust
#: checks) keep the XLA kernels, which run faster per loop.
SPEC_SWEEP = MetricsSpec(disk=True)  # the sweep table has the disk margin column
SPEC_REPORT = MetricsSpec(disk=True, literal=True, kernels="lapack")  # analyze, paper summary
SPEC_FIGURES = MetricsSpec(disk=True, literal=True, arrays=True, full_sv=True, kernels="lapack")
SPEC_VALIDATE = MetricsSpec(disk=True, kernels="lapack")  # tune's re-check on the true plant
SPEC_VERDICT = MetricsSpec(bandwidth=False, margins=False, t_peak=False, kernels="lapack")
"""The Nyquist verdict alone (the evidence certificate's nominal loop): the smallest program."""


class SystemResponse(eqx.Module):
    """``omega (M,) → H (M, p, m)`` of a state space (continuous ``H(jω)`` or sampled
    ``H(e^{jω t_s})``) times ``e^{−jω t_s d}`` (``delay`` samples): an exact plant or
    controller response at any frequency, for refining crossings off the grid. The
    realization is built once, outside the traced refinement."""

    sys: object
    rows: int = eqx.field(static=True, default=0)  # keep outputs rows: (0: all)
    delay: int = eqx.field(static=True, default=0)

    def __call__(self, omega):
        omega = jnp.asarray(omega, dtype=jnp.float64)
        H = self.sys.response(omega)[:, self.rows :, :]
        if self.delay:
            H = H * jnp.exp(-1j * omega * self.sys.ts * self.delay)[:, None, None]
        return H


class DeviceResponse(eqx.Module):
    """``omega (M,) → P (M, n, n)`` of a simulated device, continuous (``device.P(jω)``)."""

    device: object

    def __call__(self, omega):
        return self.device.P(1j * jnp.asarray(omega, dtype=jnp.float64))


def _sampled_device_response(device, sys=None) -> SystemResponse:
    """``device.sampled_P`` as a :class:`SystemResponse` (ZOH realization built once, or
    ``sys`` when given; the position outputs are the rows after the first ``n``; the actuator
    delay in samples)."""
    sys = device.discrete() if sys is None else sys
    return SystemResponse(sys, int(device.n), int(device.delay_samples))


@cached_jit
def _sampled_device(device, omega):
    """``(device.sampled_P(omega), device.discrete())`` as one compiled program (op by op,
    the small matrix algebra of the realization compiles a program per operation)."""
    return device.sampled_P(omega), device.discrete()


@cached_jit
def _controller_parts(controller, omega):
    """``(G on omega, open-loop RHP poles of G, sampled realization or None)`` of a
    :class:`hapid.pipeline.Controller` as one compiled program."""
    sys = controller.discrete() if controller.ts is not None else None
    return controller.response(omega), jnp.asarray(controller.p_rhp), sys


class ModelResponse(eqx.Module):
    """``omega (M,) → P̂(jω) (M, n, n)`` of an impedance model."""

    model: object

    def __call__(self, omega):
        return self.model.P(1j * jnp.asarray(omega, dtype=jnp.float64))


class _ControllerResponse(eqx.Module):
    controller: object

    def __call__(self, omega):
        return self.controller.response(omega)


class LoopResponse(eqx.Module):
    """``omega (M,) → L = P G (M, n, n)`` from a plant response and a controller (a pytree,
    so ``eqx.filter_jit`` does not recompile for each new loop of the same structure)."""

    plant_fn: object
    controller_fn: object

    def __call__(self, omega):
        return jnp.einsum("wij,wjk->wik", self.plant_fn(omega), self.controller_fn(omega))


class Plant(eqx.Module):
    """A plant response on a grid: ``omega (N,)`` rad/s increasing, ``P (N, n, n)`` complex,
    ``p_rhp ()`` its open-loop unstable poles (open RHP; outside the unit circle when
    sampled), ``ts`` the sampling period in s (``None``: continuous)."""

    omega: Float[Array, " N"]
    P: Complex[Array, "N n n"]
    p_rhp: Int[Array, ""]
    ts: float | None = eqx.field(static=True, default=None)
    P_fn: object = None

    @property
    def n(self) -> int:
        return int(np.shape(self.P)[-1])


def device_plant(device, omega, *, continuous: bool = False) -> Plant:
    """The simulated device's true plant on ``omega`` (rad/s): the sampled plant
    ``P(e^{jω t_s})`` (ZOH, delay), or with ``continuous=True`` the continuous ``P(jω)``
    (with the actuator delay). Passive mechanics: ``p_rhp = 0``."""
    omega = jnp.asarray(omega, dtype=jnp.float64)
    if continuous:
        return Plant(omega, device.P(1j * omega), jnp.asarray(0), None, DeviceResponse(device))
    P, sys = _sampled_device(device, omega)
    return Plant(omega, P, jnp.asarray(0), float(device.ts), _sampled_device_response(device, sys))


def model_plant(model, omega) -> Plant:
    """A model's continuous plant ``P̂ = Ẑ_H Ẑ_T⁻¹`` on ``omega`` (rad/s); its unstable poles are
    the roots of det Ẑ_T with ``Re > 0`` (non-finite roots — singular M̂_T — count too)."""
    omega = jnp.asarray(omega, dtype=jnp.float64)
    r = model.total.roots()
    p = jnp.sum(jnp.real(r) > 0) + jnp.sum(~jnp.isfinite(r))
    return Plant(omega, model.P(1j * omega), p, None, ModelResponse(model))


def frf_plant(frf, ts: float | None = None) -> Plant:
    """A measured plant ``P = Z_H Z_T⁻¹`` on the FRF's grid (assumed open-loop stable: it was
    measured open loop). ``ts``: the sampling period of the controller it will meet."""
    return Plant(jnp.asarray(frf.omega), jnp.asarray(frf.P), jnp.asarray(0), ts)


def _backend(P, G, omega, p_ol, spec: MetricsSpec, L_fn=None):
    """The ONE call into the loop-analysis numerics: :func:`hapid.control.loop_metrics`
    (refined crossings; ``L_fn`` exact ``L`` off the grid when the plant is known)."""
    return loop_metrics(P, G, omega, p_ol=p_ol, spec=spec, L_fn=L_fn)


def check_nyquist(controller, plant: Plant) -> None:
    """Raise a clear error when a sampled loop's grid goes beyond fs/2 (outside ``jit``)."""
    ts = controller.ts if controller.ts is not None else plant.ts
    try:
        w_max = float(np.max(np.asarray(plant.omega)))
    except Exception:  # noqa: BLE001  (traced grid: checked by the caller)
        return
    if ts is not None and w_max > np.pi / ts * (1 + 1e-9):
        raise ValueError(
            f"the frequency grid reaches {w_max / TWO_PI:g} Hz, beyond the sampled loop's Nyquist "
            f"frequency fs/2 = {0.5 / ts:g} Hz (fs = {1 / ts:g} Hz): a sampled controller's "
            "response is periodic there; use a grid ending at fs/2, a higher fs, or --continuous"
        )
    if (controller.ts is None) != (plant.ts is None):
        raise ValueError(
            "a sampled controller must close the loop with a sampled plant, a continuous one "
            "with a continuous plant"
        )


def loop(controller, plant: Plant, spec: MetricsSpec = SPEC_REPORT):
    """Loop metrics of ``controller`` (a :class:`hapid.pipeline.Controller`) on ``plant``.

    Returns :class:`hapid.control.LoopMetrics` (what ``spec`` asks for, crossings refined —
    on the exact ``L`` when ``plant.P_fn`` is known) whose ``stable``
    is :func:`hapid.control.nyquist_verdict` with ``p_ol = plant.p_rhp + controller.p_rhp``. Jittable and
    vmappable (the fs/2 check runs only on concrete grids).
    """
    if controller.n != plant.n:
        raise ValueError(f"controller has n = {controller.n} rods but the plant has {plant.n}")
    check_nyquist(controller, plant)
    G, p_c, sys = _controller_parts(controller, plant.omega)
    p_ol = jnp.asarray(plant.p_rhp) + p_c
    L_fn = None
    if plant.P_fn is not None:
        c_fn = SystemResponse(sys) if sys is not None else None
        L_fn = LoopResponse(plant.P_fn, c_fn or _ControllerResponse(controller))
    return _backend(plant.P, G, plant.omega, p_ol, spec, L_fn)
