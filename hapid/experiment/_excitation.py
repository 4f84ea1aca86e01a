"""Multisine excitation and the experiment patterns that distribute it over the rods.

A multisine ``r_f(t) = Σ_k a_k cos(ω_k t + α_k)`` is periodic with period ``τ`` only if every
``ω_k`` is an integer multiple of ``2π/τ``: the paper prints ``2π/t_s``, a typo (a multiple of
the sampling frequency aliases to DC). ``check_on_grid`` enforces the correct rule.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import _config  # noqa: F401


def paper_frequencies() -> np.ndarray:
    """The paper's 28 frequencies (Hz): 1, …, 10 and 15, 20, …, 100."""
    return np.concatenate([np.arange(1.0, 11.0), np.arange(15.0, 101.0, 5.0)])


def check_on_grid(freq_hz, fs_hz: float, period_samples: int) -> np.ndarray:
    """Return the FFT bin index of each frequency; raise if any is off the period's grid.

    Frequencies must be integer multiples of ``fs_hz / period_samples`` (1/τ), strictly
    between 0 and the Nyquist frequency, and distinct.
    """
    f = np.asarray(freq_hz, dtype=float)
    if f.ndim != 1 or f.size == 0:
        raise ValueError(f"excited frequencies must be a non-empty 1-D array, got shape {f.shape}")
    if not np.all(np.isfinite(f)):
        raise ValueError("excited frequencies contain NaN or inf")
    df = fs_hz / period_samples
    k = f / df
    kr = np.round(k)
    off = np.abs(k - kr) > 1e-9 * np.maximum(1.0, np.abs(k))
    if np.any(off):
        bad = ", ".join(f"{x:g}" for x in f[off][:5])
        raise ValueError(
            f"frequencies off the FFT grid: {bad} Hz are not integer multiples of 1/τ = "
            f"fs/period = {df:g} Hz (τ = {period_samples} samples at {fs_hz:g} Hz). Note: the "
            "paper's 'integer multiples of 2π/t_s' is a typo for 2π/τ."
        )
    if np.any(kr <= 0) or np.any(kr >= period_samples / 2):
        raise ValueError(
            f"excited frequencies must lie strictly between 0 and the Nyquist frequency "
            f"{fs_hz / 2:g} Hz, got {f.min():g}–{f.max():g} Hz"
        )
    if len(np.unique(kr)) != len(kr):
        raise ValueError("excited frequencies must be distinct")
    return kr.astype(np.int64)


class Multisine(eqx.Module):
    """One period of ``Σ a_k cos(2π f_k t + α_k)`` on a sampled grid.

    freq_hz ``(K,)``, amplitude ``(K,)`` (N), phase ``(K,)`` (rad); ``fs_hz`` and
    ``period_samples`` define the grid.
    """

    freq_hz: Float[Array, " K"]
    amplitude: Float[Array, " K"]
    phase: Float[Array, " K"]
    fs_hz: float = eqx.field(static=True)
    period_samples: int = eqx.field(static=True)

    @property
    def bins(self) -> np.ndarray:
        return check_on_grid(self.freq_hz, self.fs_hz, self.period_samples)

    def period(self) -> Float[Array, " T"]:
        """One period of the signal, ``(period_samples,)``."""
        t = jnp.arange(self.period_samples) / self.fs_hz
        arg = 2 * jnp.pi * self.freq_hz[:, None] * t[None, :] + self.phase[:, None]
        return jnp.sum(self.amplitude[:, None] * jnp.cos(arg), axis=0)

    def crest_factor(self) -> float:
        x = np.asarray(self.period())
        return float(np.max(np.abs(x)) / np.sqrt(np.mean(x**2)))


def schroeder_phases(K: int) -> np.ndarray:
    """Schroeder's low-crest-factor phases for ``K`` equal-amplitude components."""
    k = np.arange(1, K + 1)
    return -np.pi * k * (k - 1) / K


