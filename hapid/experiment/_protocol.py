"""Experiment protocol (what is excited, how long, how noisy) and the Run record it produces."""

from __future__ import annotations

import dataclasses

import numpy as np

from ._excitation import check_on_grid, check_patterns, multisine, paper_frequencies, patterns


@dataclasses.dataclass(frozen=True)
class Protocol:
    """The paper's multisine protocol, with hapid's options.

    freq_hz: excited frequencies (Hz), on the grid ``fs_hz / period_samples``.
    pattern: ``"paper"`` (eq. 6), ``"one_at_a_time"``, ``"hadamard"`` or an ``(E, n)`` array.
    amplitude: multisine component amplitude ``a`` (N).
    phases: ``"random"`` (the paper), ``"schroeder"``, ``"min_crest"``.
    n_periods: measured periods per experiment (≥ 2 to estimate the noise std).
    transient_periods: periods simulated and discarded before measuring (time domain).
    force_noise: force-sensor noise std (N) per sample; position_noise: encoder noise std
    (m); encoder_resolution: quantization step of ``L`` (m, 0 = off). Quantization error of
    a periodic signal repeats every period: it biases the FRF and is *not* in its std.
    """

    freq_hz: tuple[float, ...] = tuple(paper_frequencies())
    fs_hz: float = 1000.0
    period_samples: int = 1000
    n_periods: int = 4
    transient_periods: int = 1
    pattern: str | tuple = "paper"
    amplitude: float = 0.3
    phases: str = "random"
    seed: int = 0
    force_noise: float = 5e-3
    position_noise: float = 0.0
    encoder_resolution: float = 2e-6

    def __post_init__(self):
        object.__setattr__(self, "freq_hz", tuple(float(f) for f in np.atleast_1d(self.freq_hz)))
        check_on_grid(self.freq_hz, self.fs_hz, self.period_samples)
        if self.n_periods < 1 or self.transient_periods < 0:
            raise ValueError("n_periods must be ≥ 1 and transient_periods ≥ 0")
        for name in ("force_noise", "position_noise", "encoder_resolution"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be finite and ≥ 0, got {v}")

    def pattern_matrix(self, n: int) -> np.ndarray:
        if isinstance(self.pattern, str):
            return patterns(n, self.pattern)
        U = np.asarray(self.pattern, dtype=float)
        check_patterns(U, n)
        return U

    def excitation(self):
        return multisine(self.freq_hz, self.fs_hz, self.period_samples, self.amplitude,
                         self.phases, self.seed)  # fmt: skip

    def noiseless(self) -> Protocol:
        return dataclasses.replace(
            self, force_noise=0.0, position_noise=0.0, encoder_resolution=0.0
        )


@dataclasses.dataclass(frozen=True)
class Run:
    """A measured (or simulated) periodic run, the run-file contract of docs/contracts.md.

    fs_hz, period_samples; freq_hz ``(K,)`` excited frequencies (multiples of
    ``fs_hz/period_samples``); R_A, R_I, L ``(E, T, n)``: commanded actuator forces (N),
    sensed interaction forces (N), encoder rod lengths (m); ``T`` a whole number of periods in
    steady state.
    """

    fs_hz: float
    period_samples: int
    freq_hz: np.ndarray
    R_A: np.ndarray
    R_I: np.ndarray
    L: np.ndarray

    def __post_init__(self):
        validate_run(self)

    @property
    def n(self) -> int:
        return int(self.R_A.shape[-1])

    @property
    def n_periods(self) -> int:
        return int(self.R_A.shape[1] // self.period_samples)


def validate_run(run: Run) -> None:
    """Raise ``ValueError`` naming the first problem with a run record."""
    fs, Tp = run.fs_hz, run.period_samples
    if not np.isfinite(fs) or fs <= 0:
        raise ValueError(f"run: fs_hz must be finite and > 0, got {fs}")
    if int(Tp) != Tp or Tp < 2:
        raise ValueError(f"run: period_samples must be an integer ≥ 2, got {Tp}")
    shapes = {k: np.shape(getattr(run, k)) for k in ("R_A", "R_I", "L")}
    if len(set(shapes.values())) != 1:
        raise ValueError(f"run: R_A, R_I, L must have the same (E, T, n) shape, got {shapes}")
    shape = shapes["R_A"]
    if len(shape) != 3:
        raise ValueError(f"run: signals must be (E, T, n) arrays, got shape {shape}")
    E, T, n = shape
    if E < n:
        raise ValueError(f"run: E = {E} experiments < n = {n} rods; need E ≥ n to invert 𝓛")
    if T % Tp != 0 or T == 0:
        raise ValueError(
            f"run: T = {T} samples is not a whole number of periods of {Tp} samples "
            f"({T / Tp:.3f} periods)"
        )
    for k in ("R_A", "R_I", "L"):
        a = getattr(run, k)
        if not np.all(np.isfinite(a)):
            idx = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
            raise ValueError(
                f"run: {k} contains NaN or inf (first at [experiment, sample, rod] = {idx})"
            )
    check_on_grid(run.freq_hz, fs, Tp)
