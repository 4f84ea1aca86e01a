"""Impact (hammer) records: deciding between an impact estimate and Welch averaging, splitting
records at impacts, force and exponential windows, and the coherence of an H1 estimate.

An impact record holds its force energy in a small fraction of the samples (one or more short
pulses) and a response that decays after each pulse. Welch averaging with a Hann window over
segments shorter than the record is wrong for such data (the window weights each impact by
where it happens to fall in a segment and cuts the decay); the estimate that fits it is one
unwindowed segment per impact, every segment starting just before its impact.

- :func:`classify_records`: ``"impact"``, ``"stationary"`` or ``"unclear"`` from the share of
  the force energy in the loudest 1 % of the samples (:data:`IMPULSIVE_SHARE`,
  :data:`STATIONARY_SHARE`).
- :func:`impact_segments`: ``(S, L, n)`` force and response segments, one per impact (a record
  with one impact is one segment; a record with several is split before each impact when the
  response decays between them, and kept whole as a double hit otherwise); records whose force
  is clipped (:func:`clipped_records`) are dropped with a note.
- :func:`apply_windows`: optional force window (force kept for ``force_window_s`` seconds
  after the segment start, zero after) and exponential window ``e^{−t/τ}`` on force and
  response. The exponential window turns the measured system ``h(t)`` into ``h(t) e^{−t/τ}``:
  the estimate is ``Z(jω + 1/τ)`` (every pole moved left by ``1/τ``: modal damping
  ``ζ_meas = ζ_true + 1/(τ ω_n)``). :func:`hapid.fit.correct_exponential` undoes it exactly on a fitted
  ``M s² + B s + K``; the FRF itself is stored as measured (windowed).
- :func:`decay_db`: how far the response has decayed at the segment end (dB below its peak).
- :func:`coherence`: multiple coherence ``γ²_i = (S_xF S_FF⁻¹ S_Fx)_ii / S_xx,ii`` of every
  response channel on the force channels, ``(F, n)`` in ``[0, 1]``, from segment spectra.
"""

from __future__ import annotations

import numpy as np

from .._constants import COHERENCE_LOW

#: a record is impulsive when its loudest 1 % of samples hold more than this share of its force
#: energy (hammer hits: > 0.9; Gaussian noise: ≈ 0.09; a sine or chirp: ≈ 0.02)
IMPULSIVE_SHARE = 0.5
#: a record is stationary (Welch averaging fits it) below this share
STATIONARY_SHARE = 0.2
#: the loudest fraction of samples whose energy share is measured
LOUD_FRACTION = 0.01
#: samples whose |force| exceeds this fraction of the record's peak belong to an impact
IMPACT_THRESHOLD = 0.1
#: impacts closer than this (s) are one impact (a double hit)
IMPACT_MERGE_S = 2e-3
#: segment start before the impact onset, as a fraction of the segment length
PRE_TRIGGER = 0.01
#: a response whose end lies less than this far (dB) below its peak has not decayed
DECAY_WARN_DB = 40.0
#: a record's impacts are separate hits (split) when the response decays this far (dB) before
#: each next impact; otherwise a double hit (one segment)
SPLIT_DECAY_DB = 20.0
#: a force at its peak for this many consecutive samples is clipped
CLIP_RUN = 3


def energy_share(force: np.ndarray) -> np.ndarray:
    """Per record ``(E,)``: the share of the force energy (channels summed) in the loudest
    :data:`LOUD_FRACTION` of its samples (``force`` ``(E, T, n)``)."""
    p = np.sum(np.asarray(force, dtype=np.float64) ** 2, axis=-1)  # (E, T)
    k = max(1, int(np.ceil(LOUD_FRACTION * p.shape[1])))
    top = -np.sort(-p, axis=1)[:, :k].sum(axis=1)
    return top / np.maximum(p.sum(axis=1), np.finfo(float).tiny)


def classify_records(force: np.ndarray) -> tuple[str, float]:
    """``("impact" | "stationary" | "unclear", share)``: impact when every record's loudest
    1 % of samples holds more than :data:`IMPULSIVE_SHARE` of its force energy, stationary when
    every record's holds less than :data:`STATIONARY_SHARE`; ``share`` the smallest (impact) or
    largest (otherwise) over records."""
    share = energy_share(force)
    if share.min() > IMPULSIVE_SHARE:
        return "impact", float(share.min())
    if share.max() < STATIONARY_SHARE:
        return "stationary", float(share.max())
    return "unclear", float(share.max() if share.min() > STATIONARY_SHARE else share.min())


def impact_onsets(force_record: np.ndarray, fs_hz: float) -> np.ndarray:
    """Sample indices where the impacts of one record ``(T, n)`` start (|force| above
    :data:`IMPACT_THRESHOLD` of the peak; pulses closer than :data:`IMPACT_MERGE_S` merged)."""
    mag = np.linalg.norm(np.asarray(force_record, dtype=np.float64), axis=-1)
    above = np.nonzero(mag > IMPACT_THRESHOLD * mag.max())[0]
    if above.size == 0:
        return above
    gap = max(1, int(round(IMPACT_MERGE_S * fs_hz)))
    new = np.concatenate([[True], np.diff(above) > gap])
    return above[new]


