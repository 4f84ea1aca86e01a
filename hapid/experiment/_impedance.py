"""A single measured impedance from lab time series: force and response records → ``Z = F/x``.

``TimeSeries``: sampling rate ``fs_hz`` and records ``force``, ``response`` ``(E, T, n)``
(``E`` experiments of ``T`` samples on ``n`` channels; a single record is ``E = 1``). The
response is a displacement, velocity or acceleration of the same (collocated) points the
forces act on.

``estimate_impedance``: the H1 estimator with the force as reference — ``H = S_xF S_FF⁻¹``
(response over force, noise on the response), turned into dynamic stiffness ``Z = H⁻¹`` — by
:func:`hapid.experiment.estimate_frf_h1` with the force as instrument (``Z = S_FF S_xF⁻¹``),
over segments chosen to fit the records: one unwindowed segment per impact for impact
(hammer) records, Welch segments (scipy's periodic Hann, 50 % overlap) for stationary ones
(:mod:`._transient` decides). A velocity or acceleration response is converted in the
frequency domain: ``x = v/(jω) = a/(jω)²``, so ``Z = (jω)^k · F/response`` (k = 1, 2). Std
per element from the segment-to-segment scatter of the equation error (segments treated as
independent, which is optimistic with overlap); coherence γ² of every response channel. With
``E`` experiments the n × n estimate needs the forces of the experiments to span n directions
at each frequency (one chirp on all channels in phase excites only one).
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np

from .._grids import band_mask
from ..defaults import NPERSEG
from ..impedance_frf import ImpedanceFRF, as_impedance_frf
from ._estimate import estimate_frf_h1, segment_spectra, segment_starts
from ._transient import (
    IMPULSIVE_SHARE,
    STATIONARY_SHARE,
    apply_windows,
    classify_records,
    coherence,
    decay_db,
    impact_segments,
    low_coherence_note,
)

RESPONSE_KINDS = {"displacement": 0, "velocity": 1, "acceleration": 2}
#: Welch segment length (samples) when none is given
#: the force and exponential windows span at least this many samples
WINDOW_MIN_SAMPLES = 4
#: impact responses that decay less than this (dB) by the segment end leak (auto refuses)
DECAY_MIN_DB = 20.0


@dataclasses.dataclass(frozen=True)
class TimeSeries:
    """Lab records: ``fs_hz`` (Hz), ``force`` and ``response`` ``(E, T, n)`` float64;
    ``force_unit`` and ``length_unit`` (unit of the displacement the response converts to)
    only label the impedance (``Z`` in ``force_unit/length_unit``)."""

    fs_hz: float
    force: np.ndarray
    response: np.ndarray
    force_unit: str = "N"
    length_unit: str = "m"

    def __post_init__(self):
        validate_timeseries(self)

    @property
    def n(self) -> int:
        return int(self.force.shape[-1])

    @property
    def z_unit(self) -> str:
        lu = self.length_unit
        lu = f"({lu})" if any(c in lu for c in "·*/ ") else lu
        return f"{self.force_unit}/{lu}"


def validate_timeseries(ts: TimeSeries) -> None:
    """Raise ``ValueError`` naming the problem (shapes, finiteness, sampling rate)."""
    if not (np.isfinite(ts.fs_hz) and ts.fs_hz > 0):
        raise ValueError(f"fs_hz must be a positive number, got {ts.fs_hz}")
    F, Y = np.asarray(ts.force), np.asarray(ts.response)
    if F.ndim != 3 or Y.ndim != 3:
        raise ValueError(
            f"force and response must be (E, T, n) records, got shapes {F.shape} and {Y.shape}"
        )
    if F.shape != Y.shape:
        raise ValueError(f"force has shape {F.shape} but response has {Y.shape}; they must match")
    if F.shape[1] < 16:
        raise ValueError(
            f"records have only {F.shape[1]} samples (T is the middle axis of (E, T, n))"
        )
    for name, a in (("force", F), ("response", Y)):
        if not np.all(np.isfinite(a)):
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
            raise ValueError(f"{name} contains NaN or inf (first at index {bad})")


class EstimateUndecided(ValueError):
    """The records do not say which estimate fits them; the message names the options."""


class EstimateStatus(enum.StrEnum):
    """Outcome of :func:`estimate_impedance` (:class:`ImpedanceEstimate`); both are ``ok``."""

    OK = "ok"
    NOTES = "notes"


@dataclasses.dataclass(frozen=True)
class ImpedanceEstimate:
    """Outcome of :func:`estimate_impedance`.

    ``frf`` the impedance FRF (with ``coherence`` unless there are no more segments than
    channels); ``method`` ``"impact"`` (one unwindowed segment per impact) or ``"welch"``;
    ``n_segments`` and ``segment_samples`` the segments averaged; ``energy_share`` the
    share of the force energy in the loudest 1 % of the samples (:func:`classify_records`); ``decay_db`` how
    far the response decayed by the end of the impact segments (NaN for Welch); ``window``
    a description of the windows; ``notes`` lines for the user (choices made, low coherence).
    """

    frf: ImpedanceFRF
    method: str
    n_segments: int
    segment_samples: int
    energy_share: float
    decay_db: float
    window: str
    notes: tuple[str, ...] = ()

    @property
    def status(self) -> EstimateStatus:
        """:class:`EstimateStatus`: ``OK``, or ``NOTES`` when :attr:`notes` has lines for the
        user (still a usable estimate)."""
        return EstimateStatus.NOTES if self.notes else EstimateStatus.OK

    @property
    def ok(self) -> bool:
        """Always true: an estimate that cannot be made raises instead."""
        return True

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, method, segments, energy share, decay (``None``
        for Welch), window, frequency count and notes."""
        f = np.asarray(self.frf.freq_hz)
        return {"method": self.method, "n_segments": int(self.n_segments),
                "segment_samples": int(self.segment_samples),
                "energy_share": float(self.energy_share),
                "decay_db": None if not np.isfinite(self.decay_db) else float(self.decay_db),
                "window": self.window, "n_freq": int(f.size), "notes": list(self.notes),
                "status": self.status.value, "ok": self.ok}  # fmt: skip