def multisine(
    freq_hz,
    fs_hz: float = 1000.0,
    period_samples: int = 1000,
    amplitude: float | np.ndarray = 0.3,
    phases: str | np.ndarray = "random",
    seed: int = 0,
    crest_iterations: int = 200,
) -> Multisine:
    """Build a multisine on the period's FFT grid.

    phases: ``"random"`` (uniform on [0, 2π), the paper), ``"schroeder"``, ``"min_crest"``
    (Schroeder start refined by iterative clipping, Van der Ouderaa et al. 1988, which keeps
    the amplitude spectrum and lowers the crest factor), or an explicit ``(K,)`` array.
    """
    f = np.asarray(freq_hz, dtype=float)
    bins = check_on_grid(f, fs_hz, period_samples)
    amp = np.broadcast_to(np.asarray(amplitude, dtype=float), f.shape).copy()
    if np.any(~np.isfinite(amp)) or np.any(amp <= 0):
        raise ValueError("multisine amplitudes must be finite and > 0")
    if isinstance(phases, str):
        if phases == "random":
            ph = np.random.default_rng(seed).uniform(0.0, 2 * np.pi, f.size)
        elif phases == "schroeder":
            ph = schroeder_phases(f.size)
        elif phases == "min_crest":
            ph = _min_crest(bins, amp, period_samples, schroeder_phases(f.size), crest_iterations)
        else:
            raise ValueError(f"unknown phases {phases!r}; use 'random', 'schroeder', 'min_crest'")
    else:
        ph = np.asarray(phases, dtype=float)
        if ph.shape != f.shape:
            raise ValueError(f"phases must have shape {f.shape}, got {ph.shape}")
    return Multisine(
        jnp.asarray(f), jnp.asarray(amp), jnp.asarray(ph), float(fs_hz), int(period_samples)
    )


def _min_crest(bins, amp, T, ph0, iters):
    spec = np.zeros(T // 2 + 1, dtype=complex)
    best_ph, best_cf = ph0, np.inf
    ph = ph0
    for _ in range(iters):
        spec[:] = 0
        spec[bins] = amp * np.exp(1j * ph) * T / 2
        x = np.fft.irfft(spec, n=T)
        cf = np.max(np.abs(x)) / np.sqrt(np.mean(x**2))
        if cf < best_cf:
            best_cf, best_ph = cf, ph
        clip = 0.9 * np.max(np.abs(x))
        ph = np.angle(np.fft.rfft(np.clip(x, -clip, clip))[bins])
    return best_ph


def patterns(n: int, kind: str = "paper") -> np.ndarray:
    """Experiment patterns ``(E, n)``: row ``e`` multiplies ``r_f(t)`` on each rod.

    ``"paper"``: eq. (6), all ones with −1 on the diagonal (``E = n``; invertible for n ≥ 3).
    ``"one_at_a_time"``: the identity (the paper's failing alternative).
    ``"hadamard"``: the first ``n`` columns of a Sylvester–Hadamard matrix of order
    ``2^⌈log2(n+1)⌉`` skipping its all-ones column (orthogonal columns, ``E > n``: least squares).
    """
    if n < 1:
        raise ValueError(f"n must be ≥ 1, got {n}")
    if kind == "paper":
        U = np.ones((n, n)) - 2 * np.eye(n)
    elif kind == "one_at_a_time":
        U = np.eye(n)
    elif kind == "hadamard":
        H = np.array([[1.0]])
        while H.shape[0] < n + 1:
            H = np.block([[H, H], [H, -H]])
        U = H[:, 1 : n + 1]
    else:
        raise ValueError(f"unknown pattern {kind!r}; use 'paper', 'one_at_a_time', 'hadamard'")
    check_patterns(U, n)
    return U


def check_patterns(U, n: int) -> None:
    """Raise if a pattern matrix ``(E, n)`` cannot identify an ``n``-rod impedance."""
    U = np.asarray(U, dtype=float)
    if U.ndim != 2 or U.shape[1] != n:
        raise ValueError(f"pattern matrix must be (E, n) with n = {n}, got shape {U.shape}")
    if U.shape[0] < n:
        raise ValueError(f"E = {U.shape[0]} experiments < n = {n} rods: 𝓛 cannot be inverted")
    if not np.all(np.isfinite(U)):
        raise ValueError("pattern matrix contains NaN or inf")
    sv = np.linalg.svd(U, compute_uv=False)
    if sv[-1] <= 1e-10 * sv[0]:
        raise ValueError(
            f"singular excitation pattern matrix (rank {int(np.sum(sv > 1e-10 * sv[0]))} < n = {n}): "
            "the experiments do not excite independent directions"
        )
