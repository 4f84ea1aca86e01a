"""A single measured impedance from lab time series: force and response records → ``Z = F/x``.

``TimeSeries``: sampling rate ``fs_hz`` and records ``force``, ``response`` ``(E, T, n)``
(``E`` experiments of ``T`` samples on ``n`` channels; a single record is ``E = 1``). The
response is a displacement, velocity or acceleration of the same (collocated) points the
forces act on.

``estimate_impedance_h1``: the H1 estimator over Welch segments (Hann, 50 % overlap) with the
force as reference — ``H = S_xF S_FF⁻¹`` (response over force, noise on the response), turned
into dynamic stiffness ``Z = H⁻¹`` — by :func:`hapid.experiment.estimate_frf_h1` with the
force as instrument (``Z = S_FF S_xF⁻¹``). A velocity or acceleration response is converted
in the frequency domain: ``x = v/(jω) = a/(jω)²``, so ``Z = (jω)^k · F/response`` (k = 1, 2).
Std per element from the segment-to-segment scatter of the equation error (segments treated
as independent, which is optimistic with overlap). With ``E`` experiments the n × n estimate
needs the forces of the experiments to span n directions at each frequency (one chirp on all
channels in phase excites only one).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..impedance_frf import ImpedanceFRF, as_impedance_frf
from ._estimate import estimate_frf_h1

RESPONSE_KINDS = {"displacement": 0, "velocity": 1, "acceleration": 2}


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
    """Dynamic stiffness ``Z = sign · F/x`` ``(N, n, n)`` with element std from lab records.

    ``response``: ``"displacement"`` | ``"velocity"`` | ``"acceleration"`` (what the response
    channels measure); ``sign`` ``+1`` (force on the structure and displacement counted in the
    same direction: a spring has Z = +k) or ``-1`` (reaction-force convention, the paper's
    ``R = −Z L``). Frequencies are the Welch bins (``fs/nperseg`` spacing) in
    ``[f_min_hz, f_max_hz]`` (default all but DC). The unit is ``ts.z_unit``. ``window``
    ``"hann"`` (default) or ``"boxcar"`` (leakage-free, hence exact without noise, for periodic
    excitation whose period divides ``nperseg``).
    """
    if response not in RESPONSE_KINDS:
        raise ValueError(f"response must be one of {tuple(RESPONSE_KINDS)}, got {response!r}")
    if sign not in (1, -1, 1.0, -1.0):
        raise ValueError(f"sign must be +1 or -1, got {sign}")
    validate_timeseries(ts)
    lo = 0.0 if f_min_hz is None else float(f_min_hz)
    hi = ts.fs_hz / 2 if f_max_hz is None else float(f_max_hz)
    if not lo < hi:
        raise ValueError(f"empty band {lo:g}–{hi:g} Hz")
    R = -float(sign) * np.asarray(ts.force, dtype=np.float64)
    frf = estimate_frf_h1(
        ts.fs_hz, R, R, np.asarray(ts.response, dtype=np.float64),
        nperseg=nperseg, f_band_hz=(lo, hi), reference="R_A", window=window,
    )  # fmt: skip
    if frf.omega.shape[0] == 0:
        raise ValueError(
            f"no Welch frequency bin in {lo:g}–{hi:g} Hz (spacing {ts.fs_hz / nperseg:g} Hz)"
        )
    k = RESPONSE_KINDS[response]
    w = np.asarray(frf.omega)
    jw = (1j * w)[:, None, None] ** k
    Z = np.asarray(frf.Z_T) * jw
    std = np.asarray(frf.Z_T_std) * (w[:, None, None] ** k)
    return as_impedance_frf(w / (2 * np.pi), Z, std, unit=ts.z_unit)


__all__ = [
    "TimeSeries",
    "estimate_impedance_h1",
    "validate_timeseries",
    "RESPONSE_KINDS",
    "ImpedanceFRF",
]
