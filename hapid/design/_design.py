"""``run_design``: input file → stages → files, figures, ``report.json`` and ``report.html``."""

from __future__ import annotations

import dataclasses
import enum
import platform
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

from .. import __version__, io
from .._constants import COHERENCE_LOW
from ..control import Compensator
from ..defaults import PPHAT_BAND_HZ
from ..experiment import low_coherence_note
from ..fit import crhp_report, pphat_band_db
from ..impedance_frf import ImpedanceFRF
from ..verdict import Check, Verdict, worst
from . import _graph, _html
from ._commands import FILES, DesignOptions, analyze_command, shell_line
from ._figures import LABELS, coherences, figures, loops
from ._verdict import TUNED, robust_check, tuned_check, tuned_row

BAND_HZ = PPHAT_BAND_HZ


class DesignStatus(enum.StrEnum):
    """Outcome of :func:`run_design` (:class:`DesignReport`): the delivered controller's
    :class:`~hapid.verdict.Verdict`, or ``NO_CONTROLLER``; ``ok`` means ``PASSED``."""

    PASSED = Verdict.PASSED.value
    FAILED = Verdict.FAILED.value
    NOT_ESTABLISHED = Verdict.NOT_ESTABLISHED.value
    NO_CONTROLLER = "no controller"


@dataclasses.dataclass(frozen=True)
class DesignReport:
    """What ``hapid design`` made.

    Attributes:
        out_dir: the output folder.
        checks: the requirement checks (empty without a controller).
        numbers: the strict-JSON content of ``report.json``.
        files: the files written, relative to ``out_dir``.
    """

    out_dir: Path
    checks: tuple[Check, ...]
    numbers: dict
    files: tuple[str, ...]

    @property
    def status(self) -> DesignStatus:
        """:class:`DesignStatus`: the verdict on the controller the design delivers
        (:func:`delivered`), or ``NO_CONTROLLER`` (a single impedance, or the controller
        stages skipped)."""
        return (
            DesignStatus(delivered(self.checks).value)
            if self.checks
            else DesignStatus.NO_CONTROLLER
        )

    @property
    def ok(self) -> bool:
        """The delivered controller passed (False without checks)."""
        return self.status is DesignStatus.PASSED

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok`` and ``report.json``'s content."""
        return {"status": self.status.value, "ok": self.ok} | self.numbers


def delivered(checks) -> Verdict:
    """The verdict on the controller a design delivers: the tuned g's check when it was
    tuned (the last check), else the worst of the paper g's checks on every model."""
    tuned = [c for c in checks if c.name.startswith(TUNED)]
    return tuned[-1].verdict if tuned else worst(*checks)


def versions() -> dict:
    """hapid, jax, numpy and python versions."""
    return {"hapid": __version__, "jax": jax.__version__, "numpy": np.__version__,
            "python": platform.python_version()}  # fmt: skip


def _fit_numbers(fit: dict, frf) -> dict:
    if "error" in fit:
        return {"error": fit["error"]}
    out = {"method": fit["method"], "status": fit["status"], "notes": fit["notes"],
           "quality": fit["quality"].summary(), "quality_lines": fit["quality"].report()}  # fmt: skip
    if not isinstance(frf, ImpedanceFRF):
        lo, hi = pphat_band_db(frf.P, fit["model"], frf.omega, BAND_HZ)
        c = crhp_report(fit["model"])
        out |= {"pphat_band_db": [float(lo), float(hi)], "pphat_band_to_hz": BAND_HZ,
                "crhp_roots_hand_total": [int(c.hand), int(c.total)]}  # fmt: skip
    return out


def _robust_json(robust: dict) -> dict:
    return {m: {"posterior": r["report"].summary(), "device": None}  # its draws: the loop GP
            for m, r in robust.items()}  # fmt: skip


