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

import numpy as np

from ._constants import BELOW_NYQUIST, TWO_PI

SAMPLED_BAND_HZ = (0.05, 450.0)
SAMPLED_N = 1000
CONTINUOUS_BAND_HZ = (0.005, 5000.0)
CONTINUOUS_N = 1500
NYQUIST_F_MIN_HZ = 1e-3
NYQUIST_N = 1500


def log_grid_hz(f_min_hz: float, f_max_hz: float, n: int) -> np.ndarray:
    """``n`` log-spaced frequencies from ``f_min_hz`` to ``f_max_hz`` (both included), in rad/s."""
    f_min_hz, f_max_hz, n = float(f_min_hz), float(f_max_hz), int(n)
    if not (0.0 < f_min_hz < f_max_hz) or not np.isfinite(f_max_hz):
        raise ValueError(
            f"frequency grid: need 0 < f_min_hz < f_max_hz, got {f_min_hz:g}, {f_max_hz:g}"
        )
    if n < 2:
        raise ValueError(f"frequency grid: need at least 2 points, got {n}")
    return TWO_PI * np.geomspace(f_min_hz, f_max_hz, n)


def sampled_grid(
    n_freq: int = SAMPLED_N,
    f_min_hz: float = SAMPLED_BAND_HZ[0],
    f_max_hz: float = SAMPLED_BAND_HZ[1],
) -> np.ndarray:
    """Grid for sampled plants (rad/s): ``n_freq`` log-spaced points, 0.05–450 Hz by default."""
    return log_grid_hz(f_min_hz, f_max_hz, n_freq)


def continuous_grid(
    n_freq: int = CONTINUOUS_N,
    f_min_hz: float = CONTINUOUS_BAND_HZ[0],
    f_max_hz: float = CONTINUOUS_BAND_HZ[1],
) -> np.ndarray:
    """Grid for continuous model loops (rad/s): ``n_freq`` log-spaced points, 0.005 Hz–5 kHz."""
    return log_grid_hz(f_min_hz, f_max_hz, n_freq)


def nyquist_grid(
    fs_hz: float, n_freq: int = NYQUIST_N, f_min_hz: float = NYQUIST_F_MIN_HZ
) -> np.ndarray:
    """Grid for a loop sampled at ``fs_hz`` (rad/s): ``n_freq - 1`` log-spaced points from
    ``f_min_hz`` to just below ``fs_hz / 2``, plus ``fs_hz / 2`` itself (``n_freq`` in all)."""
    fs_hz = float(fs_hz)
    f_max = BELOW_NYQUIST * fs_hz
    return np.append(log_grid_hz(f_min_hz, f_max, int(n_freq) - 1), TWO_PI * 0.5 * fs_hz)


def below_nyquist_grid(
    fs_hz: float, n_freq: int, f_min_hz: float = 0.1, fraction: float = 0.499
) -> np.ndarray:
    """Grid for a loop sampled at ``fs_hz`` without the Nyquist point (rad/s): ``n_freq``
    log-spaced points from ``f_min_hz`` to ``fraction · fs_hz`` (the tuner's device family)."""
    return log_grid_hz(f_min_hz, fraction * float(fs_hz), n_freq)