def clipped_records(force: np.ndarray, run: int = CLIP_RUN) -> list[tuple[int, float, int]]:
    """Records whose force sits at its peak magnitude for ``run`` or more consecutive samples
    (an overloaded hammer or ADC: the recorded pulse is not the applied one), as
    ``(record, peak, samples at the peak)``; ``force`` ``(E, T, n)``."""
    out = []
    for e, rec in enumerate(np.asarray(force, dtype=np.float64)):
        mag = np.max(np.abs(rec), axis=-1)
        peak = float(mag.max())
        at = np.concatenate([[0], (mag >= peak * (1 - 1e-7)).astype(int), [0]])
        edges = np.diff(at)
        lengths = np.nonzero(edges == -1)[0] - np.nonzero(edges == 1)[0]
        if peak > 0 and lengths.max() >= run:
            out.append((e, peak, int(lengths.max())))
    return out


def impact_segments(
    force: np.ndarray, response: np.ndarray, fs_hz: float
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Force and response segments ``(S, L, n)``, one per impact, and notes for the user.

    Records whose force is clipped (:func:`clipped_records`) are dropped. A record with one
    impact is one segment from its start. A record with several impacts is split, each segment
    starting :data:`PRE_TRIGGER`·L before its impact and ending before the next (``L`` the
    shortest such span over all records), when the response has decayed by
    :data:`SPLIT_DECAY_DB` before each next impact; otherwise the later impacts are double hits
    and the record stays one segment (H1 holds for any force inside a segment). Raises
    ``ValueError`` when every record is clipped, a record has no impact, or the segments would
    be shorter than 16 samples."""
    F, Y = np.asarray(force, dtype=np.float64), np.asarray(response, dtype=np.float64)
    notes: list[str] = []
    clipped = clipped_records(F)
    if len(clipped) == F.shape[0]:
        e, peak, k = clipped[0]
        raise ValueError(f"the force of every record is clipped (record {e}: {k} samples at its "
                         f"peak {peak:.4g}): the hammer or the ADC was overloaded; measure again "
                         "with a softer hit or a larger range")  # fmt: skip
    for e, peak, k in clipped:
        notes.append(f"record {e} dropped: its force is clipped ({k} samples at its peak "
                     f"{peak:.4g}; an overloaded hammer or ADC)")  # fmt: skip
    dropped = {c[0] for c in clipped}
    keep = [e for e in range(F.shape[0]) if e not in dropped]
    F, Y = F[keep], Y[keep]
    E, T, _ = F.shape
    onsets = [impact_onsets(F[e], fs_hz) for e in range(E)]
    for e, o in enumerate(onsets):
        if o.size == 0:
            raise ValueError(f"record {keep[e]} has no impact (its force is zero)")
    # several impacts in a record: separate hits when the response decays before each next one
    split = []
    w = max(1, int(round(IMPACT_MERGE_S * fs_hz)))
    for e, o in enumerate(onsets):
        if o.size > 1:
            decays = [
                _decay_before(Y[e], int(a), int(b), w) for a, b in zip(o[:-1], o[1:], strict=True)
            ]
            if min(decays) >= SPLIT_DECAY_DB:
                split.append(e)
            else:
                i = int(np.argmin(decays))
                ratio = (
                    np.abs(F[e, o[i + 1] : o[i + 1] + w]).max()
                    / np.abs(F[e, o[i] : o[i] + w]).max()
                )
                notes.append(f"record {keep[e]} has a double hit ({1e3 * (o[i + 1] - o[i]) / fs_hz:.1f} "
                             f"ms after the first, {100 * ratio:.0f} % of its peak): kept as one "
                             "segment")  # fmt: skip
    L_multi = [int(np.min(np.diff(np.append(onsets[e], T)))) for e in split]
    L = T if not L_multi else min(L_multi)
    pre = int(PRE_TRIGGER * L) if L_multi else 0
    if L - pre < 16:
        raise ValueError(f"impacts only {L} samples apart: too close for one segment each")
    segF, segY = [], []
    for e, o in enumerate(onsets):
        if e not in split:
            start = [0] if not L_multi else [max(0, min(int(o[0]) - pre, T - L))]
        else:
            start = [max(0, min(int(t) - pre, T - L)) for t in o]
        for s in start:
            segF.append(F[e, s : s + L])
            segY.append(Y[e, s : s + L])
    if split:
        notes.append(f"{len(split)} record(s) held several impacts: split before each impact")
    return np.stack(segF), np.stack(segY), notes


def _decay_before(y: np.ndarray, a: int, b: int, w: int) -> float:
    """dB from the response's largest mean square over ``w`` samples in ``[a, b)`` to its mean
    square over the last ``w`` samples before ``b`` (``y`` ``(T, n)``)."""
    if b - a < w:
        return 0.0
    return float(_peak_to_end_db(np.sum(y[a:b] ** 2, axis=-1), w))


def apply_windows(
    F: np.ndarray,
    Y: np.ndarray,
    fs_hz: float,
    *,
    force_window_s: float | None = None,
    exp_tau_s: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Segments ``(S, L, n)`` with the force window (force zeroed after ``force_window_s``
    seconds from the impact onset) and the exponential window ``e^{−t/τ}`` (t from the segment
    start) on both; ``None``: not applied."""
    F, Y = np.array(F, dtype=np.float64), np.array(Y, dtype=np.float64)
    t = np.arange(F.shape[1]) / fs_hz
    if force_window_s is not None:
        for s in range(F.shape[0]):
            o = impact_onsets(F[s], fs_hz)
            t0 = t[o[0]] if o.size else 0.0
            F[s, t > t0 + force_window_s] = 0.0
    if exp_tau_s is not None:
        w = np.exp(-t / exp_tau_s)[None, :, None]
        F, Y = F * w, Y * w
    return F, Y


def _peak_to_end_db(power: np.ndarray, w: int) -> np.ndarray:
    """dB from the largest mean of ``power`` over any ``w`` consecutive samples (axis 0) to its
    mean over the last ``w``: ``(T, ...)`` → ``(...)`` (``T ≥ w``)."""
    c = np.cumsum(np.concatenate([np.zeros((1,) + power.shape[1:]), power]), axis=0)
    ms = (c[w:] - c[:-w]) / w  # moving mean (T-w+1, ...)
    tiny = np.finfo(float).tiny
    return 10 * np.log10(np.maximum(ms.max(axis=0), tiny) / np.maximum(ms[-1], tiny))


def decay_db(Y: np.ndarray) -> float:
    """How far (dB) the response's RMS over the last 5 % of each segment lies below its largest
    RMS over any 5 % window; the smallest over segments and channels (``Y`` ``(S, L, n)``)."""
    Y = np.asarray(Y, dtype=np.float64)
    w = max(1, Y.shape[1] // 20)
    return float(np.min(_peak_to_end_db(np.moveaxis(Y**2, 1, 0), w)))


def coherence(XF: np.ndarray, XY: np.ndarray) -> np.ndarray:
    """Multiple coherence ``(F, n)`` of each response channel on the forces, from segment
    spectra ``XF``, ``XY`` ``(S, F, n)``; 1 where a channel's spectrum is zero."""
    S_FF = np.einsum("sfi,sfj->fij", XF, XF.conj())
    S_YF = np.einsum("sfi,sfj->fij", XY, XF.conj())
    S_YY = np.einsum("sfi,sfi->fi", XY, XY.conj()).real
    H = S_YF @ np.linalg.pinv(S_FF, hermitian=True)
    num = np.einsum("fij,fij->fi", H, S_YF.conj()).real
    g = np.where(S_YY > 0, num / np.where(S_YY > 0, S_YY, 1.0), 1.0)
    return np.clip(g, 0.0, 1.0)


def low_coherence_bands(freq_hz: np.ndarray, gamma2: np.ndarray, level=COHERENCE_LOW) -> list:
    """Contiguous bands ``[(f_lo, f_hi, min γ²)]`` where the smallest channel coherence is
    below ``level`` (at most 5, the widest first)."""
    g = np.min(np.asarray(gamma2), axis=-1)
    low = g < level
    out, i = [], 0
    while i < low.size:
        if low[i]:
            j = i
            while j + 1 < low.size and low[j + 1]:
                j += 1
            out.append((float(freq_hz[i]), float(freq_hz[j]), float(g[i : j + 1].min()), j - i))
            i = j + 1
        else:
            i += 1
    out.sort(key=lambda b: -b[3])
    return [b[:3] for b in out[:5]]


def low_coherence_note(freq_hz: np.ndarray, gamma2: np.ndarray, level=COHERENCE_LOW) -> str:
    """One line naming where the smallest channel coherence of ``gamma2`` ``(N, n)`` is below
    ``level``: how many frequencies and the widest bands (at most 3) with their minimum γ²;
    ``""`` when it nowhere is."""
    bands = low_coherence_bands(freq_hz, gamma2, level)
    if not bands:
        return ""
    txt = ", ".join(f"{a:.4g}–{b:.4g} Hz (min {g:.2f})" for a, b, g in bands[:3])
    n_low = int(np.sum(np.min(np.asarray(gamma2), axis=-1) < level))
    return (f"low coherence γ² < {level:g} at {n_low} of {np.shape(gamma2)[0]} frequencies; "
            f"widest bands {txt}")  # fmt: skip


__all__ = [
    "classify_records",
    "impact_segments",
    "apply_windows",
    "decay_db",
    "coherence",
    "low_coherence_bands",
    "low_coherence_note",
    "energy_share",
]