def _write_files(d: Path, res: dict, cmds: dict) -> list[str]:
    out = []

    def put(name, path):
        out.append(str(Path(path).relative_to(d)))

    if cmds.get("frf") is not None:
        frf = res["frf"]
        save = io.save_impedance_frf if isinstance(frf, ImpedanceFRF) else io.save_frf
        put("frf", save(d / FILES["frf"], frf))
    for m in _graph.MODELS:
        fit = res.get(m)
        if fit and "error" not in fit:
            save = (
                io.save_impedance_model if isinstance(res["frf"], ImpedanceFRF) else io.save_model
            )
            put(m, save(d / FILES[m], fit["model"], **fit["meta"]))
    if "posterior" in res:
        put("posterior", io.save_samples(d / FILES["posterior"], res["posterior"]["samples"]))
    if "robust" in res:
        rj = _robust_json(res["robust"])
        put(
            "robust",
            io.save_json(d / FILES["robust"], next(iter(rj.values())) if len(rj) == 1 else rj),
        )
    t = res.get("tune")
    if t and "error" not in t:
        info = t["info"]
        put("tune", io.save_design(d / FILES["tune"], t["g"], **info))
        tab = info.get("table", {})
        put("tune", io.save_json(d / "tune.json", {"start": tab.get("start"), "tuned": tab.get("tuned"),
                                                    "constraints": info["constraints"],
                                                    "history": info["history"],
                                                    "parameters": info["parameters"]}))  # fmt: skip
    return out


def run_design(input_path, out_dir, o: DesignOptions, parse: Callable, *, skip=(), only=(),
               cache_dir=".hapid_cache/stages", say: Callable[[str], None] = _graph.stderr,
               ) -> DesignReport:  # fmt: skip
    """Run the design stages on ``input_path`` (kind ``o.kind``) and write into ``out_dir``:
    the single commands' files (``frf.npz``, ``wls.npz``, ``nls.npz``, ``ml.npz``,
    ``samples.npz``, ``robust.json``, ``design.npz``, ``tune.json``), every figure as PNG and
    PDF, ``report.json`` (strict JSON) and ``report.html`` (self-contained). ``parse(argv)``
    parses a ``hapid`` command line (the single commands' defaults); ``skip``/``only``:
    stage names (:data:`hapid.design.STAGES`); ``cache_dir`` None: no stage cache. Raises
    ``ValueError`` for an unknown or inapplicable stage name."""
    d = Path(out_dir)
    path = str(input_path)
    cmds = _graph.plan(o, skip, only)
    graph = _graph.build(o, cmds, path, io.file_sha256(path), parse, say)
    res, log = _graph.run(graph, cmds, cache_dir)
    for name in log["cached"]:
        say(f"{name}: from the stage cache")
    files = _write_files(d, res, cmds)
    frf = res["frf"]
    fits = {m: res[m] for m in _graph.MODELS if m in res}
    robust = res.get("robust")
    tune = res.get("tune") if res.get("tune") and "error" not in res["tune"] else None
    nls = fits.get("nls")
    reps = {}
    pair = not isinstance(frf, ImpedanceFRF)
    if nls and "error" not in nls and pair and {"robust", "tune"} & set(cmds):
        reps = loops(frf, nls["model"], Compensator.paper(), tune["g"] if tune else None)
    checks = [robust_check(m, r["report"], r["info"]) for m, r in (robust or {}).items()]
    if tune:
        checks.append(tuned_check(tune))
    figs = figures(frf, fits, robust, reps)
    for fig in figs:
        files += [str(io.save_bytes(d / f"{fig.name}.{ext}", getattr(fig, ext)).relative_to(d))
                  for ext in ("png", "pdf")]  # fmt: skip
    numbers = _numbers(o, path, cmds, log, res, fits, robust, tune, reps, checks, figs, files)
    files += ["report.json", "report.html"]
    numbers["files"] = files
    io.save_json(d / "report.json", numbers)
    io.save_text(d / "report.html", _page(numbers, figs))
    return DesignReport(d, tuple(checks), numbers, tuple(files))


def _coherence_numbers(frf, f, kind: str) -> dict:
    """The report's coherence figures: per H1 block (``Z``, or ``Z_H`` and ``Z_T``) the median
    and minimum γ² and where it is low; a note why there is none otherwise."""
    coh = coherences(frf)
    if not coh:
        why = ("a periodic run's FRF is averaged over whole periods (no leakage): its quality is "
               "the element std" if kind == "run" else "the FRF file holds none")  # fmt: skip
        return {"coherence": None, "coherence_note": f"not measured: {why}"}
    blocks = {k: {"median": float(np.median(g)), "min": float(np.min(g)),
                  "low": low_coherence_note(f, g)} for k, g in coh.items()}  # fmt: skip
    low = "; ".join(f"{k}: {b['low']}" for k, b in blocks.items() if b["low"])
    note = ", ".join(
        f"{k} median γ² {b['median']:.3f} (min {b['min']:.2f})" for k, b in blocks.items()
    )
    return {
        "coherence": blocks,
        "coherence_note": note + (f"; {low}" if low else f"; ≥ {COHERENCE_LOW:g} everywhere"),
    }


