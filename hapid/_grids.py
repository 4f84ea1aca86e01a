"""Frequency grids (rad/s) — the one place where analysis grids are built.

Every builder returns a float64 numpy array ``(N,)`` of angular frequencies in rad/s,
strictly increasing; arguments are in Hz. The named grids encode hapid's defaults:

- :func:`sampled_grid` — for *sampled* plants (device variants, measured-like arrays) below the
  1 kHz device's Nyquist frequency: 0.05–450 Hz, 1000 points.
- :func:`continuous_grid` — for *continuous* model plants (posterior samples, tuned g):
  0.005 Hz–5 kHz, 1500 points. The generalized Nyquist count of a continuous loop is only
  resolved once the loop has rolled off at the grid's top; on cu5 with the paper's g the
  0.05–450 Hz grid counted 70 % of emcee draws as "not stable" (unresolved count) where this
  grid finds 85 % stable.
- :func:`nyquist_grid` — for a *discrete* loop sampled at ``fs_hz``: log-spaced to just below
  the Nyquist frequency, plus the Nyquist frequency itself (where the discrete contour ends).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from . import _config  # noqa: F401  (float64)
from ._constants import BELOW_NYQUIST, TWO_PI

SAMPLED_BAND_HZ = (0.05, 450.0)
SAMPLED_N = 1000
CONTINUOUS_BAND_HZ = (0.005, 5000.0)
CONTINUOUS_N = 1500
NYQUIST_F_MIN_HZ = 1e-3
NYQUIST_N = 1500


def band_mask(f: np.ndarray, lo: float, hi: float, rtol: float = 1e-9) -> np.ndarray:
    """``lo ≤ f ≤ hi`` with a relative tolerance on both edges (a bin stored as
    920.0000000000001 Hz is inside a band edge given as 920)."""
    f = np.asarray(f, dtype=np.float64)
    return (f >= lo - rtol * abs(lo)) & (f <= hi + rtol * abs(hi))


def _traced(*xs) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in xs)


def log_grid_hz(f_min_hz: float, f_max_hz: float, n: int) -> np.ndarray:
    """``n`` log-spaced frequencies from ``f_min_hz`` to ``f_max_hz`` (both included), in rad/s.

    Concrete bounds give a numpy array (checked: ``0 < f_min_hz < f_max_hz``); traced bounds
    (inside ``jit``/``vmap``, e.g. a swept ``f_min_hz``) give the same grid as a JAX array."""
    n = int(n)
    if n < 2:
        raise ValueError(f"frequency grid: need at least 2 points, got {n}")
    if _traced(f_min_hz, f_max_hz):
        return TWO_PI * 10.0 ** jnp.linspace(jnp.log10(f_min_hz), jnp.log10(f_max_hz), n)
    f_min_hz, f_max_hz = float(f_min_hz), float(f_max_hz)
    if not (0.0 < f_min_hz < f_max_hz) or not np.isfinite(f_max_hz):
        raise ValueError(
            f"frequency grid: need 0 < f_min_hz < f_max_hz, got {f_min_hz:g}, {f_max_hz:g}"
        )
    return TWO_PI * np.geomspace(f_min_hz, f_max_hz, n)


def _named_grid(n_default: int, band_hz: tuple[float, float], doc: str):
    def grid(n_freq: int = n_default, f_min_hz: float = band_hz[0], f_max_hz: float = band_hz[1]):
        return log_grid_hz(f_min_hz, f_max_hz, n_freq)

    grid.__doc__ = doc
    return grid


sampled_grid = _named_grid(
    SAMPLED_N,
    SAMPLED_BAND_HZ,
    "Grid for sampled plants (rad/s): ``n_freq`` log-spaced points, 0.05–450 Hz by default.",
)
continuous_grid = _named_grid(
    CONTINUOUS_N,
    CONTINUOUS_BAND_HZ,
    "Grid for continuous model loops (rad/s): ``n_freq`` log-spaced points, 0.005 Hz–5 kHz.",
)
sampled_grid.__name__, continuous_grid.__name__ = "sampled_grid", "continuous_grid"


def nyquist_grid(
    fs_hz: float, n_freq: int = NYQUIST_N, f_min_hz: float = NYQUIST_F_MIN_HZ
) -> np.ndarray:
    """Grid for a loop sampled at ``fs_hz`` (rad/s): ``n_freq - 1`` log-spaced points from
    ``f_min_hz`` to just below ``fs_hz / 2``, plus ``fs_hz / 2`` itself (``n_freq`` in all)."""
    fs_hz = float(fs_hz)
    grid = log_grid_hz(f_min_hz, BELOW_NYQUIST * fs_hz, int(n_freq) - 1)
    return (jnp if _traced(grid) else np).append(grid, TWO_PI * 0.5 * fs_hz)


def below_nyquist_grid(
    fs_hz: float, n_freq: int, f_min_hz: float = 0.1, fraction: float = 0.499
) -> np.ndarray:
    """Grid for a loop sampled at ``fs_hz`` without the Nyquist point (rad/s): ``n_freq``
    log-spaced points from ``f_min_hz`` to ``fraction · fs_hz`` (the tuner's device family)."""
    return log_grid_hz(f_min_hz, fraction * float(fs_hz), n_freq)
