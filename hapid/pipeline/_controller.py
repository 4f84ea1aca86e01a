# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Stage ``model + g → controller``: the inverse-model MIMO controller or the SISO baseline,
continuous or sampled, as one value object.

* MIMO: ``G = g(s) Ẑ_T Ẑ_H⁻¹`` (paper section 5); sampled: matched pole-zero g, Tustin matrix
  part (:func:`hapid.control.discretize_controller`).
* SISO: ``G = c·g(s)·I_n``; sampled: matched pole-zero g.

``p_rhp`` is the controller's own open-loop unstable poles: the roots of det Ẑ_H with
``Re > 0`` (MIMO) plus the unstable poles of g (``n`` copies for SISO). Both
discretizations map the open RHP outside the unit circle, so the count is the same for the
sampled controller.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Complex, Float

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from ..control import (
    Compensator,
    controller_unstable_poles,
    discretize_controller,
    discretize_siso_controller,
    inverse_model_response,
    siso_response,
)

KINDS = ("mimo", "siso")


class Controller(eqx.Module):
    """A controller ready to close a loop (see the module docstring).

    Fields: ``g`` (:class:`hapid.control.Compensator`), ``model`` (the nominal
    :class:`hapid.impedance.ImpedanceModel`; ``None`` for SISO), ``c`` (SISO gain, ``()``),
    ``kind`` (``"mimo"``/``"siso"``), ``ts`` (s; ``None`` = continuous), ``n`` (rods).
    """

    g: object
    model: object
    c: Float[Array, ""]
    kind: str = eqx.field(static=True)
    ts: float | None = eqx.field(static=True)
    n: int = eqx.field(static=True)

    def discrete(self):
        """The sampled realization (:class:`hapid.control.DiscreteStateSpace`, input R_E,
        output R_A) — for closed-loop eigenvalues and time simulation."""
        if self.ts is None:
            raise ValueError("a continuous controller has no sampled realization (give ts)")
        if self.kind == "mimo":
            return discretize_controller(self.model, self.g, self.ts)
        return discretize_siso_controller(self.g, self.c, self.ts, self.n)

    def response(self, omega: Float[Array, " N"]) -> Complex[Array, "N n n"]:
        """``G`` on ``omega`` (rad/s): ``G(e^{jω t_s})`` when sampled, ``G(jω)`` otherwise."""
        omega = jnp.asarray(omega, dtype=jnp.float64)
        if self.ts is not None:
            return self.discrete().at_omega(omega)
        if self.kind == "mimo":
            return inverse_model_response(self.model, self.g, omega)
        return siso_response(self.g, omega, self.n, self.c)

    @property
    def p_rhp(self):
        """Open-loop unstable poles of G (0-d int array; jittable)."""
        if self.kind == "mimo":
            return controller_unstable_poles(self.model, self.g)
        return self.n * self.g.state_space().n_unstable_poles()


def controller(
    model, g, *, ts: float | None = None, kind: str = "mimo", c=1.0, n: int | None = None
) -> Controller:
    """Build the controller value (module docstring). ``ts`` in s (``None``: continuous);
    ``kind="siso"`` needs ``n`` (or a ``model`` to take it from)."""
    if kind not in KINDS:
        raise ValueError(f"controller kind must be one of {KINDS}, got {kind!r}")
    if kind == "mimo" and model is None:
        raise ValueError("the MIMO inverse-model controller needs a model")
    if n is None:
        if model is None:
            raise ValueError("a SISO controller without a model needs n")
        n = model.n
    if ts is not None:
        ts = float(ts)
        if not ts > 0:
            raise ValueError(f"sampling period ts must be > 0 s, got {ts!r}")
    return Controller(g=g, model=model if kind == "mimo" else None, c=jnp.asarray(c, dtype=jnp.float64),
                      kind=kind, ts=ts, n=int(n))  # fmt: skip


def compensator(o: dict):
    """g(s) from scene-style options (Hz for frequencies): ``k``, ``lag_zero_hz``,
    ``lag_pole_hz``, ``notch_hz`` (list), ``zeta_num``, ``zeta_den``, ``lowpass_hz`` (list).
    Values may be traced scalars (sweeps)."""

    def hz(x):
        return TWO_PI * jnp.asarray(x, dtype=jnp.float64)

    return Compensator(
        k=o["k"], lag_zeros=[hz(o["lag_zero_hz"])], lag_poles=[hz(o["lag_pole_hz"])],
        notch_omega=jnp.stack([hz(f) for f in o["notch_hz"]]) if len(o["notch_hz"]) else (),
        notch_zeta_num=o["zeta_num"], notch_zeta_den=o["zeta_den"],
        lowpass=jnp.stack([hz(f) for f in o["lowpass_hz"]]) if len(o["lowpass_hz"]) else (),
    )  # fmt: skip
