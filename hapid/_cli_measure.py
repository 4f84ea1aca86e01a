"""The measurement commands of ``hapid``: ``simulate`` (a run file from a simulated device),
``frf`` (impedances from a run file or lab time series), ``demo``, and ``fit`` (the shell over
:mod:`hapid._cli_fit`). Library imports stay inside the commands (start-up time)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ._cli_device import describe, device_from_args
from ._cli_errors import CLIError
from .defaults import NPERSEG


def _protocol(a):
    from .experiment import Protocol, paper_frequencies  # local: CLI start-up (hapid.io, equinox)

    freqs = paper_frequencies() if a.freqs == "paper" else [float(x) for x in a.freqs.split(",")]
    return Protocol(
        freq_hz=tuple(freqs), fs_hz=a.fs, period_samples=a.period, n_periods=a.periods,
        transient_periods=a.transient, pattern=a.pattern, amplitude=a.amplitude,
        phases=a.phases, seed=a.seed, force_noise=a.noise, position_noise=a.position_noise,
        encoder_resolution=a.encoder_res,
    )  # fmt: skip


def cmd_simulate(a):
    from . import io  # local: CLI start-up (hapid.io, equinox)
    from .experiment import periodic_run, time_domain_run  # local: CLI start-up (hapid.io, equinox)

    dev, prot = device_from_args(a, fs_hz=a.fs), _protocol(a)
    if a.time_domain or a.friction:
        run = time_domain_run(dev, prot, friction=a.friction)
        how = "time-domain" + (" with Coulomb friction" if a.friction else "")
    else:
        run = periodic_run(dev, prot)
        how = "periodic steady state"
    out = io.save_run(a.out, run)
    E, T, n = run.R_A.shape
    print(f"simulated {describe(a)} ({how}): E={E} experiments × {T} samples × n={n} rods, "
          f"{len(run.freq_hz)} frequencies {run.freq_hz.min():g}–{run.freq_hz.max():g} Hz → {out}")  # fmt: skip


def _run_frf(a, run, estimate_frf, estimate_frf_h1):
    """The haptic pair from a run file: periodic estimate, or H1 with ``--h1``."""
    if a.h1:
        frf = estimate_frf_h1(run.fs_hz, run.R_A, run.R_I, run.L, nperseg=a.nperseg or NPERSEG,
                              f_band_hz=(a.f_min_hz or 0.0, a.f_max_hz or run.fs_hz / 2),
                              window=a.window)  # fmt: skip
    else:
        frf = estimate_frf(run, cond_warn=a.cond_warn)
    return frf


def cmd_frf(a):
    from . import io  # local: CLI start-up (hapid.io, equinox)
    from .experiment import estimate_frf, estimate_frf_h1, low_coherence_note  # local: CLI start-up

    kind = (
        "timeseries"
        if a.add or a.force_key != "force"
        else io.file_kind(a.run, "a run file or a time-series file")
    )
    if kind in ("timeseries", "unknown"):  # unknown: the reader names the arrays it found
        from ._cli_lab import run_frf_lab  # local: CLI start-up (hapid.io, equinox)

        return run_frf_lab(a)  # lab records → single impedance Z = F/x
    if kind != "run":
        raise CLIError(f"{a.run}: holds a {kind} file; hapid frf takes a run file (R_A, R_I, L) "
                       "or a time series (fs_hz, force, response)")  # fmt: skip
    run = io.load_run(a.run)
    if a.h1 and a.f_max_hz is not None and a.f_max_hz > run.fs_hz / 2:
        print(f"note: --f-max-hz {a.f_max_hz:g} is above the Nyquist frequency: the FRF ends at "
              f"fs/2 = {run.fs_hz / 2:g} Hz")  # fmt: skip
    for opt, v in (
        ("--estimate", a.estimate != "auto"),
        ("--force-window", a.force_window),
        ("--exp-tau", a.exp_tau),
    ):
        if v:
            raise CLIError(f"{opt} is for lab time series (force, response); {a.run} is a run file")
    try:
        frf = _run_frf(a, run, estimate_frf, estimate_frf_h1)
    except ValueError as e:
        raise CLIError(f"{a.run}: {e}") from None
    out = io.save_frf(a.out, frf)
    rel = np.asarray(frf.Z_H_std) / np.abs(np.asarray(frf.Z_H)) if frf.Z_H_std is not None else None
    print(f"FRF (haptic pair Z_H, Z_T in N/m{', H1' if a.h1 else ''}): {frf.Z_H.shape[0]} "
          f"frequencies, n={frf.n}; cond(𝓛) "
          f"{float(np.min(frf.cond_L)):.3g}–{float(np.max(frf.cond_L)):.3g}" +
          (f"; median relative std of Z_H {np.median(rel):.2e}" if rel is not None else "") +
          f" → {out}")  # fmt: skip
    if a.h1 and frf.coherence_H is None:
        print("note: no coherence: no more Welch segments (over all experiments) than rods, "
              "where γ² is identically 1; give longer records or a smaller --nperseg")  # fmt: skip
    elif a.h1:
        f = np.asarray(frf.freq_hz)
        for name, g, sig in (("Z_H", frf.coherence_H, "R_I"), ("Z_T", frf.coherence_T, "R_A")):
            g = np.asarray(g)
            print(f"coherence γ² of {name} ({sig} on L): median {np.median(g):.3f}, "
                  f"min {g.min():.3f}")  # fmt: skip
            if low := low_coherence_note(f, g):
                warnings.warn(f"{name}: {low} (noise, leakage or nonlinearity there)",
                              stacklevel=1)  # fmt: skip
    if a.plot:
        from . import plot  # local: CLI start-up (matplotlib)

        fig, _ = plot.frf_overview(frf)
        plot.save(fig, a.plot)
        print(f"figure → {a.plot}")


def cmd_demo(a):
    from . import io, plot  # local: CLI start-up (matplotlib)
    from .experiment import Protocol, estimate_frf, periodic_run  # local: CLI start-up (hapid.io)
    from .impedance import span_db  # local: CLI start-up (hapid.io, equinox)

    out = Path(a.out)
    dev = device_from_args(a)
    run = periodic_run(dev, Protocol())
    frf = estimate_frf(run)
    io.save_run(out / "run.npz", run)
    io.save_frf(out / "frf.npz", frf)
    fig, _ = plot.frf_overview(frf, title_prefix=f"{describe(a)}: ")
    plot.save(fig, out / "frf_singular_values.png")
    span = np.asarray(span_db(frf.P))
    f = np.asarray(frf.freq_hz)
    band = f <= 30
    print(f"{describe(a)}: plant singular-value span over {f[band].min():g}–{f[band].max():g} Hz: "
          f"{span[band].min():.1f}–{span[band].max():.1f} dB (paper: 25–50 dB)")  # fmt: skip
    print(f"wrote {out / 'run.npz'}, {out / 'frf.npz'}, {out / 'frf_singular_values.png'}")


def cmd_fit(a):
    from ._cli_fit import run_fit  # local: CLI start-up (hapid.fit, optimistix)

    run_fit(a)
