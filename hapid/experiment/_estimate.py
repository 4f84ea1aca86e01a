"""Empirical impedances from measured signals (paper section 4.1), with noise std.

Periodic runs: average the periods, take the DFT at the excited bins, stack the ``E``
experiments into ``𝓡_I, 𝓡_A, 𝓛`` (``n × E`` per frequency) and solve
``Z_H = −𝓡_I 𝓛⁺``, ``Z_T = −𝓡_A 𝓛⁺`` (``𝓛⁺ = 𝓛⁻¹`` when ``E = n``, least squares when
``E > n``).

Noise std: per period ``p`` the equation error ``ε_p = R_p + Ẑ L_p`` (``n × E``) scatters with
the measurement noise; its sample variance over periods divided by the number of periods is
the variance of the averaged equation error, and to first order
``var(Ẑ_ij) = Σ_e var(ε̄_ie) |𝓛⁺_ej|²`` (experiments independent). The reported std is
``sqrt(E|Ẑ_ij − Z_ij|²)`` (real and imaginary parts together); it needs ≥ 2 periods.

Non-periodic records (chirps, noise, lab data): ``estimate_frf_h1`` averages cross-spectra
over Welch segments and experiments.
"""

from __future__ import annotations

import warnings

import numpy as np

from .._grids import band_mask
from ..frf import FRF, as_frf
from ._protocol import Run, validate_run
from ._transient import coherence

#: 𝓛 with a condition number above this is treated as rank deficient (an error).
COND_ERROR = 1e10


def _dft_bins(x: np.ndarray, bins: np.ndarray, Tp: int) -> np.ndarray:
    """Complex amplitudes at ``bins`` of ``x`` (``(..., Tp, n)``) scaled so a cosine of
    amplitude ``a`` and phase ``α`` gives ``a e^{jα}``."""
    return np.fft.rfft(x, axis=-2)[..., bins, :] * (2.0 / Tp)


def _nonzero_positions(L: np.ndarray) -> None:
    """Raise ``ValueError`` when a position record is zero everywhere (no FRF exists)."""
    L = np.asarray(L)
    for e in range(L.shape[0]):
        if not np.any(L[e]):
            raise ValueError(
                f"the position record L of experiment {e} is zero everywhere: the encoders "
                "recorded nothing, so no impedance can be estimated"
            )