ESTIMATES = ("auto", "impact", "welch")


def _choose(ts: TimeSeries, estimate: str) -> tuple[str, float]:
    kind, frac = classify_records(ts.force)
    if estimate != "auto":
        return estimate, frac
    if kind == "unclear":
        raise EstimateUndecided(
            f"cannot tell impact records from stationary ones: the loudest 1 % of the samples "
            f"hold {100 * frac:.0f} % of the force energy (impacts: > {100 * IMPULSIVE_SHARE:g} %, "
            f"stationary: < {100 * STATIONARY_SHARE:g} %); choose --estimate impact (one "
            "unwindowed segment per impact) or --estimate welch (Hann segments of --nperseg)"
        )
    return ("impact" if kind == "impact" else "welch"), frac


def estimate_impedance(
    ts: TimeSeries,
    *,
    estimate: str = "auto",
    nperseg: int | None = None,
    response: str = "displacement",
    sign: float = 1.0,
    f_min_hz: float | None = None,
    f_max_hz: float | None = None,
    window: str = "hann",
    force_window_s: float | None = None,
    exp_tau_s: float | None = None,
) -> ImpedanceEstimate:
    """Dynamic stiffness ``Z = sign · F/x`` ``(N, n, n)`` with element std and coherence.

    ``estimate``: ``"auto"`` (impact records → ``"impact"``, stationary ones → ``"welch"``;
    raises :class:`EstimateUndecided` naming the options when the records are neither, or when
    impact responses have not decayed by :data:`DECAY_MIN_DB` at the segment end and no
    exponential window is given), ``"impact"`` (one unwindowed segment per impact; optional
    ``force_window_s`` and ``exp_tau_s`` windows, see :mod:`._transient`) or ``"welch"``
    (``window`` ``"hann"`` — scipy's periodic Hann, 50 % overlap — or ``"boxcar"``, segments of
    ``nperseg`` samples, default :data:`NPERSEG`). ``response``, ``sign``, the band: as
    :func:`estimate_impedance_h1`. Frequencies are the segment's rFFT bins in
    ``[f_min_hz, f_max_hz]`` (default all but DC, up to fs/2). Raises ``ValueError`` naming the
    problem.
    """
    if response not in RESPONSE_KINDS:
        raise ValueError(f"response must be one of {tuple(RESPONSE_KINDS)}, got {response!r}")
    if sign not in (1, -1, 1.0, -1.0):
        raise ValueError(f"sign must be +1 or -1, got {sign}")
    if estimate not in ESTIMATES:
        raise ValueError(f"estimate must be one of {ESTIMATES}, got {estimate!r}")
    validate_timeseries(ts)
    for name, v in (("force_window_s", force_window_s), ("exp_tau_s", exp_tau_s)):
        if v is not None and not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive number of seconds, got {v}")
    zero = [e for e in range(ts.force.shape[0]) if not np.any(ts.force[e])]
    if zero:
        raise ValueError(f"the force of record {zero[0]} is zero everywhere: nothing excites Z")
    zero = [e for e in range(ts.response.shape[0]) if not np.any(ts.response[e])]
    if zero:
        raise ValueError(
            f"the response of record {zero[0]} is zero everywhere: Z = F/x is undefined"
        )
    lo = 0.0 if f_min_hz is None else float(f_min_hz)
    hi = ts.fs_hz / 2 if f_max_hz is None else min(float(f_max_hz), ts.fs_hz / 2)
    if not lo < hi:
        raise ValueError(f"empty band {lo:g}–{hi:g} Hz")
    for name, v in (("force_window_s", force_window_s), ("exp_tau_s", exp_tau_s)):
        if v is not None and v * ts.fs_hz < WINDOW_MIN_SAMPLES:
            raise ValueError(
                f"{name} {v:g} s is shorter than {WINDOW_MIN_SAMPLES} samples at {ts.fs_hz:g} Hz"
            )
    method, frac = _choose(ts, estimate)
    notes: list[str] = []
    if f_max_hz is not None and f_max_hz > ts.fs_hz / 2:
        notes.append(f"f_max_hz {f_max_hz:g} is above the Nyquist frequency: the FRF ends at "
                     f"fs/2 = {ts.fs_hz / 2:g} Hz")  # fmt: skip
    F, Y = np.asarray(ts.force, np.float64), np.asarray(ts.response, np.float64)
    decay = float("nan")
    if method == "impact":
        if window != "hann" or nperseg is not None:
            notes.append("--nperseg/--window are for --estimate welch; impact records use one "
                         "unwindowed segment per impact")  # fmt: skip
        Fs, Ys, seg_notes = impact_segments(F, Y, ts.fs_hz)
        notes.extend(seg_notes)
        Fs, Ys = apply_windows(Fs, Ys, ts.fs_hz, force_window_s=force_window_s,
                               exp_tau_s=exp_tau_s)  # fmt: skip
        decay = decay_db(Ys)
        if decay < DECAY_MIN_DB and exp_tau_s is None:
            tau = Fs.shape[1] / ts.fs_hz / 4
            msg = (f"the response has decayed only {decay:.1f} dB by the end of the "
                   f"{Fs.shape[1]}-sample impact segments: an unwindowed segment leaks; give "
                   f"--exp-tau {tau:.3g} (exponential window, e^-4 at the segment end; hapid fit "
                   "corrects the damping it adds) or longer records")  # fmt: skip
            if estimate == "auto":
                raise EstimateUndecided(msg + ", or --estimate impact to accept the leakage")
            notes.append(msg)
        L = Fs.shape[1]
        seg_F, seg_Y = Fs, Ys
        win = "rectangular (one segment per impact)"
        if force_window_s is not None:
            win += f", force window {force_window_s:g} s"
        if exp_tau_s is not None:
            win += f", exponential τ = {exp_tau_s:g} s"
        n_seg = Fs.shape[0]
        wname = "boxcar"
    else:
        if force_window_s is not None or exp_tau_s is not None:
            raise ValueError("--force-window/--exp-tau are for impact records (--estimate impact)")
        L = NPERSEG if nperseg is None else int(nperseg)
        if L > F.shape[1]:
            raise ValueError(f"nperseg {L} is longer than the records ({F.shape[1]} samples)")
        seg_F, seg_Y, wname = F, Y, window
        n_seg = F.shape[0] * len(segment_starts(F.shape[1], L, window))
        win = {"hann": "scipy periodic Hann, 50 % overlap", "boxcar": "rectangular, no overlap"}[
            window
        ]
    fgrid = np.fft.rfftfreq(L, 1.0 / ts.fs_hz)
    if not np.any(band_mask(fgrid, lo, hi) & (fgrid > 0)):
        raise ValueError(f"no frequency bin in {lo:g}–{hi:g} Hz (spacing {ts.fs_hz / L:g} Hz)")
    R = -float(sign) * seg_F
    frf = estimate_frf_h1(ts.fs_hz, R, R, seg_Y, nperseg=L, f_band_hz=(lo, hi),
                          reference="R_A", window=wname)  # fmt: skip
    if frf.omega.shape[0] == 0:
        raise ValueError(f"no frequency bin in {lo:g}–{hi:g} Hz (spacing {ts.fs_hz / L:g} Hz)")
    k = RESPONSE_KINDS[response]
    w = np.asarray(frf.omega)
    # the windowed response is the windowed system's: a velocity or acceleration response
    # converts with (jω + 1/τ)^k, so that Z is exactly Z(jω + 1/τ)
    s = 1j * w + (0.0 if exp_tau_s is None else 1.0 / exp_tau_s)
    Z = np.asarray(frf.Z_T) * s[:, None, None] ** k
    std = np.asarray(frf.Z_T_std) * (np.abs(s)[:, None, None] ** k)
    coh = None
    if n_seg <= ts.n:
        std = None
        notes.append(f"no std and no coherence from {n_seg} segment(s) for n = {ts.n} "
                     "channel(s): give more records or impacts")  # fmt: skip
    else:
        XF = segment_spectra(seg_F, L, wname).reshape(-1, L // 2 + 1, ts.n)
        XY = segment_spectra(seg_Y, L, wname).reshape(-1, L // 2 + 1, ts.n)
        idx = np.nonzero(band_mask(fgrid, lo, hi) & (fgrid > 0))[0]
        coh = coherence(XF[:, idx], XY[:, idx])
    z = as_impedance_frf(w / (2 * np.pi), Z, std, unit=ts.z_unit, coherence=coh,
                         exp_tau_s=0.0 if exp_tau_s is None else exp_tau_s)  # fmt: skip
    if coh is not None and (low := low_coherence_note(np.asarray(z.freq_hz), coh)):
        notes.append(low)
    return ImpedanceEstimate(z, method, n_seg, L, frac, decay, win, tuple(notes))


def estimate_impedance_h1(
    ts: TimeSeries,
    *,
    nperseg: int = 2048,
    response: str = "displacement",
    sign: float = 1.0,
    f_min_hz: float | None = None,
    f_max_hz: float | None = None,
    window: str = "hann",
) -> ImpedanceFRF:
    """Dynamic stiffness ``Z = sign · F/x`` ``(N, n, n)`` with element std, by Welch
    averaging (no impact detection; :func:`estimate_impedance` decides).

    ``response``: ``"displacement"`` | ``"velocity"`` | ``"acceleration"`` (what the response
    channels measure); ``sign`` ``+1`` (force on the structure and displacement counted in the
    same direction: a spring has Z = +k) or ``-1`` (reaction-force convention, the paper's
    ``R = −Z L``). Frequencies are the Welch bins (``fs/nperseg`` spacing) in
    ``[f_min_hz, f_max_hz]`` (default all but DC). The unit is ``ts.z_unit``. ``window``
    ``"hann"`` (default; scipy's periodic Hann) or ``"boxcar"`` (leakage-free, hence exact
    without noise, for periodic excitation whose period divides ``nperseg``).
    """
    return estimate_impedance(
        ts, estimate="welch", nperseg=nperseg, response=response, sign=sign,
        f_min_hz=f_min_hz, f_max_hz=f_max_hz, window=window,
    ).frf  # fmt: skip


__all__ = [
    "TimeSeries",
    "estimate_impedance",
    "ImpedanceEstimate",
    "EstimateUndecided",
    "estimate_impedance_h1",
    "validate_timeseries",
    "RESPONSE_KINDS",
    "ImpedanceFRF",
]
