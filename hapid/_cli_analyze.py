"""``hapid analyze``: the closed loop of a model's controller on a device's true plant or a
measured FRF (stability first, then bandwidth and margins). Library imports stay inside the
command (start-up time)."""

from __future__ import annotations

import numpy as np

from ._analyze_check import loop_check, loop_label, margin_words
from ._cli_device import device_from_args
from ._cli_errors import CLIError
from ._cli_verdict import check_line
from .defaults import CONTINUOUS_BAND_HZ

FEW_FRF_FREQUENCIES = 200  # an FRF with fewer points may leave the Nyquist count unresolved


def cmd_analyze(a):

    from . import io, pipeline, scene  # local: CLI start-up (hapid.fit, optimistix)
    from .control import max_siso_gain  # local: CLI start-up (hapid.io, equinox)

    model = io.load_model(a.model)
    cfg = scene.merge({})
    note = ""
    if a.design:
        from .tune import load_design  # local: CLI start-up (hapid.tune, ~0.8 s)

        g, _ = load_design(a.design)  # --k with --design: refused by hapid._cli_checks
    else:
        g = scene.compensator(cfg["controller"] | ({"k": a.k} if a.k is not None else {}))
    if a.frf:
        frf = io.load_frf(a.frf)
        ts = None if a.continuous else 1.0 / a.fs
        plant = pipeline.frf_plant(frf, ts)
        if ts is not None and float(np.max(frf.freq_hz)) > 0.5 * a.fs:
            raise CLIError(f"{a.frf} extends to {float(np.max(frf.freq_hz)):g} Hz, beyond the sampled "
                           f"controller's Nyquist frequency fs/2 = {0.5 * a.fs:g} Hz (--fs {a.fs:g}); "
                           "give the FRF's real sampling rate with --fs, or use --continuous")  # fmt: skip
        f_hz = np.asarray(frf.freq_hz, dtype=float)
        note = (f"note: the measured FRF has {f_hz.size} frequencies, {f_hz[0]:g}–{f_hz[-1]:g} Hz: "
                "the Nyquist count runs over that band only; margins and bandwidth are read on the "
                "FRF grid")  # fmt: skip
        if f_hz.size < FEW_FRF_FREQUENCIES:
            note += " (few frequencies: the count needs a dense grid and may be unresolved)"
    else:
        dev = device_from_args(a)
        if dev.n != model.n:
            raise CLIError(f"model has n = {model.n} rods but device {a.device} has {dev.n}")
        if a.continuous:
            omega = pipeline.analysis_grid(CONTINUOUS_BAND_HZ[0], int(cfg["analysis"]["n_freq"]),
                                           f_max_hz=CONTINUOUS_BAND_HZ[1])  # fmt: skip
        else:
            omega = scene.analysis_grid(cfg["analysis"], dev.fs_hz)
        plant = pipeline.device_plant(dev, omega, continuous=a.continuous)
        ts = None if a.continuous else dev.ts
    if plant.n != model.n:
        raise CLIError(f"model has n = {model.n} rods but the plant has {plant.n}")
    c = None
    if a.controller == "mimo":
        ctrl = pipeline.controller(model, g, ts=ts)
    else:
        if a.siso_gain is None:
            gs = pipeline.controller(None, g, kind="siso", n=model.n, ts=ts)
            gd = np.asarray(gs.response(plant.omega))[:, 0, 0]
            c = float(max_siso_gain(np.asarray(plant.P), np.asarray(plant.omega), gd))
        else:
            c = a.siso_gain
        ctrl = pipeline.controller(None, g, kind="siso", c=c, n=model.n, ts=ts)
    rep = pipeline.loop(ctrl, plant)
    s = rep.numbers()
    out = {"controller": a.controller, "siso_gain": c, "continuous": bool(a.continuous),
           "design": a.design, "controller_rhp_poles": int(ctrl.p_rhp),
           "loop": loop_label(ts), **s}  # fmt: skip
    if a.gm_db is not None or a.pm_deg is not None:  # the requirement check, printed first
        band = top = None
        if a.frf:
            band = (float(frf.freq_hz[0]), float(frf.freq_hz[-1]))
            w = np.asarray(plant.omega)[-1:]
            L = np.asarray(plant.P)[-1:] @ np.asarray(ctrl.response(w))
            top = float(np.linalg.svd(L, compute_uv=False)[0, 0])
        ck = loop_check(s, gm_db=6.0 if a.gm_db is None else a.gm_db,
                        pm_deg=30.0 if a.pm_deg is None else a.pm_deg, ts=ts,
                        frf_band_hz=band, top_loop_gain=top)  # fmt: skip
        out |= {"verdict": ck.verdict.value, "reason": ck.reason, "remedy": ck.remedy,
                "check": ck.name}  # fmt: skip
        print(check_line(ck))
    if note:
        print(note)
    if a.out:
        io.save_json(a.out, out)
    verdict = (
        "STABLE"
        if s["stable"]
        else ("UNSTABLE" if s.get("nyquist_resolved", True) else "UNDECIDED (grid too coarse)")
    )
    kind = f"sampled at {1 / ts:g} Hz" if ts else "continuous-time"
    print(f"closed loop ({kind} controller): {verdict} (generalized Nyquist, {s['n_encirclements']} "
          f"encirclements, {int(ctrl.p_rhp)} open-loop RHP pole(s) of the controller)")  # fmt: skip
    if s["stable"]:
        print(f"isotropic bandwidth {s['iso_bandwidth_hz']:.2f} Hz (paper-literal "
              f"{s['iso_bandwidth_literal_hz']:.2f} Hz); {margin_words(s['gm_db'], s['pm_deg'])}, "
              f"disk margin α {s['disk_margin']:.3f}; peak σ̄(T) {s['t_peak_db']:.1f} dB at "
              f"{s['t_peak_hz']:.1f} Hz")  # fmt: skip
    else:
        print("no bandwidth reported for a loop that is not stable")
    if c is not None:
        print(f"SISO gain c = {c:.4g}")
    if a.out:
        print(f"report → {a.out}")
