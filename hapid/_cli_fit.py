"""The ``hapid fit`` command and the lab-data branch of ``hapid frf`` (the CLI shell only:
parse results in, library calls, one report out).

``hapid fit`` dispatches on the file kind (the arrays the file holds):

- an FRF file with ``Z_H``, ``Z_T`` — the haptic hand/total pair → an ``ImpedanceModel``;
- an impedance FRF with ``Z`` — a single measured impedance → one ``M, B, K``.

and on ``--method`` through :data:`PAIR_METHODS` / :data:`SINGLE_METHODS` (name → function
``(data, args, band_hz) -> Fitted``; ``data`` already restricted to the band): adding a method
is one function and one table entry. Every
method sees the band given by ``--f-min-hz``/``--f-max-hz`` (default every frequency in the
file, except NLS and ML on the haptic pair: up to :data:`hapid.defaults.FIT_BAND_HZ`), selected before the fit and echoed in the report; every fit gets a
:class:`hapid.fit.FitQuality` over that band, printed and stored in the model file. Extra
report lines (a Cramér–Rao band, an error against a known true plant) go through
``FitQuality.with_line`` in the method function or in :func:`extra_quality_lines`.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable

import numpy as np

from . import io
from ._cli_lab import matrices_report
from ._constants import TWO_PI
from ._grids import band_mask
from .defaults import FIT_BAND_HZ, NLS_MAX_STEPS, NLS_SOLVER, PPHAT_BAND_HZ
from .device import preset
from .experiment import estimate_frf
from .impedance_frf import model_units


class FitCommandError(ValueError):
    """A fit the CLI refuses to write (one line, exit code 2)."""


@dataclasses.dataclass
class Fitted:
    """What a method function returns: the model, its file metadata, a status text, and the
    quality (``None``: the dispatcher computes it on the band); ``before`` is the model a
    positized fit started from (for the "positizing made it worse" warning)."""

    model: object
    meta: dict
    status: str
    quality: object = None
    before: object = None
    notes: tuple[str, ...] = ()
    std: object = None


def _nls_refuse(res, a):
    if not bool(res.ok) and not a.allow_unconverged:
        raise FitCommandError(
            f"NLS fit did not converge (status {res.status} after {int(res.n_steps)} steps); "
            "no model written (use --allow-unconverged to write it anyway)"
        )


# ---- the haptic hand/total pair ---------------------------------------------------------------
def _pair_wls(frf, a, band) -> Fitted:
    from .fit import positize, wls  # local: CLI start-up (hapid.fit, optimistix)

    raw = wls(frf, omega_c=TWO_PI * a.omega_c_hz)
    if a.positize:
        return Fitted(positize(raw), {"method": "wls+positize"}, "closed form", before=raw)
    return Fitted(raw, {"method": "wls"}, "closed form")


def _pair_nls(frf, a, band) -> Fitted:
    from . import pipeline  # local: CLI start-up (hapid.fit, optimistix)

    o = dict(weight=a.weight, solver=a.solver, f_max_hz=None, omega_c_hz=a.omega_c_hz,
             max_steps=a.max_steps)  # fmt: skip
    # a Ẑ_H with a root at ∞ / on the imaginary axis is refitted strictly PD
    cf = pipeline.control_fit(frf, boundary_refit=not getattr(a, "keep_boundary", False), **o)
    f, refit = cf.fit, cf.refit_pd_eps
    res = f.result
    _nls_refuse(res, a)
    meta = dict(method="nls", status=res.status, cost=float(res.cost), steps=int(res.n_steps),
                weight=a.weight, solver=a.solver, covariance=np.asarray(res.covariance),
                theta=np.asarray(res.theta))  # fmt: skip
    notes = (f"at the PSD boundary: {', '.join(res.boundary)}",) if res.boundary else ()
    if refit is not None:
        meta["pd_eps"] = refit
        notes += (f"refitted with pd_eps = {refit:g}: the PSD-boundary fit put a root of "
                  "det Ẑ_H at ∞ or on the imaginary axis, where the inverse-model controller "
                  "is improper or marginal (--keep-boundary keeps that fit)",)  # fmt: skip
    status = f"{res.status} after {int(res.n_steps)} steps, cost {float(res.cost):.4g}"
    return Fitted(res.model, meta, status, notes=notes)


def _pair_ml(frf, a, band=None) -> Fitted:
    """Sample maximum likelihood on the run's spectra (``hapid.fit.fit_ml``); the run is the
    file read by :func:`run_fit` (``a.ml_run``), ``frf`` its banded FRF (for the report)."""
    from .fit import crb_band_db, fit_ml, solver_from  # local: CLI start-up (hapid.fit, optimistix)

    run = getattr(a, "ml_run", None)
    if run is None:  # pragma: no cover - run_fit always sets it for --method ml
        raise FitCommandError("--method ml needs the run file")
    solver = a.solver  # jaxopt_lm is refused before any work (hapid._cli_checks_cross)
    f = np.asarray(frf.freq_hz)
    res = fit_ml(run, f_min_hz=float(f.min()), f_max_hz=float(f.max()),
                 model_floor=a.model_floor, solver=solver_from(solver), max_steps=a.max_steps)  # fmt: skip
    if not bool(res.ok) and not a.allow_unconverged:
        raise FitCommandError(
            f"ML fit did not converge (status {res.status} after {int(res.n_steps)} steps); "
            "no model written (use --allow-unconverged to write it anyway)"
        )
    meta = dict(method="ml", status=res.status, cost=float(res.cost), steps=int(res.n_steps),
                weight="ml", solver=solver, model_floor=float(a.model_floor),
                sigma2=float(res.sigma2), covariance=np.asarray(res.covariance),
                crb=np.asarray(res.crb), theta=np.asarray(res.theta))  # fmt: skip
    notes = (f"at the PSD boundary: {', '.join(res.boundary)}",) if res.boundary else ()
    clo, chi = crb_band_db(res.model, res.crb, res.scale, frf.omega, f_max_hz=a.band_hz)
    meta["cramer_rao_band_db"] = np.array([clo, chi])
    status = (f"{res.status} after {int(res.n_steps)} steps, cost {float(res.cost):.4g}, "
              f"σ̂² {float(res.sigma2):.3g} (≈1: noise explains the misfit; ≫1: model error)")  # fmt: skip
    return Fitted(res.model, meta, status, notes=notes)


# ---- a single impedance ----------------------------------------------------------------------
def _single(method: str):
    def run(zfrf, a, band) -> Fitted:
        from .fit import fit_impedance  # local: CLI start-up (hapid.fit, optimistix)

        if a.weight not in ("relative", "noise"):
            raise FitCommandError(
                f"--weight {a.weight} is for the haptic pair; a single impedance takes "
                "relative or noise"
            )
        res = fit_impedance(zfrf, method=method, positize=a.positize and method == "wls",
                            weight=a.weight, max_steps=a.max_steps, f_min_hz=band[0],
                            f_max_hz=band[1])  # fmt: skip
        if method == "nls" and not res.ok and not a.allow_unconverged:
            raise FitCommandError(
                f"NLS fit did not converge (status {res.status} after {res.n_steps} steps); "
                "no model written (use --allow-unconverged to write it anyway)"
            )
        status = res.status
        if method == "nls":
            status += f" after {res.n_steps} steps, cost {res.cost:.4g}"
        notes = (f"at the PSD boundary: {', '.join(res.boundary)}",) if res.boundary else ()
        if method == "nls":
            chi = res.reduced_chi2
            notes += ((f"reduced χ² {chi:.3g}: std of M, B, K scaled by it (relative weights)"
                       if a.weight == "relative" else
                       f"reduced χ² {chi:.3g}: std of M, B, K scaled by it (noise weights; the "
                       "FRF's std under-state the misfit)" if res.sigma2 != 1.0 else
                       f"reduced χ² {chi:.3g} (noise weights): std of M, B, K from the FRF's std, "
                       "not scaled"),)  # fmt: skip
        return Fitted(res.model, res.metadata(), status, quality=res.quality, notes=notes,
                      std=res.model_std)  # fmt: skip

    return run


PAIR_METHODS: dict[str, Callable] = {"wls": _pair_wls, "nls": _pair_nls, "ml": _pair_ml}
SINGLE_METHODS: dict[str, Callable] = {"wls": _single("wls"), "nls": _single("nls")}
#: every method name ``hapid fit --method`` accepts (the parser's choices)
METHODS = tuple(dict.fromkeys([*PAIR_METHODS, *SINGLE_METHODS]))


def extra_quality_lines(quality, fitted: Fitted, data, a):
    """Hook for report lines that need more than the fit: the band against a known true
    plant (``--true-device``, haptic pair only)."""
    crb = fitted.meta.get("cramer_rao_band_db")
    if crb is not None:
        quality = quality.with_line(
            "cramer_rao",
            f"Cramér–Rao limit of the P·P̂⁻¹ band to {a.band_hz:g} Hz (noise only; median over "
            f"draws from the bound): {float(crb[0]):+.2f} / {float(crb[1]):+.2f} dB",
        )
    name = getattr(a, "true_device", None)
    if not name or not hasattr(data, "Z_T"):
        return quality
    from .fit import pphat_band_db  # local: CLI start-up (hapid.fit, optimistix)

    dev = preset(name)
    if dev.n != data.n:
        raise FitCommandError(
            f"--true-device {name} has n = {dev.n} rods but the data n = {data.n}"
        )
    P = np.asarray(dev.sampled_P(np.asarray(data.omega)))
    lo, hi = pphat_band_db(P, fitted.model, data.omega, a.band_hz)
    return quality.with_line(
        "vs_true",
        f"P·P̂⁻¹ band to {a.band_hz:g} Hz against the TRUE sampled plant of {name}: "
        f"{float(lo):+.1f} / {float(hi):+.1f} dB",
    )


def _default_f_max(a, pair: bool) -> float | None:
    """The band's upper edge when ``--f-max-hz`` is not given: :data:`hapid.defaults.FIT_BAND_HZ`
    for NLS and ML on the haptic pair, else every frequency (the paper's WLS, single impedances)."""
    if a.f_max_hz is None and pair and a.method in ("nls", "ml"):
        return FIT_BAND_HZ
    return a.f_max_hz


def _band(a, f_all_hz: np.ndarray, f_max_hz: float | None = None) -> tuple[float, float]:
    f_max_hz = a.f_max_hz if f_max_hz is None else f_max_hz
    lo = 0.0 if a.f_min_hz is None else float(a.f_min_hz)
    hi = np.inf if f_max_hz is None else float(f_max_hz)
    n_in = int(np.sum(band_mask(f_all_hz, lo, hi)))
    if n_in < 3:
        raise FitCommandError(
            f"only {n_in} of the file's {f_all_hz.size} frequencies "
            f"({f_all_hz.min():g}–{f_all_hz.max():g} Hz) lie in the band {lo:g}–{hi:g} Hz; "
            "a second-order fit needs at least 3"
        )
    return lo, hi


def fit_band(sel, single: bool, a, band: tuple[float, float]):
    """``(fitted, quality, meta)``: the fit ``hapid fit`` makes of ``sel`` (the data already
    cut to ``band``, Hz) with the options ``a`` of its parser — the :class:`Fitted`, its
    :class:`hapid.fit.FitQuality` over the band (extra lines included) and the metadata the
    model file stores. Raises :class:`FitCommandError` for a fit the command refuses."""
    from .fit import pair_quality  # local: CLI start-up (hapid.fit, optimistix)

    table = SINGLE_METHODS if single else PAIR_METHODS
    fitted = table[a.method](sel, a, band)
    q = fitted.quality
    if q is None:
        before = None
        if fitted.before is not None:
            before = pair_quality(sel, fitted.before, method="wls", band_hz=band)
        q = pair_quality(sel, fitted.model, method=fitted.meta.get("method", a.method),
                         band_hz=band, before=before)  # fmt: skip
    q = extra_quality_lines(q, fitted, sel, a)
    return fitted, q, {**fitted.meta, **q.to_arrays()}


def fit_data(data, single: bool, a):
    """``(fitted, quality, meta, sel)``: :func:`fit_band` on ``data`` cut to the band ``hapid
    fit`` chooses from ``a`` (``--f-min-hz``/``--f-max-hz``, NLS on the pair: 40 Hz)."""
    lo, hi = _band(a, np.asarray(data.freq_hz), _default_f_max(a, not single))
    sel = data.band(lo, hi)
    return (*fit_band(sel, single, a, (lo, hi)), sel)


def run_fit(a) -> None:
    """``hapid fit``: read, dispatch on file kind and method, report, write (all or nothing)."""
    from .fit import crhp_report, pphat_band_db  # local: CLI start-up (hapid.fit, optimistix)

    kind = io.file_kind(a.frf, "an FRF file (freq_hz with Z_H, Z_T or Z)")
    if a.method == "ml":
        if kind != "run":
            raise FitCommandError(
                f"{a.frf}: holds a {kind} file; --method ml needs the run file (per-experiment, "
                "per-period R_A, R_I, L: an FRF has lost the noise covariances), e.g. "
                "hapid simulate --out run.npz; hapid fit run.npz --method ml"
            )

        a.ml_run = io.load_run(a.frf)
        kind = "frf"
    elif kind not in ("frf", "impedance_frf"):
        what = "arrays hapid does not know" if kind == "unknown" else f"a {kind} file"
        raise FitCommandError(
            f"{a.frf}: holds {what}, not an FRF; hapid fit takes an FRF with freq_hz, Z_H, Z_T "
            "(hapid frf on a run file; CSV header freq_hz,Z_H_re_0_0,…) or an impedance FRF "
            "with freq_hz, Z (hapid frf on a time series; CSV header freq_hz,Z_re_0_0,…)"
        )
    single = kind == "impedance_frf"
    if a.method == "ml":
        data = estimate_frf(a.ml_run)
    else:
        data = io.load_impedance_frf(a.frf) if single else io.load_frf(a.frf)
    table = SINGLE_METHODS if single else PAIR_METHODS
    if a.method not in table:
        raise FitCommandError(
            f"--method {a.method} is not available for "
            f"{'a single impedance' if single else 'the haptic pair'} (choose from {', '.join(table)})"
        )
    f_max = _default_f_max(a, not single)
    lo, hi = _band(a, np.asarray(data.freq_hz), f_max)
    sel = data.band(lo, hi)
    unit = data.unit if single else "N/m"
    units = model_units(unit)
    what = (f"single impedance Z ({unit})" if single
            else "haptic hand/total pair Z_H, Z_T (N/m)")  # fmt: skip
    f = np.asarray(sel.freq_hz)
    print(f"data: {what}, n = {data.n}, from {a.frf}")
    if a.f_min_hz is None and f_max is None:
        how = "every frequency in the file; narrow it with --f-min-hz/--f-max-hz"
    elif a.f_max_hz is None and f_max is not None:
        how = (f"default for nls and ml on the haptic pair: up to {f_max:g} Hz, the scenes' fit "
               "band and hapid posterior's; --f-max-hz to change")  # fmt: skip
    else:
        how = f"--f-min-hz {lo:g} --f-max-hz {hi:g}"
    print(f"band: {f.min():g}–{f.max():g} Hz, {f.size} of {np.size(data.freq_hz)} frequencies "
          f"({how})")  # fmt: skip
    fitted, q, meta = fit_band(sel, single, a, (lo, hi))
    if single:
        out = io.save_impedance_model(a.out, fitted.model, **meta)
    else:
        out = io.save_model(a.out, fitted.model, **meta)
    print(f"{fitted.meta.get('method', a.method)}: {fitted.status}")
    for note in fitted.notes:
        print(f"note: {note}")
    if single:
        m = fitted.model
        n_crhp = int(m.n_crhp_roots())
        for line in matrices_report(m, fitted.std, units):
            print(line)
        print(f"closed-RHP roots of det Ẑ: {n_crhp} of {2 * m.n}")
        if n_crhp:
            warnings.warn(f"det Ẑ has {n_crhp} closed-right-half-plane root(s): the model is not "
                          "a stable passive structure (negative damping or stiffness)",
                          stacklevel=1)  # fmt: skip
    else:
        for which, so in (("hand", fitted.model.hand), ("total", fitted.model.total)):
            for line in matrices_report(so, None, units, label=f"{which} ", std_note=False):
                print(line)
        after = crhp_report(fitted.model)
        print(f"CRHP roots of det Ẑ_H, det Ẑ_T: {int(after.hand)}, {int(after.total)} (of "
              f"{2 * data.n} each)")  # fmt: skip
        if int(after.hand) > 0:
            warnings.warn(f"Ẑ_H has {int(after.hand)} closed-right-half-plane root(s): the "
                          "inverse-model controller g Ẑ_T Ẑ_H⁻¹ cancels them unstably, so no g "
                          "makes its loop stable (hapid tune will not certify it); "
                          + (f"fit a narrower band (e.g. --f-max-hz {FIT_BAND_HZ:g})"
                             if a.method != "wls" else "use --positize or --method nls"),
                          stacklevel=1)  # fmt: skip
        if np.all(np.asarray(data.Z_H) == np.asarray(data.Z_T)) or not np.any(np.asarray(data.Z_H)):
            print("P·P̂⁻¹ band: not reported (Z_H = Z_T or Z_H = 0: a single impedance in the "
                  "pair; store it as Z for the single-impedance path)")  # fmt: skip
        else:
            plo, phi = pphat_band_db(data.P, fitted.model, data.omega, a.band_hz)
            print(f"P·P̂⁻¹ band to {a.band_hz:g} Hz (measured P): {float(plo):+.1f} / "
                  f"{float(phi):+.1f} dB")  # fmt: skip
    for line in q.report():
        print(line)
    print(f"model → {out}")


def register_fit(sub, func) -> None:
    """The ``hapid fit`` parser (method choices from :data:`METHODS`)."""
    f = sub.add_parser("fit", help="fit M, B, K to an FRF: the haptic pair or a single impedance",
                       description="Fit M s² + B s + K to an FRF file. The file kind decides: "
                       "Z_H, Z_T (the haptic pair, from hapid frf on a run) → hand and total "
                       "models; Z (a single impedance, from hapid frf on a time series) → one "
                       "M, B, K. Methods: weighted least squares (optionally positized) or "
                       "hapid's nonlinear fit with positive-semidefinite M, B, K. One band for "
                       "every method; the data-fit error over it is printed and stored.",
                       epilog="example: hapid fit z.npz --method nls --f-min-hz 5 --f-max-hz 50 "
                       "--out model.npz")  # fmt: skip
    f.add_argument("frf", help="FRF file (.npz, .csv, .mat) holding Z_H, Z_T or Z")
    f.add_argument("--method", choices=list(METHODS), default="nls",
                   help="wls, nls (FRF file) or ml (sample maximum likelihood: the RUN file)")  # fmt: skip
    f.add_argument("--model-floor", type=float, default=0.3,
                   help="ml: relative equation-error floor φ for unmodeled dynamics (default 0.3, "
                   "chosen on cu5; 0 = pure ML for data a second-order model describes)")  # fmt: skip
    f.add_argument("--true-device", help="simulated data: also report the P·P̂⁻¹ band against "
                   "this preset's true sampled plant (cu5, tripod3, hexapod6)")  # fmt: skip
    f.add_argument("--positize", action="store_true", help="positize the WLS model (paper 5.1)")
    f.add_argument("--weight", choices=["relative", "paper", "noise", "blend"], default="relative")
    f.add_argument("--solver", default=NLS_SOLVER, help=f"{NLS_SOLVER} (default), dogleg, "
                   "gauss_newton, bfgs, nonlinear_cg, jaxopt_lm")  # fmt: skip
    f.add_argument("--f-min-hz", type=float,
                   help="fit band lower edge (Hz), every method; default: the file's lowest")  # fmt: skip
    f.add_argument("--f-max-hz", type=float,
                   help=f"fit band upper edge (Hz), every method; default: {FIT_BAND_HZ:g} for nls and ml "
                   "on the haptic pair (hapid posterior's band), else the file's highest")  # fmt: skip
    f.add_argument("--omega-c-hz", type=float, default=7.0, help="paper weight corner (Hz)")
    f.add_argument(
        "--max-steps",
        type=int,
        default=NLS_MAX_STEPS,
        help=f"NLS solver step limit (default: {NLS_MAX_STEPS})",
    )
    f.add_argument("--band-hz", type=float, default=PPHAT_BAND_HZ,
                   help="report the P·P̂⁻¹ band to here (haptic pair)")  # fmt: skip
    f.add_argument("--allow-unconverged", action="store_true")
    f.add_argument("--keep-boundary", action="store_true",
                   help="nls: keep a fit whose det Ẑ_H has a root at ∞ or on the imaginary axis "
                   "(default: refit with every matrix strictly PD, pd_eps = 1e-3, so that the "
                   "inverse-model controller is proper and stable)")  # fmt: skip
    f.add_argument("--out", required=True, help="model file (.npz)")
    f.set_defaults(func=func)
