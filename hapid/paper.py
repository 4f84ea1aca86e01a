"""The paper reproduction: figures 5–10 and the summary table, from scene stage results.

Figures are drawn by ``hapid.plot``; this module picks the data and writes the files.
``PAPER`` holds the numbers the paper reports, for the summary's first column.
"""

from __future__ import annotations

import dataclasses
import enum
from pathlib import Path

import numpy as np

from . import io
from ._constants import TWO_PI
from ._plain import jsonable
from .defaults import PPHAT_BAND_HZ
from .fit import FitStatus, anisotropy_reduction, pphat_band_db
from .impedance import span_db

PAPER = {
    "plant_span_db": "25–50",
    "pphat_band_db": "≈ ±7 (to 30 Hz)",
    "anisotropy_reduction": "8–140",
    "siso_iso_bandwidth_hz": "< 1",
    "mimo_iso_bandwidth_hz": "≈ 3",
    "mimo_gm_db": "≈ 5",
    "mimo_pm_deg": "≈ 20",
    "mimo_t_peak": "≈ 6 dB near 15 Hz",
}


def figure(num: int, out_dir, *deps) -> str:
    from . import plot  # local: CLI start-up (matplotlib)

    out = Path(out_dir) / f"fig{num}.png"
    if num == 5:
        (siso,) = deps
        fig, _ = plot.sigma_T_minus_I(
            {f"SISO, c = {v['c']:.3g}" + (f" ({k})" if not k.startswith("c=") else ""): v["report"]
             for k, v in siso.items() if v["report"] is not None},
            title="Fig. 5 — σ(T(jω) − I) under SISO control G = c·g(s)·I",
        )  # fmt: skip
    elif num in (6, 7):
        frf, wls, nls = deps
        which = "Z_H" if num == 6 else "Z_T"
        f = np.asarray(frf.freq_hz)
        fd = np.geomspace(f.min(), f.max(), 300)
        s = TWO_PI * 1j * fd
        pick = (lambda m: m.hand(s)) if num == 6 else (lambda m: m.total(s))  # noqa: E731
        fig, _ = plot.impedance_fit(
            f, np.asarray(getattr(frf, which)), fd,
            {"paper WLS + positize": np.asarray(pick(wls["model"])), "hapid NLS + PD": np.asarray(pick(nls["model"]))},
            title=f"Fig. {num} — singular values of {which} (measured, solid) and its models",
            name=which,
            Z_std=None if getattr(frf, which + "_std") is None else np.asarray(getattr(frf, which + "_std")),
        )  # fmt: skip
    elif num == 8:
        device, frf, wls, nls = deps
        P = np.asarray(device.sampled_P(frf.omega))
        f = np.asarray(frf.freq_hz)
        curves = {}
        for label, m in (("paper WLS + positize", wls["model"]), ("hapid NLS + PD", nls["model"])):
            curves[label] = P @ np.asarray(m.P_inv(1j * frf.omega))
        fig, _ = plot.pphat(
            f, curves, title="Fig. 8 — singular values of P·P̂⁻¹ (true sampled plant)"
        )
    elif num == 9:
        mimo, plant = deps
        fig, _ = plot.loci({"paper WLS + positize": mimo["wls"]["report"], "hapid NLS + PD": mimo["nls"]["report"]},
                           title="Fig. 9 — characteristic loci of P(z)G(z) (eigenvalues)")  # fmt: skip
    elif num == 10:
        mimo, *rest = deps
        reps = {
            "MIMO, paper WLS + positize": mimo["wls"]["report"],
            "MIMO, hapid NLS + PD": mimo["nls"]["report"],
        }
        if rest:  # the scene's tuned-g loop (the summary's third column)
            reps["MIMO, hapid NLS + PD + tuned g"] = rest[0]["report"]
        fig, _ = plot.sigma_T_minus_I(reps, title="Fig. 10 — σ(T(jω) − I), MIMO controller G = g(s) Ẑ_T Ẑ_H⁻¹")  # fmt: skip
    else:
        raise ValueError(f"no figure {num}")
    plot.save(fig, out)
    return str(out)


def _f(x):
    x = float(x)
    return None if not np.isfinite(x) else x


