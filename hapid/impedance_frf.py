# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""A single measured impedance (dynamic stiffness ``Z = F/x``), the lab-data counterpart of
the haptic hand/total :class:`hapid.frf.FRF`.

``ImpedanceFRF``: ``omega`` ``(N,)`` rad/s strictly increasing and > 0, ``Z`` ``(N, n, n)``
complex, optional ``Z_std`` ``(N, n, n)`` (std of each complex element estimate,
``sqrt(E|Ẑ − Z|²)``), optional ``coherence`` ``(N, n)`` (the H1 estimate's multiple
coherence γ² of every response channel on the forces, in [0, 1]), ``exp_tau_s`` (> 0: the
records were multiplied by ``e^{−t/τ}``, so ``Z`` is the windowed system's ``Z(jω + 1/τ)``;
0: no exponential window), and ``unit`` — the unit of Z as text (``"N/m"`` for force in N over
displacement in m; whatever the lab's channels were, e.g. ``"V/m"``). A fitted
``M s² + B s + K`` then has M in ``unit·s²``, B in ``unit·s``, K in ``unit``
(:func:`model_units`).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from . import _config  # noqa: F401
from ._grids import band_mask
from .frf import TWO_PI, check_frf_arrays, require_x64


class ImpedanceFRF(eqx.Module):
    omega: Float[Array, " N"]
    Z: Complex[Array, "N n n"]
    Z_std: Float[Array, "N n n"] | None = None
    unit: str = eqx.field(static=True, default="N/m")
    coherence: Float[Array, "N n"] | None = None
    exp_tau_s: float = eqx.field(static=True, default=0.0)

    def __post_init__(self):
        require_x64("ImpedanceFRF")
        self.omega = jnp.asarray(self.omega, dtype=jnp.float64)
        self.Z = jnp.asarray(self.Z, dtype=jnp.complex128)
        if self.Z_std is not None:
            self.Z_std = jnp.asarray(self.Z_std, dtype=jnp.float64)
        if self.coherence is not None:
            self.coherence = jnp.asarray(self.coherence, dtype=jnp.float64)

    def __check_init__(self):
        try:
            check_frf_arrays(self.omega, self.Z, self.Z, self.Z_std, None)
        except ValueError as e:
            raise ValueError(str(e).replace("FRF: Z_H", "impedance FRF: Z")) from None
        if self.coherence is not None:
            g = np.asarray(self.coherence)
            N, n = np.shape(self.Z)[:2]
            if g.shape != (N, n):
                raise ValueError(
                    f"impedance FRF: coherence must be (N, n) = {(N, n)}, got {g.shape}"
                )
            if not np.all((g >= 0) & (g <= 1)):
                raise ValueError("impedance FRF: coherence must lie in [0, 1]")
        if not (np.isfinite(self.exp_tau_s) and self.exp_tau_s >= 0):
            raise ValueError(f"impedance FRF: exp_tau_s must be ≥ 0, got {self.exp_tau_s}")

    @property
    def n(self) -> int:
        return int(np.shape(self.Z)[-1])

    @property
    def freq_hz(self):
        return self.omega / TWO_PI

    def select(self, mask) -> ImpedanceFRF:
        """A new ImpedanceFRF at the frequencies where ``mask`` (``(N,)`` bool) is true."""
        mask = np.asarray(mask, dtype=bool)
        pick = lambda a: None if a is None else np.asarray(a)[mask]  # noqa: E731
        return ImpedanceFRF(
            omega=pick(self.omega), Z=pick(self.Z), Z_std=pick(self.Z_std), unit=self.unit,
            coherence=pick(self.coherence), exp_tau_s=self.exp_tau_s,
        )  # fmt: skip

    def band(self, f_min_hz: float = 0.0, f_max_hz: float = np.inf) -> ImpedanceFRF:
        """A new ImpedanceFRF restricted to ``f_min_hz ≤ f ≤ f_max_hz``."""
        f = np.asarray(self.freq_hz)
        return self.select(band_mask(f, f_min_hz, f_max_hz))


def as_impedance_frf(
    freq_hz, Z, Z_std=None, unit: str = "N/m", coherence=None, exp_tau_s: float = 0.0
) -> ImpedanceFRF:
    """Build an :class:`ImpedanceFRF` from Hz frequencies (the file contract's units)."""
    require_x64("as_impedance_frf")
    f = np.asarray(freq_hz, dtype=np.float64)
    return ImpedanceFRF(
        omega=TWO_PI * f,
        Z=jnp.asarray(Z),
        Z_std=None if Z_std is None else jnp.asarray(Z_std),
        unit=unit,
        coherence=None if coherence is None else np.asarray(coherence, dtype=np.float64),
        exp_tau_s=float(exp_tau_s),
    )


def model_units(z_unit: str) -> dict[str, str]:
    """Units of M, B, K for an impedance in ``z_unit`` (``"N/m"`` → kg, N·s/m, N/m)."""
    if z_unit == "N/m":
        return {"M": "kg", "B": "N·s/m", "K": "N/m"}
    return {"M": f"{z_unit}·s²", "B": f"{z_unit}·s", "K": z_unit}