def _numbers(o, path, cmds, log, res, fits, robust, tune, reps, checks, figs, files) -> dict:
    frf = res["frf"]
    f = np.asarray(frf.freq_hz)
    std = frf.Z_std if isinstance(frf, ImpedanceFRF) else frf.Z_H_std
    Z = frf.Z if isinstance(frf, ImpedanceFRF) else frf.Z_H
    rel = None if std is None else float(np.median(np.asarray(std) / np.abs(np.asarray(Z))))
    errors = {s: r["error"] for s, r in res.items() if isinstance(r, dict) and "error" in r}
    an = analyze_command(o)
    out = {
        "title": f"hapid design of {Path(path).name}",
        "input": {"path": path, "kind": o.kind, "sha256": io.file_sha256(path)},
        "versions": versions(),
        "commands": [shell_line(a, path) for a in cmds.values() if a is not None],
        "check_command": None if an is None or tune is None else shell_line(an, path),
        "stages": {
            "run": list(cmds),
            "skipped": [s for s in _graph.plan(o) if s not in cmds],
            "computed": log["computed"],
            "cached": log["cached"],
            "seconds": log["seconds"],
            "errors": errors,
        },  # fmt: skip
        "frf": {
            "n": frf.n,
            "n_freq": int(f.size),
            "f_min_hz": float(f.min()),
            "f_max_hz": float(f.max()),
            "median_relative_std": rel,
            **_coherence_numbers(frf, f, o.kind),
        },  # fmt: skip
        "fits": {m: _fit_numbers(r, frf) for m, r in fits.items()},
        "posterior": None
        if "posterior" not in res
        else {
            "method": o.posterior,
            "n_samples": int(np.shape(res["posterior"]["samples"].samples)[0]),
            "summary": str(res["posterior"]["summary"]),
        },  # fmt: skip
        "robust": None if robust is None else _robust_json(robust),
        "tune": None
        if tune is None
        else {
            k: tune["info"].get(k)
            for k in (
                "bandwidth_claimed_hz",
                "bandwidth0_claimed_hz",
                "feasible",
                "parameters",
                "table",
                "constraints",
            )
        }
        | {
            "decision": tune["decision"],
            "kept_start": tune["kept_start"],
            "returned": tuned_row(tune),
        },  # fmt: skip
        "loops_on_measured_plant": {k: r.summary() for k, r in reps.items()},
        "verdict": {
            "overall": delivered(checks).value if checks else None,
            "overall_means": "the tuned g's check when tuned, else the worst of the paper g's",
            "checks": [c.summary() for c in checks],
        },  # fmt: skip
        "controller": None
        if checks
        else (
            "no controller: a single impedance (lab time series or impedance FRF) is fitted "
            "and checked for quality, not controlled"
            if o.single
            else "no controller: "
            + (
                "; ".join(f"{k} failed: {v}" for k, v in errors.items())
                or "the robust and tune stages were skipped"
            )
        ),  # fmt: skip
        "figures": [{"name": g.name, "title": g.title, "caption": g.caption} for g in figs],
    }
    return io.jsonable(out)


