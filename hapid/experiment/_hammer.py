"""Synthetic impact-hammer records of a structure with known modes (for examples and tests).

The structure at one point is a sum of uncoupled modes ``k`` (natural frequency ``f_k`` Hz,
damping ratio ``ζ_k``, modal mass ``m_k`` kg): receptance
``x/F = Σ_k 1/(m_k (ω_k² − ω² + 2jζ_k ω_k ω))``, dynamic stiffness ``Z = F/x`` its inverse
(:func:`modal_impedance`). :func:`hammer_records` strikes it with short half-sine force pulses
and returns the force and the acceleration, computed in the frequency domain over a
record zero-padded past the slowest mode's decay (the response from rest of the structure
sampled at ``fs_hz``: its DFT-bin transfer function is the closed form),
with white noise added on both channels.
"""

from __future__ import annotations

import numpy as np

from ._impedance import TimeSeries

#: the structure of the examples: modes near 900 Hz and 2640 Hz, lightly damped
EXAMPLE_MODES = ((900.0, 1e-3, 0.5), (2640.0, 3e-4, 0.8))


def modal_receptance(freq_hz, modes=EXAMPLE_MODES) -> np.ndarray:
    """``x/F`` ``(N,)`` complex at ``freq_hz`` for ``modes`` ``[(f_k Hz, ζ_k, m_k kg)]``."""
    w = 2 * np.pi * np.asarray(freq_hz, dtype=np.float64)
    H = np.zeros(w.shape, dtype=np.complex128)
    for f, zeta, m in modes:
        wk = 2 * np.pi * f
        H += 1.0 / (m * (wk**2 - w**2 + 2j * zeta * wk * w))
    return H


def modal_impedance(freq_hz, modes=EXAMPLE_MODES) -> np.ndarray:
    """Dynamic stiffness ``Z = F/x`` ``(N, 1, 1)`` (N/m) of ``modes`` at ``freq_hz``."""
    return (1.0 / modal_receptance(freq_hz, modes))[:, None, None]


def hammer_records(
    *,
    modes=EXAMPLE_MODES,
    fs_hz: float = 25_600.0,
    hits: int = 5,
    hit_spacing_s: float = 1.5,
    pulse_s: float = 1e-4,
    force_noise: float = 1e-3,
    response_noise: float = 1e-3,
    separate: bool = False,
    seed: int = 0,
) -> TimeSeries:
    """Force (N) and acceleration (m/s²) of ``hits`` hammer hits ``hit_spacing_s`` apart.

    Each hit is a half-sine pulse of ``pulse_s`` seconds and a random amplitude in 0.7–1.3 kN
    (starting 5 % into its span, at a random sub-sample offset). ``force_noise`` and
    ``response_noise`` are white-noise std relative to the largest force and acceleration.
    ``separate``: one record per hit (``(hits, T, 1)``, each starting with the structure at
    rest, as a hammer test records each hit) instead of one record ``(1, hits·T, 1)`` (each hit
    adds to the previous hits' decay). Returns a :class:`TimeSeries` (``force_unit``
    N, ``length_unit`` m; the response is an acceleration).
    """
    rng = np.random.default_rng(seed)
    span = int(round(hit_spacing_s * fs_hz))
    t = np.arange(span) / fs_hz
    pulses = np.zeros((hits, span))
    for h in range(hits):
        t0 = (0.05 * span + rng.uniform(0, 1)) / fs_hz
        on = (t >= t0) & (t <= t0 + pulse_s)
        pulses[h, on] = rng.uniform(700, 1300) * np.sin(np.pi * (t[on] - t0) / pulse_s)
    F = pulses if separate else pulses.reshape(1, -1)
    T = F.shape[1]
    # zero padding past 12 decay times of the slowest mode: the DFT's periodic response is the
    # response from rest (no wrap-around onto the record's start)
    decay = max(1.0 / (zeta * 2 * np.pi * fk) for fk, zeta, _ in modes)
    P = int(2 ** np.ceil(np.log2(T + 12 * decay * fs_hz)))
    f = np.fft.rfftfreq(P, 1 / fs_hz)
    A = np.fft.irfft(np.fft.rfft(F, P) * (2j * np.pi * f) ** 2 * modal_receptance(f, modes), P)
    A = A[:, :T]
    F = F + force_noise * np.abs(F).max() * rng.standard_normal(F.shape)
    A = A + response_noise * np.abs(A).max() * rng.standard_normal(A.shape)
    return TimeSeries(fs_hz=fs_hz, force=F[..., None], response=A[..., None])


__all__ = ["hammer_records", "modal_impedance", "modal_receptance", "EXAMPLE_MODES"]
