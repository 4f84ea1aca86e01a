"""The lab-data branch of ``hapid frf``: time series (force, response) → a single impedance
FRF file, with the estimate chosen to fit the records (impact or Welch) and the coherence."""

from __future__ import annotations

import warnings

import numpy as np

from . import io
from .experiment import estimate_impedance


def lab_estimate(a):
    """``(estimate, time series)``: the H1 estimate (:class:`hapid.experiment` impedance
    estimate: ``frf``, ``method``, ``n_segments``…) ``hapid frf`` makes of the lab records
    ``a.run`` (and ``a.add``) with the options ``a`` of its parser. Raises ``ValueError``
    naming the file."""
    ts = io.load_timeseries([a.run, *(a.add or [])], fs_hz=a.fs_hz, force_key=a.force_key,
                            response_key=a.response_key, force_unit=a.force_unit,
                            length_unit=a.length_unit)  # fmt: skip
    if a.nperseg is not None and a.nperseg > ts.force.shape[1]:
        raise ValueError(
            f"--nperseg {a.nperseg} is longer than the records ({ts.force.shape[1]} samples)"
        )
    try:
        est = estimate_impedance(ts, estimate=a.estimate, nperseg=a.nperseg,
                                 response=a.response, sign=-1.0 if a.sign == "-" else 1.0,
                                 f_min_hz=a.f_min_hz, f_max_hz=a.f_max_hz, window=a.window,
                                 force_window_s=a.force_window, exp_tau_s=a.exp_tau)  # fmt: skip
    except ValueError as e:
        raise ValueError(f"{a.run}: {e}") from None
    return est, ts


def lab_frf(a):
    """``(impedance FRF, time series)`` of :func:`lab_estimate`."""
    est, ts = lab_estimate(a)
    return est.frf, ts


def run_frf_lab(a) -> None:
    """``hapid frf`` on lab records: impact or Welch H1 → impedance FRF file (and ``--plot``)."""
    est, ts = lab_estimate(a)
    z = est.frf
    out = io.save_impedance_frf(a.out, z)
    E, T, n = ts.force.shape
    conv = {"displacement": "Z = F/x", "velocity": "Z = jω·F/v", "acceleration": "Z = (jω)²·F/a"}
    f = np.asarray(z.freq_hz)
    how = "one segment per impact" if est.method == "impact" else "Welch"
    std = "no std (one segment)"
    if z.Z_std is not None:
        rel = np.asarray(z.Z_std) / np.maximum(np.abs(np.asarray(z.Z)), 1e-300)
        std = f"median relative std of Z {np.median(rel):.2e}"
    coh = ""
    if z.coherence is not None:
        coh = f", median coherence γ² {np.median(np.asarray(z.coherence)):.3f}"
    print(f"impedance FRF (single impedance, {'+' if a.sign != '-' else '−'}{conv[a.response]}, "
          f"unit {z.unit}): H1, {how}: {est.n_segments} segments of {est.segment_samples} "
          f"samples, {est.window} ({E} record{'s' if E > 1 else ''} × {T} samples at "
          f"{ts.fs_hz:g} Hz, n = {n}; loudest 1 % of samples: "
          f"{100 * est.energy_share:.0f} % of the force energy); {f.size} frequencies "
          f"{f.min():g}–{f.max():g} Hz; {std}{coh} → {out}")  # fmt: skip
    if z.exp_tau_s:
        print(f"note: exponential window τ = {z.exp_tau_s:g} s: the stored Z is Z(jω + 1/τ) "
              "(every pole moved left by 1/τ, modal ζ raised by 1/(τ ω_n)); hapid fit corrects "
              "M, B, K for it, the FRF is not corrected")  # fmt: skip
    for note in est.notes:
        if note.startswith("low coherence"):
            warnings.warn(note + " (noise, leakage or nonlinearity there)", stacklevel=1)
        else:
            print(f"note: {note}")
    if a.plot:
        from . import plot  # local: CLI start-up (matplotlib)

        fig, _ = plot.impedance_h1(f, np.asarray(z.Z), z.coherence, unit=z.unit,
                                   title=f"{a.run}: H1 ({how})")  # fmt: skip
        plot.save(fig, a.plot)
        print(f"figure → {a.plot}")