def _page(n: dict, figs) -> str:
    H = _html
    byname = {g.name: g for g in figs}
    inp = n["input"]
    secs = [
        ("Input", H.table(("file", "kind", "sha256"), [(inp["path"], inp["kind"], inp["sha256"])]))
    ]
    v = n["verdict"]
    if v["checks"]:
        secs.append((f"Verdict: {v['overall']}", H.para(f"Overall: {v['overall_means']}.")
                     + H.verdict_table(v["checks"])))  # fmt: skip
    else:
        secs.append(("Verdict", H.para(n["controller"])))
    fr = n["frf"]
    frf_html = H.table(("n", "frequencies", "range (Hz)", "median relative std of Z"),
                       [(fr["n"], fr["n_freq"], f"{fr['f_min_hz']:g}–{fr['f_max_hz']:g}",
                         fr["median_relative_std"])]) + H.para(f"Coherence: {fr['coherence_note']}.")  # fmt: skip
    frf_html += "".join(H.figure(byname[k]) for k in ("frf_Z", "frf_Z_H", "frf_Z_T", "coherence")
                        if k in byname)  # fmt: skip
    secs.append(("FRF and fits", frf_html))
    rows = []
    for m, q in n["fits"].items():
        if "error" in q:
            rows.append((LABELS[m], "error: " + q["error"], "—", "—", "—", "—"))
            continue
        band = q.get("pphat_band_db")
        band = None if band is None else f"{band[0]:+.1f} / {band[1]:+.1f} dB"
        for b, v in q["quality"].items():
            if isinstance(v, dict):  # one block (Z_H, Z_T or Z)
                rows.append((LABELS[m], q["status"], b, v["median_rel_err_db"], v["max_rel_err_db"], band))  # fmt: skip
    fit_html = H.table(("model", "status", "block", "median rel. error (dB)", "max rel. error (dB)",
                        f"P P̂⁻¹ band to {BAND_HZ:g} Hz"), rows)  # fmt: skip
    fit_html += "".join(H.pre("\n".join([f"{LABELS[m]}:"] + q.get("quality_lines", []) + q.get("notes", [])))
                        for m, q in n["fits"].items() if "error" not in q)  # fmt: skip
    if "pphat" in byname:
        fit_html += H.figure(byname["pphat"])
    secs.append(("Fit quality", fit_html))
    if n["posterior"]:
        secs.append(("Posterior", H.pre(n["posterior"]["summary"])))
    if n["robust"]:
        keys = ("n", "p_stable", "gm_db_q05", "gm_db_q50", "pm_deg_q05", "pm_deg_q50",
                "iso_bandwidth_hz_q05", "iso_bandwidth_hz_q50", "passed")  # fmt: skip
        rows = [(LABELS[m], *(r["posterior"][k] for k in keys)) for m, r in n["robust"].items()]
        h = H.table(("paper g on", *keys), rows) + (
            H.figure(byname["robust"]) if "robust" in byname else ""
        )
        secs.append(("Robust check of the paper g (loop draws conditioned on the FRF)", h))
    if n["tune"]:
        t = n["tune"]
        tab = t["table"] or {}
        keys = sorted(set().union(*(r.keys() for r in tab.values()))) if tab else []
        rows = [(k, *(tab[c].get(k) for c in tab)) for k in keys if k != "validate_s"]
        h = H.para(t["decision"]) + H.table(("quantity", *tab), rows)
        h += H.table(
            ("parameter", "start", "tuned"),
            [(p["name"], p["start"], p["tuned"]) for p in t["parameters"]],
        )
        if n["check_command"]:
            h += H.para(
                "Check the design file on a plant: a densely measured FRF (the "
                "experiment's own FRF has too few frequencies for a Nyquist count) in "
                "place of frf.npz, or --device NAME for a simulated device:"
            )
            h += H.pre(n["check_command"])
        secs.append(("Tuned g and its certificate", h))
    loops = n["loops_on_measured_plant"]
    if loops:
        keys = (
            "stable",
            "iso_bandwidth_hz",
            "gm_db",
            "pm_deg",
            "disk_margin",
            "t_peak_db",
            "t_peak_hz",
        )
        h = H.table(
            ("loop on the measured plant (GP-interpolated, continuous g)", *keys),
            [(k, *(r.get(x) for x in keys)) for k, r in loops.items()],
        )
        h += "".join(H.figure(byname[k]) for k in ("sigma_T_minus_I", "loci") if k in byname)
        secs.append(("Closed loop on the measured plant (NLS model)", h))
    st = n["stages"]
    rows = [
        (s, "cache" if s in st["cached"] else "computed", st["seconds"].get(s)) for s in st["run"]
    ]
    rows += [(s, "skipped", None) for s in st["skipped"]]
    ver = ", ".join(f"{k} {x}" for k, x in n["versions"].items())
    secs.append(("How this was made", H.para("The single commands this design ran (same options, same "
                 "numbers):") + H.pre("\n".join(n["commands"])) + H.table(("stage", "how", "seconds"), rows)
                 + H.para(f"Versions: {ver}. Files: {', '.join(n['files'])}.")))  # fmt: skip
    return H.page(n["title"], secs)
