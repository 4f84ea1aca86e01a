"""Log-coordinate parameterization of a :class:`~hapid.control.Compensator` for tuning.

Every tuned quantity of g(s) is positive (the gain ``k``, lag zeros/poles, notch
frequencies and damping ratios, low-pass poles), so the optimizer works on their natural
logarithms: an unconstrained vector ``x``, ``g = ParamMap.compensator(x)``. The structure
(how many lag pairs, notches and low-pass poles) is fixed by a template compensator.
Frequencies stay in rad/s inside; :meth:`ParamMap.describe` gives Hz for reports.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from ..control import Compensator
from ..control._compensator import FIELDS

_FIELDS = FIELDS
_LABEL = {"k": "k", "lag_zeros": "lag zero", "lag_poles": "lag pole", "notch_omega": "notch",
          "notch_zeta_num": "notch ζ_num", "notch_zeta_den": "notch ζ_den", "lowpass": "low-pass"}  # fmt: skip
_IS_FREQ = {"lag_zeros", "lag_poles", "notch_omega", "lowpass"}


@dataclasses.dataclass(frozen=True)
class ParamMap:
    """Maps ``x`` (log of every parameter, in the order of :attr:`names`) to a Compensator.

    ``sizes``: number of entries per field (``k`` has 1). Build with :meth:`from_template`.
    """

    sizes: tuple[int, ...]

    @classmethod
    def from_template(cls, g: Compensator) -> ParamMap:
        return cls(tuple(int(np.size(getattr(g, f))) for f in _FIELDS))

    @property
    def dim(self) -> int:
        return int(sum(self.sizes))

    @property
    def names(self) -> list[str]:
        out = []
        for f, m in zip(_FIELDS, self.sizes, strict=True):
            out += [_LABEL[f]] if f == "k" else [f"{_LABEL[f]} {i + 1}" for i in range(m)]
        return out

    @property
    def is_frequency(self) -> np.ndarray:
        """``(dim,)`` bool: the entry is a frequency (rad/s)."""
        return np.concatenate(
            [np.full(m, f in _IS_FREQ) for f, m in zip(_FIELDS, self.sizes, strict=True)]
        )

    def vector(self, g: Compensator) -> jnp.ndarray:
        """``x = log`` of g's parameters (``(dim,)``). All must be > 0."""
        parts = [jnp.atleast_1d(jnp.asarray(getattr(g, f), dtype=jnp.float64)) for f in _FIELDS]
        v = jnp.concatenate(parts)
        if v.shape != (self.dim,):
            raise ValueError(
                f"ParamMap: compensator has {v.shape[0]} parameters, map expects {self.dim}"
            )
        if not bool(jnp.all(v > 0)):
            raise ValueError("ParamMap: every tuned parameter of g must be > 0 (log coordinates)")
        return jnp.log(v)

    def compensator(self, x) -> Compensator:
        """The compensator with parameters ``exp(x)`` (differentiable in ``x``)."""
        v = jnp.exp(jnp.asarray(x, dtype=jnp.float64))
        out, i = {}, 0
        for f, m in zip(_FIELDS, self.sizes, strict=True):
            out[f] = v[i] if f == "k" else v[i : i + m]
            i += m
        return Compensator(**out)

    def describe(self, x) -> dict[str, float]:
        """``{name: value}`` with frequencies in Hz (reporting)."""
        v = np.exp(np.asarray(x, dtype=float))
        v = np.where(self.is_frequency, v / TWO_PI, v)
        return {n: float(a) for n, a in zip(self.names, v, strict=True)}


IDENTITY_NOTCH_ZETA = 0.5
"""Damping ratio (numerator = denominator) of a notch added by :func:`extend_structure`."""


def extend_structure(g: Compensator, *, lag_hz=(), notch_hz=(),
                     notch_zeta: float = IDENTITY_NOTCH_ZETA) -> Compensator:  # fmt: skip
    """``g`` with more tunable terms that leave its response unchanged: a lag/lead pair with
    zero = pole at each frequency of ``lag_hz`` (Hz), and a notch with ``ζ_num = ζ_den =
    notch_zeta`` at each frequency of ``notch_hz`` (Hz). The result is a template for
    :func:`hapid.tune.tune` / :func:`hapid.tune.robust_design` (``g0``): the tuner starts at
    ``g``'s response (same |g(0)|, same loop) with more freedom — a pair can become a lead or
    a lag, a notch a dip or a bump — so the tuned design is no worse than ``g``'s structure
    allows from the same start. Frequencies must be > 0."""
    lag = np.asarray(lag_hz, dtype=float).reshape(-1)
    notch = np.asarray(notch_hz, dtype=float).reshape(-1)
    if (
        np.any(~np.isfinite(lag))
        or np.any(lag <= 0)
        or np.any(~np.isfinite(notch))
        or np.any(notch <= 0)
    ):
        raise ValueError("extend_structure: added lag/notch frequencies must be finite and > 0 Hz")
    if not notch_zeta > 0:
        raise ValueError(f"extend_structure: notch_zeta must be > 0, got {notch_zeta}")
    cat = lambda a, b: np.concatenate([np.asarray(a, dtype=float).reshape(-1), b])  # noqa: E731
    w = TWO_PI * notch
    return Compensator(
        k=float(g.k),
        lag_zeros=cat(g.lag_zeros, TWO_PI * lag),
        lag_poles=cat(g.lag_poles, TWO_PI * lag),
        notch_omega=cat(g.notch_omega, w),
        notch_zeta_num=cat(g.notch_zeta_num, np.full(w.size, notch_zeta)),
        notch_zeta_den=cat(g.notch_zeta_den, np.full(w.size, notch_zeta)),
        lowpass=np.asarray(g.lowpass, dtype=float),
    )