def register_lab_frf_args(f) -> None:
    """``hapid frf`` options for non-periodic records and lab time series."""
    lab = f.add_argument_group("non-periodic records and lab time series (H1)")
    lab.add_argument("--h1", action="store_true",
                     help="H1 estimate (implied for a time series)")  # fmt: skip
    lab.add_argument("--estimate", choices=["auto", "impact", "welch"], default="auto",
                     help="lab records: auto (default: impact records → one unwindowed segment "
                     "per impact, stationary records → Welch), impact, or welch")  # fmt: skip
    lab.add_argument("--nperseg", type=int, default=None,
                     help="samples per Welch segment (default 2048; impact records use one "
                     "segment per impact)")  # fmt: skip
    lab.add_argument("--window", choices=["hann", "boxcar"], default="hann",
                     help="Welch segment window: hann (default; scipy's periodic Hann) or boxcar "
                     "(periodic excitation whose period divides --nperseg: leakage-free)")  # fmt: skip
    lab.add_argument("--force-window", type=float, metavar="S", help="impact records: keep "
                     "the force for S seconds after each impact, zero after (default: off)")  # fmt: skip
    lab.add_argument("--exp-tau", type=float, metavar="S", help="impact records: exponential "
                     "window e^(-t/S) on force and response (default: off); hapid fit corrects "
                     "the damping it adds")  # fmt: skip
    lab.add_argument("--response", choices=["displacement", "velocity", "acceleration"],
                     default="displacement", help="what the response channels measure; Z = F/x "
                     "is formed in the frequency domain (default displacement)")  # fmt: skip
    lab.add_argument("--sign", choices=["+", "-"], default="+", help="+: Z = +F/x (force on the "
                     "structure, displacement the same way; default); -: reaction force, Z = -F/x")  # fmt: skip
    lab.add_argument("--fs-hz", type=float, help="sampling rate in Hz, if the file has no fs_hz")
    lab.add_argument("--force-key", default="force",
                     help="array holding the forces (default force)")  # fmt: skip
    lab.add_argument("--response-key", default="response",
                     help="array holding the responses (default response)")  # fmt: skip
    lab.add_argument("--add", action="append", metavar="FILE", help="another record file: more "
                     "experiments (same length and channels); repeat as needed")  # fmt: skip
    lab.add_argument("--force-unit", help="unit of the forces (default: the file's, else N)")
    lab.add_argument("--length-unit", help="unit of the displacement (default: the file's, else m)")
    lab.add_argument("--f-min-hz", type=float, help="lowest frequency kept (Hz; default above DC)")
    lab.add_argument("--f-max-hz", type=float, help="highest frequency kept (Hz; default fs/2)")


def _cell(x: float, sd: float | None) -> str:
    return f"{x:+.4g}" if sd is None else f"{x:+.4g} ± {sd:.2g}"


def matrices_report(
    model, std, units: dict, *, label: str = "", std_note: bool = True
) -> list[str]:
    """Lines showing the fitted ``M, B, K`` with their std (``std``: a ``SecondOrder`` or
    ``None``): every entry for n ≤ 3; for larger n the eigenvalues of the symmetric part and
    the diagonal ± std. For n = 1 also the natural frequency and damping ratio. ``label``
    prefixes each matrix name (e.g. ``"hand "``); ``std_note``: say when std are missing."""
    out = []
    n = int(np.shape(model.M)[0])
    for k in "MBK":
        A = np.asarray(getattr(model, k), dtype=np.float64)
        S = None if std is None else np.asarray(getattr(std, k), dtype=np.float64)
        head = f"{label}{k} [{units[k]}]"
        if n <= 3:
            cells = [[_cell(A[i, j], None if S is None else S[i, j]) for j in range(n)]
                     for i in range(n)]  # fmt: skip
            w = max(len(c) for row in cells for c in row)
            rows = ["  ".join(c.ljust(w) for c in row).rstrip() for row in cells]
            out.append(f"{head}: {rows[0]}")
            pad = " " * (len(head) + 2)
            out += [pad + r for r in rows[1:]]
        else:
            lam = np.linalg.eigvalsh(0.5 * (A + A.T))
            diag = ", ".join(_cell(A[i, i], None if S is None else S[i, i]) for i in range(n))
            out.append(f"{head}: eigenvalues {', '.join(f'{x:.4g}' for x in lam)}; diagonal {diag}")
    if n == 1:
        m, b, k = (float(np.asarray(getattr(model, x))[0, 0]) for x in "MBK")
        if m > 0 and k > 0:
            fn = np.sqrt(k / m) / (2 * np.pi)
            out.append(f"one mode: f_n = √(K/M)/2π = {fn:.5g} Hz, ζ = B/(2√(KM)) = "
                       f"{b / (2 * np.sqrt(k * m)):.3g}")  # fmt: skip
    if std is None and std_note:
        out.append("std: not available for this method (--method nls gives them)")
    return out
