"""The commands of ``hapid`` that work over uncertainty: ``posterior`` (samples of M, B, K),
``robust`` (the margins of a nominal controller over draws) and ``tune`` (a robust g by
gradients). Library imports stay inside the commands (start-up time)."""

from __future__ import annotations

import math
import time
from pathlib import Path

from ._cli_errors import CLIError
from ._cli_kw import device_or_none, posterior_kw, robust_metrics, tune_kw, uncertified_warning
from ._cli_processes import _is_main
from ._cli_verdict import check_line, verdict_lines
from ._constants import ROBUST_EXPECTED_S
from .defaults import NLS_MAX_STEPS


def cmd_posterior(a):
    from .fit import FitFailedError  # local: CLI start-up (hapid.fit, optimistix)
    from .uncertainty import posterior_from_files  # local: CLI start-up (hapid.uncertainty, ~0.7 s)

    try:
        ps = posterior_from_files(a.frf, a.out, **posterior_kw(a))
    except FitFailedError as e:
        raise CLIError(f"{a.frf}: the NLS fit the posterior is built around did not converge "
                       f"({e}); no samples written: give more steps (--max-steps, default "
                       f"{NLS_MAX_STEPS}) or check the fit with hapid fit {a.frf} --method nls") from e  # fmt: skip
    eps = float(ps.diagnostics.get("fit_pd_eps", 0.0))
    if eps > 0:  # the same note and metadata as hapid fit (diag_fit_pd_eps in the file)
        print(f"note: fit refitted with pd_eps = {eps:g}: the PSD-boundary fit put a root of "
              "det Ẑ_H at ∞ or on the imaginary axis (--keep-boundary keeps that fit); the "
              "posterior is built around the refitted model, as hapid fit writes it")  # fmt: skip
    print(ps.report())
    print(f"samples → {a.out}")


def cmd_robust(a):
    if not _is_main():  # jax.distributed: compute this process's share, process 0 reports
        _robust_worker(a)
        return

    from .io import to_json  # local: CLI start-up (hapid.io, equinox)
    from .robust import robust_from_files, side_by_side  # local: CLI start-up (hapid.uncertainty)

    dev = device_or_none(a)
    from .tune._progress import TuneProgress  # local: CLI start-up (tqdm)

    say = TuneProgress(enabled=not a.quiet, expected_s=ROBUST_EXPECTED_S, command="robust").phase
    if len(a.model) == 1:
        res = robust_from_files(a.samples, a.model[0], a.out, progress=say, **_robust_kw(a, dev))
        for line in verdict_lines(res):
            print(line)
        print(to_json(res.numbers())[:4000])
        print(_draws_line(res.posterior.draws))
    else:
        res = {}
        for m in a.model:
            say(f"model {m}")
            res[Path(m).stem] = robust_from_files(a.samples, m, None, progress=say,
                                                  **_robust_kw(a, dev))  # fmt: skip
        for name, r in res.items():
            for line in verdict_lines(r):
                print(f"{name}: {line}")
        print(side_by_side(res))
        for name, r in res.items():
            print(f"{name}: {_draws_line(r.posterior.draws)}")
        if a.out:
            from .io import save_json  # local: CLI start-up (hapid.io, equinox)

            save_json(a.out, {name: r.numbers() for name, r in res.items()})
    if not a.all_metrics:
        print("disk margin and peak of σ̄(T): not computed (null; add --all-metrics)")
    if a.out:
        print(f"report → {a.out}")


def _robust_kw(a, dev) -> dict:
    """The options of ``hapid robust`` for :func:`hapid.robust.robust_from_files`
    (``dev``: the device of the ``--device`` options, or None)."""
    return {"frf_path": a.frf, "draws": a.draws, "gm_db": a.gm_db, "pm_deg": a.pm_deg,
            "max_samples": a.max_samples, "device": dev, "n_subjects": a.subjects,
            "metrics": robust_metrics(a), "ts": None if a.fs is None else 1.0 / a.fs,
            "n_freq": a.n_freq}  # fmt: skip