def _solve_frf(R: np.ndarray, Lm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Z = −R 𝓛⁺`` and ``𝓛⁺`` per frequency. R, Lm: ``(K, n, E)``."""
    Lpinv = np.linalg.pinv(Lm)  # (K, E, n)
    return -R @ Lpinv, Lpinv


def estimate_frf(run: Run, *, cond_warn: float = 1e3) -> FRF:
    """Empirical ``Z_H, Z_T`` (``(K, n, n)``) with element std from a periodic run.

    Warns where ``cond(𝓛)`` exceeds ``cond_warn`` (poorly excited directions: the paper's
    one-rod-at-a-time failure) and raises ``ValueError`` where 𝓛 is rank deficient.
    """
    validate_run(run)
    _nonzero_positions(run.L)
    Tp, E, n = run.period_samples, run.R_A.shape[0], run.n
    P = run.n_periods
    bins = np.round(np.asarray(run.freq_hz) * Tp / run.fs_hz).astype(int)

    def spectra(x):  # (E, P*Tp, n) → per period (E, P, K, n)
        return _dft_bins(x.reshape(E, P, Tp, n), bins, Tp)

    SL, SI, SA = spectra(run.L), spectra(run.R_I), spectra(run.R_A)
    # stack experiments as columns: (K, n, E)
    col = lambda S: np.transpose(S.mean(axis=1), (1, 2, 0))  # noqa: E731
    Lm, RI, RA = col(SL), col(SI), col(SA)
    sv = np.linalg.svd(Lm, compute_uv=False)
    cond = sv[:, 0] / np.maximum(sv[:, -1], np.finfo(float).tiny)
    f = np.asarray(run.freq_hz)
    bad = cond > COND_ERROR
    if np.any(bad):
        raise ValueError(
            f"rank-deficient displacement matrix 𝓛 at {', '.join(f'{x:g}' for x in f[bad][:5])} Hz "
            f"(cond up to {cond[bad].max():.3g}): the experiments do not move the rods in n "
            "independent directions there; change the excitation patterns"
        )
    poor = cond > cond_warn
    if np.any(poor):
        warnings.warn(
            f"poorly conditioned 𝓛 (cond > {cond_warn:g}) at {int(poor.sum())} frequencies "
            f"({', '.join(f'{x:g}' for x in f[poor][:5])} Hz …; max {cond.max():.3g}): the "
            "empirical impedances are sensitive to noise there",
            stacklevel=2,
        )
    # The commanded forces are known exactly: nearly dependent excitation patterns show in
    # cond(𝓡_A) even when sensor noise makes the measured 𝓛 look well conditioned (the
    # noise, not the excitation, then "excites" the missing direction).
    sa = np.linalg.svd(RA, compute_uv=False)
    cond_A = sa[:, 0] / np.maximum(sa[:, -1], np.finfo(float).tiny)
    poor_A = (cond_A > cond_warn) & ~poor
    if np.any(poor_A):
        warnings.warn(
            f"nearly dependent excitation: the commanded forces 𝓡_A have cond > {cond_warn:g} "
            f"at {int(poor_A.sum())} frequencies ({', '.join(f'{x:g}' for x in f[poor_A][:5])} "
            f"Hz …; max {cond_A.max():.3g}) although cond(𝓛) is lower: the displacement in the "
            "weakly excited direction is mostly noise; change the excitation patterns",
            stacklevel=2,
        )
    Z_H, Lpinv = _solve_frf(RI, Lm)
    Z_T, _ = _solve_frf(RA, Lm)
    std_H = std_T = None
    if P >= 2:
        std_H = _std(SI, SL, Z_H, Lpinv)
        std_T = _std(SA, SL, Z_T, Lpinv)
    return as_frf(f, Z_H, Z_T, std_H, std_T, cond)


def _std(SR, SL, Z, Lpinv):
    """First-order std of ``Ẑ = −R̄ 𝓛⁺`` from period-to-period scatter (see module doc)."""
    E, P = SR.shape[:2]
    # equation error per period: ε = R_p + Z L_p, shapes (E, P, K, n)
    eps = SR + np.einsum("kij,epkj->epki", Z, SL)
    var_mean = np.var(eps, axis=1, ddof=1) / P  # (E, K, n): var of the averaged ε (complex)
    w = np.abs(Lpinv) ** 2  # (K, E, n)
    var = np.einsum("eki,kej->kij", var_mean, w)
    return np.sqrt(var)


def window_array(window: str, nperseg: int) -> np.ndarray:
    """The segment window: ``"hann"`` is scipy's periodic Hann
    (``scipy.signal.get_window("hann", nperseg)``, scipy's default for Welch), ``"boxcar"``
    ones."""
    if window == "hann":  # scipy's general_cosine with (0.5, 0.5), term by term: same bits
        if nperseg <= 1:
            return np.ones(nperseg)
        fac = np.linspace(-np.pi, np.pi, nperseg + 1)
        w = np.zeros(nperseg + 1)
        w += 0.5 * np.cos(0 * fac)
        w += 0.5 * np.cos(1 * fac)
        return w[:-1]
    if window == "boxcar":
        return np.ones(nperseg)
    raise ValueError(f"window must be 'hann' or 'boxcar', got {window!r}")


def segment_starts(T: int, nperseg: int, window: str) -> np.ndarray:
    """Segment starts: 50 % overlap for Hann; none for boxcar (overlapping rectangular segments
    share half their noise, which the segment-scatter std, segments independent, would not
    see)."""
    step = nperseg if window == "boxcar" else nperseg // 2
    return np.arange(0, T - nperseg + 1, step)


def segment_spectra(x: np.ndarray, nperseg: int, window: str) -> np.ndarray:
    """rFFT of the windowed Welch segments of ``x`` ``(E, T, n)`` → ``(E, S, F, n)``."""
    starts = segment_starts(x.shape[1], nperseg, window)
    win = window_array(window, nperseg)
    seg = np.stack([x[:, s : s + nperseg] for s in starts], 1) * win[:, None]
    return np.fft.rfft(seg, axis=2)


def estimate_frf_h1(
    fs_hz: float,
    R_A: np.ndarray,
    R_I: np.ndarray,
    L: np.ndarray,
    *,
    nperseg: int,
    freq_hz: np.ndarray | None = None,
    f_band_hz: tuple[float, float] | None = None,
    reference: str = "L",
    window: str = "hann",
) -> FRF:
    """Averaged cross-spectral estimate for non-periodic records (chirp, noise, lab data).

    Signals ``(E, T, n)``; Welch segments of ``nperseg`` samples (scipy's periodic Hann window, 50 % overlap,
    or ``window="boxcar"`` without overlap: leakage-free for periodic excitation)
    over all experiments. ``reference="L"`` is the classic H1 estimator
    ``Z = −S_{R L} S_{L L}⁻¹`` (assumes noise-free ``L``); ``reference="R_A"`` uses the
    known command as instrument, ``Z = −S_{R A} S_{L A}⁻¹``, which is not biased by encoder
    noise. Returns the FRF at the Welch bins nearest to ``freq_hz`` (or all bins in
    ``f_band_hz``, excluding DC). Std from segment-to-segment equation-error scatter
    (segments treated as independent, which is optimistic with overlap).

    Coherence (``reference="L"``): ``coherence_H[f, i]`` is the multiple coherence of the hand
    force ``R_I,i`` on the displacements ``L``, ``γ²_i = (S_{R L} S_{L L}⁻¹ S_{L R})_ii /
    S_{R R,ii}`` over the same segments, ``coherence_T`` the same for ``R_A``; ``(N, n)`` in
    ``[0, 1]`` (1 where a channel's spectrum is zero). It is ``None`` when there are no more
    segments (over all experiments) than rods, where it is identically 1 and says nothing, and
    with ``reference="R_A"`` (the command is the instrument there, not the H1 input).
    """
    R_A, R_I, L = (np.asarray(a, dtype=float) for a in (R_A, R_I, L))
    if not (R_A.shape == R_I.shape == L.shape) or R_A.ndim != 3:
        raise ValueError(
            f"R_A, R_I, L must be equal (E, T, n) arrays, got {R_A.shape}, {R_I.shape}, {L.shape}"
        )
    for name, a in (("R_A", R_A), ("R_I", R_I), ("L", L)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} contains NaN or inf")
    E, T, n = R_A.shape
    if reference == "L":
        _nonzero_positions(L)
    if nperseg > T or nperseg < 8:
        raise ValueError(f"nperseg = {nperseg} must be between 8 and the record length {T}")
    if window not in ("hann", "boxcar"):
        raise ValueError(f"window must be 'hann' or 'boxcar', got {window!r}")
    n_seg = len(segment_starts(T, nperseg, window))
    if n_seg * E < n:
        raise ValueError(f"only {n_seg * E} segments for n = {n} rods: record too short")
    fft = lambda x: segment_spectra(x, nperseg, window)  # noqa: E731  (E, S, F, n)
    XL, XI, XA = fft(L), fft(R_I), fft(R_A)
    fgrid = np.fft.rfftfreq(nperseg, 1.0 / fs_hz)
    if freq_hz is not None:
        idx = np.unique(np.argmin(np.abs(fgrid[None, :] - np.asarray(freq_hz)[:, None]), axis=1))
    else:
        lo, hi = f_band_hz if f_band_hz is not None else (fgrid[1], fgrid[-1])
        idx = np.nonzero(band_mask(fgrid, lo, hi) & (fgrid > 0))[0]
    if reference == "L":
        X = XL
    elif reference == "R_A":
        X = XA
    else:
        raise ValueError(f"reference must be 'L' or 'R_A', got {reference!r}")
    flat = lambda Y: Y[:, :, idx, :].reshape(-1, len(idx), n)  # noqa: E731  (E·S, F, n)
    YL, YI, YA, YX = flat(XL), flat(XI), flat(XA), flat(X)
    S = lambda Y: np.einsum("sfi,sfj->fij", Y, YX.conj())  # noqa: E731
    S_LX = S(YL)
    cond = np.linalg.cond(S_LX)
    if np.any(cond > COND_ERROR**2):
        raise ValueError(
            "rank-deficient cross-spectrum S_LX: too few independent experiments/segments"
        )
    inv = np.linalg.inv(S_LX)
    Z_H = -S(YI) @ inv
    Z_T = -S(YA) @ inv

    def std(YR, Z):
        eps = YR + np.einsum("fij,sfj->sfi", Z, YL)  # (S, F, n)
        w = np.einsum("sfj,fjk->sfk", YX.conj(), inv)  # (S, F, n)
        var = np.einsum("sfi,sfk->fik", np.abs(eps) ** 2, np.abs(w) ** 2)
        return np.sqrt(var)

    coh_H = coh_T = None
    if reference == "L" and n_seg * E > n:
        coh_H, coh_T = coherence(YX, YI), coherence(YX, YA)
    return as_frf(fgrid[idx], Z_H, Z_T, std(YI, Z_H), std(YA, Z_T), np.sqrt(cond),
                  coherence_H=coh_H, coherence_T=coh_T)  # fmt: skip