def _loop_numbers(rep) -> dict:
    """The table's numbers of a loop report (non-finite as ``None``); ``{"stable": False}``
    for a loop not closed (``rep`` ``None``)."""
    if rep is None:
        return {"stable": False}
    s = rep.numbers()
    keys = ("stable", "iso_bandwidth_hz", "iso_bandwidth_literal_hz", "gm_db", "gm_freq_hz",
            "pm_deg", "pm_freq_hz", "disk_margin", "disk_gm_db", "disk_pm_deg", "t_peak_db",
            "t_peak_hz", "nyquist_resolved")  # fmt: skip
    return {k: (s[k] if isinstance(s[k], bool) else _f(s[k])) for k in keys}


class PaperStatus(enum.StrEnum):
    """Outcome of the paper summary (:class:`PaperSummary`); ``ok`` means ``OK``: the NLS fit
    converged and every MIMO loop of the table (both fits, and the tuned g when present) is
    stable. ``FIT_NOT_CONVERGED`` is reported before ``UNSTABLE_LOOP``."""

    OK = "ok"
    FIT_NOT_CONVERGED = "fit not converged"
    UNSTABLE_LOOP = "unstable loop"


@dataclasses.dataclass(frozen=True)
class PaperSummary:
    """Result of :func:`summary`: the numbers of the summary table.

    - ``device``: ``n``, ``fs_hz`` (Hz), ``delay_samples``.
    - ``plant_span_db_1_30hz``: ``[min, max]`` (dB) of the true plant's singular-value span
      over the measured frequencies up to 30 Hz.
    - ``fits``: ``"wls"`` (paper WLS + positize) and ``"nls"`` (hapid NLS + PD) → ``label``,
      P·P̂⁻¹ bands to 30 Hz (dB) against the true and the measured plant, the anisotropy
      reduction ``[min, max]``, ``mimo`` (the loop's numbers: stability, bandwidths in Hz,
      margins in dB and deg, disk margin, peak of σ̄(T) in dB and its frequency in Hz;
      ``None`` where undefined); WLS: the CRHP root counts before and after positizing;
      NLS: its ``status``, ``steps`` and ``refit_pd_eps``.
    - ``siso``: ``"c=1"`` and ``"design rule"`` → the gain ``c`` and the loop's numbers.
    - ``tuned``: the tuned-g column (``label``, ``mimo``, ``g`` parameters, ``design_file``,
      the tuner's ``status`` and ``decision``), or ``None`` without the tuned stages.
    """

    device: dict
    plant_span_db_1_30hz: list
    fits: dict
    siso: dict
    tuned: dict | None = None

    @property
    def status(self) -> PaperStatus:
        if self.fits["nls"]["status"] != FitStatus.CONVERGED:
            return PaperStatus.FIT_NOT_CONVERGED
        loops = [self.fits[k]["mimo"] for k in ("wls", "nls")]
        loops += [] if self.tuned is None else [self.tuned["mimo"]]
        return PaperStatus.OK if all(m["stable"] for m in loops) else PaperStatus.UNSTABLE_LOOP

    @property
    def ok(self) -> bool:
        return self.status is PaperStatus.OK

    def numbers(self) -> dict:
        """The content of ``summary.json``: ``device``, ``plant_span_db_1_30hz``, ``fits``,
        ``siso`` and, with the tuned stages, ``tuned``."""
        out = {"device": self.device, "plant_span_db_1_30hz": self.plant_span_db_1_30hz,
               "fits": self.fits, "siso": self.siso}  # fmt: skip
        return out if self.tuned is None else out | {"tuned": self.tuned}

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, then :meth:`numbers`."""
        return jsonable({"status": self.status, "ok": self.ok} | self.numbers())

    def markdown(self) -> str:
        """``summary.md``: the table of the paper's numbers next to each fit's."""
        return _markdown(self.numbers())


def summary(
    out_dir, device, frf, wls, nls, mimo, siso, tuned=None, tuned_mimo=None
) -> PaperSummary:
    """The summary table from the scene's stage results (:class:`PaperSummary`), written to
    ``out_dir`` as ``summary.json`` (:meth:`PaperSummary.numbers`) and ``summary.md``
    (:meth:`PaperSummary.markdown`); ``tuned``/``tuned_mimo`` (the scene's tuned-g stages)
    fill the third column and write ``design_tuned.npz``."""
    w = frf.omega
    P_true = np.asarray(device.sampled_P(w))
    f = np.asarray(frf.freq_hz)
    band = f <= PPHAT_BAND_HZ
    span = np.asarray(span_db(P_true))
    dev = {"n": device.n, "fs_hz": device.fs_hz, "delay_samples": device.delay_samples}
    fits = {}
    for key, label, out in (("wls", "paper WLS + positize", wls), ("nls", "hapid NLS + PD", nls)):
        lo, hi = pphat_band_db(P_true, out["model"], w, PPHAT_BAND_HZ)
        rlo, rhi = anisotropy_reduction(P_true, out["model"], w, PPHAT_BAND_HZ)
        lom, him = pphat_band_db(np.asarray(frf.P), out["model"], w, PPHAT_BAND_HZ)
        entry = {
            "label": label,
            "pphat_band_db_to_30hz": [float(lo), float(hi)],
            "pphat_band_db_to_30hz_measured_P": [float(lom), float(him)],
            "anisotropy_reduction": [float(rlo), float(rhi)],
            "mimo": _loop_numbers(mimo[key]["report"]),
        }
        if key == "wls":
            entry["crhp_roots_before_positize"] = {
                "hand": wls["crhp_before"][0],
                "total": wls["crhp_before"][1],
            }
            entry["crhp_roots_after_positize"] = {
                "hand": wls["crhp_after"][0],
                "total": wls["crhp_after"][1],
            }
        else:
            entry["status"], entry["steps"] = nls["status"], nls["steps"]
            entry["refit_pd_eps"] = nls.get("refit_pd_eps")
        fits[key] = entry
    siso_rows = {k: {"c": _f(v["c"]), **_loop_numbers(v["report"])} for k, v in siso.items()}
    # third column: the same NLS + PD model with g(s) tuned by gradients (the scene's tuned stages)
    tuned_col = None
    if tuned is not None and tuned_mimo is not None:
        dfile = Path(out_dir) / "design_tuned.npz"
        io_save = getattr(io, "save_design", None)
        if io_save is None:
            from .tune import save_design as io_save  # local: CLI start-up (hapid.tune, ~0.8 s)
        io_save(dfile, tuned["g"], constraints=tuned["constraints"], history=tuned["history"])
        tuned_col = {"label": "hapid NLS + PD + tuned g", "mimo": _loop_numbers(tuned_mimo["report"]),
                     "g": tuned["parameters"], "design_file": str(dfile),
                     "status": tuned.get("status"), "decision": tuned.get("decision")}  # fmt: skip
    res = PaperSummary(dev, [float(span[band].min()), float(span[band].max())], fits, siso_rows,
                       tuned_col)  # fmt: skip
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    io.save_json(out / "summary.json", res.numbers())
    io.save_text(out / "summary.md", res.markdown())
    return res


def _fmt(x, nd=1):
    return "—" if x is None else (str(x) if isinstance(x, bool) else f"{x:.{nd}f}")


def _markdown(res: dict) -> str:
    W, N = res["fits"]["wls"], res["fits"]["nls"]
    sp = res["plant_span_db_1_30hz"]
    siso = res["siso"].get("design rule", {})
    siso1 = res["siso"].get("c=1", {})

    def mim(e, k, nd=1):
        return _fmt(e["mimo"].get(k), nd)

    def tpk(e):
        m = e["mimo"]
        return (
            "—"
            if m.get("t_peak_db") is None
            else f"{m['t_peak_db']:.1f} dB at {m['t_peak_hz']:.1f} Hz"
        )

    X = res.get("tuned")
    rows = [
        ("plant singular-value span, 1–30 Hz (dB)", PAPER["plant_span_db"], f"{sp[0]:.1f}–{sp[1]:.1f}", "(same plant)"),
        ("P·P̂⁻¹ band to 30 Hz (dB)", PAPER["pphat_band_db"],
         "{:+.1f} / {:+.1f}".format(*W["pphat_band_db_to_30hz"]), "{:+.1f} / {:+.1f}".format(*N["pphat_band_db_to_30hz"])),
        ("anisotropy reduction factor", PAPER["anisotropy_reduction"],
         "{:.1f}–{:.1f}".format(*W["anisotropy_reduction"]), "{:.1f}–{:.1f}".format(*N["anisotropy_reduction"])),
        ("SISO iso-bandwidth (Hz), design-rule gain c = " + _fmt(siso.get("c"), 3), PAPER["siso_iso_bandwidth_hz"],
         _fmt(siso.get("iso_bandwidth_hz"), 2), "(same)"),
        ("SISO, c = 1: closed loop stable?", "—", _fmt(siso1.get("stable")), "(same)"),
        ("MIMO closed loop stable (Nyquist)", "yes", mim(W, "stable"), mim(N, "stable")),
        ("MIMO iso-bandwidth (Hz)", PAPER["mimo_iso_bandwidth_hz"], mim(W, "iso_bandwidth_hz", 2), mim(N, "iso_bandwidth_hz", 2)),
        ("MIMO gain margin (dB)", PAPER["mimo_gm_db"], mim(W, "gm_db"), mim(N, "gm_db")),
        ("MIMO phase margin (deg)", PAPER["mimo_pm_deg"], mim(W, "pm_deg"), mim(N, "pm_deg")),
        ("MIMO disk margin α (σ̄(S − T), conservative)", "—", mim(W, "disk_margin", 3), mim(N, "disk_margin", 3)),
        ("peak of σ̄(T)", PAPER["mimo_t_peak"], tpk(W), tpk(N)),
        ("CRHP roots of det Ẑ_H, det Ẑ_T before → after positize", "—",
         f"{W['crhp_roots_before_positize']['hand']}, {W['crhp_roots_before_positize']['total']} → "
         f"{W['crhp_roots_after_positize']['hand']}, {W['crhp_roots_after_positize']['total']}", "0, 0 (by construction)"),
    ]  # fmt: skip
    # the tuned-g column (hapid.tune): MIMO rows only, the model is the NLS + PD one
    mimo_rows = {"MIMO closed loop stable (Nyquist)": "stable", "MIMO iso-bandwidth (Hz)": "iso_bandwidth_hz",
                 "MIMO gain margin (dB)": "gm_db", "MIMO phase margin (deg)": "pm_deg",
                 "MIMO disk margin α (σ̄(S − T), conservative)": "disk_margin"}  # fmt: skip

    def third(label):
        if X is None:
            return "—"
        if label in mimo_rows:
            k = mimo_rows[label]
            return mim(X, k, 3 if k == "disk_margin" else 2 if k == "iso_bandwidth_hz" else 1)
        return tpk(X) if label == "peak of σ̄(T)" else "(same model)"

    rows = [(a, b, c, d, third(a)) for a, b, c, d in rows]
    lines = [
        "# Paper reproduction on the simulated device",
        "",
        f"Device: n = {res['device']['n']} rods, {res['device']['fs_hz']:g} Hz, "
        f"{res['device']['delay_samples']}-sample actuator delay. Loop analysis on the true sampled "
        "plant P(e^{jωt_s}) with the discretized controller (matched-pole-zero g, Tustin matrix part).",
        "",
        "| quantity | paper | paper WLS + positize | hapid NLS + PD | hapid NLS + PD + tuned g |",
        "|---|---|---|---|---|",
    ]
    lines += [f"| {a} | {b} | {c} | {d} | {e} |" for a, b, c, d, e in rows]
    refit = N.get("refit_pd_eps")
    lines += ["", f"NLS status: {N.get('status')} after {N.get('steps')} steps."
              + ("" if refit is None else
                 f" Refitted with pd_eps = {refit:g}: the PSD-boundary fit put a root of det Ẑ_H "
                 "at ∞ or on the imaginary axis, where the inverse-model controller is improper "
                 "or marginal."), ""]  # fmt: skip
    if X is not None:
        lines += [
            "Tuned g (hapid.tune, robust over the device's pose/subject variants, nominal plant "
            "held out): "
            + ", ".join(f"{k} {v:.3g}" for k, v in X["g"].items())
            + " (Hz for frequencies)."
            + (f" Tuner: {X['status']}; {X['decision']}." if X.get("status") else ""),
            "",
        ]
    lines += [
        "Noisy data: the fits above invert the empirical FRF, which a noisy position 𝓛 biases. "
        "`hapid run scenes/noisy.toml` repeats this scene with 10× the force and encoder noise; "
        "there fit the run file with the sample maximum-likelihood estimator "
        "(`hapid fit run.npz --method ml --true-device cu5`), which reports its band against "
        "the true plant beside the Cramér–Rao band.",
        "",
    ]
    return "\n".join(lines)