def _draws_line(d: dict) -> str:
    """One line saying which draws the posterior check used and what they cover."""
    if d["draws"] != "loop_gp":
        return "draws: " + d["note"]
    lo, hi = d["measured_hz"]
    return (f"draws: loop GP conditioned on the measured FRF {lo:g}–{hi:g} Hz "
            f"(ℓ = {d['ell']:.2g} in ln ω), {d['loop']}; loop gain above {hi:g} Hz ≤ "
            f"{d['beyond_loop_gain']:.3g} (covered by the draws only when ≤ 0.5: see the verdict)"
            + (f"; isotropic bandwidth {d['iso_bandwidth_nominal_hz']:.2f} Hz (measured-FRF-"
               f"conditioned loop), draws 5–95 % {d['iso_bandwidth_interval_hz'][0]:.2f}–"
               f"{d['iso_bandwidth_interval_hz'][1]:.2f} Hz"
               if d.get("iso_bandwidth_nominal_hz") and d.get("iso_bandwidth_interval_hz") else ""))  # fmt: skip


def _robust_worker(a):
    from .robust import robust_from_files  # local: CLI start-up (hapid.uncertainty, ~0.7 s)

    dev = device_or_none(a)
    for m in a.model:
        robust_from_files(a.samples, m, None, **_robust_kw(a, dev))


def no_bandwidth_note(table: dict, kept_start: bool = False) -> str:
    """A line when the returned g meets the margins only by barely acting: its held-out
    draws' median isotropic bandwidth is under a tenth of the start's (e.g. the certified
    fallback's gain scaled far down when no g with the start's static gain holds the
    margins). ``""`` otherwise."""
    if not table:
        return ""
    ret = table.get("returned") or table.get("start" if kept_start else "tuned") or {}
    bw, bw0 = (d.get("posterior_iso_bandwidth_hz_q50") for d in (ret, table.get("start", {})))
    if bw is None or bw0 is None or not math.isfinite(bw0) or not bw < 0.1 * bw0:
        return ""
    return (f"NOTE: the returned g meets the margins by barely acting — held-out median isotropic "
            f"bandwidth {bw:.2f} Hz against the start's {bw0:.2f} Hz (--free-dc lets the tuner "
            "trade the start's static gain for margin)")  # fmt: skip


def cmd_tune(a):

    from .tune import tune_from_files  # local: CLI start-up (hapid.tune, ~0.8 s)
    from .tune._progress import TuneProgress  # local: CLI start-up (hapid.tune, ~0.8 s)

    t = time.perf_counter()
    bar = TuneProgress(enabled=not a.quiet)
    try:
        res = tune_from_files(a.model, a.samples, a.out, **tune_kw(a), progress=bar)
    finally:
        bar.close()
    r = res.result
    if r.check is not None:  # the verdict first: passed / failed / not established, for which loop
        print(check_line(r.check))
    tab = res.table
    note = no_bandwidth_note(tab, res.kept_start)
    if note:
        print(note)
    print(res.decision.reason)
    print(f"tuned in {r.wall_s:.1f} s: claimed robust bandwidth {r.bandwidth0_hz:.2f} → {r.bandwidth_hz:.2f} Hz, "
          f"smooth constraints {'met' if r.feasible else 'NOT met'} on the training scenarios")  # fmt: skip
    if r.gain_backoff < 1.0:  # a gain back-off: the first sign of a collapse
        print(f"  the tuner started from g with its gain scaled by {r.gain_backoff:.3g}: at full gain it "
              "left more training loops unstable than the quantile allows (hapid.tune.gain_backoff)")  # fmt: skip
    for p in r.parameters():
        print(f"  {p['name']:16s} {p['start']:10.4g} → {p['tuned']:10.4g}")
    if tab:
        from ._cli_predict import recheck_table  # local: CLI start-up (hapid.io, equinox)

        print("non-smooth re-check (held-out samples / true plant / time domain):")
        print(recheck_table(tab["start"], tab["tuned"]))
        warn = uncertified_warning(res.returned_row)
        if warn:
            print(warn)
    if a.report:
        from .io import save_json  # local: CLI start-up (hapid.io, equinox)

        save_json(a.report, {"start": tab.get("start"), "tuned": tab.get("tuned"), "constraints": r.constraints,
                             "history": r.history, "parameters": r.parameters(), "loop": res.loop,
                             "returned": tab.get("returned"), "decision": res.decision.reason, "choice": res.decision.choice.value, "note": note,
                             "bandwidth_claimed_hz": r.bandwidth_hz, "tune_wall_s": r.wall_s}
                  | ({} if r.check is None else {"verdict": r.check.verdict.value, "reason": r.check.reason,
                                                 "remedy": r.check.remedy}))  # fmt: skip
    print(f"design → {a.out} ({time.perf_counter() - t:.1f} s)")
