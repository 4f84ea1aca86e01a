"""One result convention: every public result type has ``status`` (a member of its own
:class:`enum.StrEnum`), ``ok`` (true exactly for the enum's ok members) and ``summary()``, a
dict of plain Python values that strict JSON (``allow_nan=False``) writes and reads back
unchanged, whose ``status`` is ``status.value``. Each result is built through the public API
on a tiny problem; the test per type also checks that the status is the right member for a
case whose outcome is known (a truth, a negated stiffness, a gain above the critical one)."""

import dataclasses
import enum
import json

import jax
import numpy as np
import pytest
from helpers import second_order_device
from helpers_fit import random_truth, synthetic_frf
from oracles import example_model

from hapid import io, pipeline, scene, sweep
from hapid.control import (
    Compensator,
    ControllerCheck,
    ControllerStatus,
    LoopMetrics,
    LoopStatus,
    MetricsSpec,
    check_controller,
    discretize_siso_controller,
    loop_metrics,
)
from hapid.design import DesignReport, DesignStatus
from hapid.device import SecondOrderDevice, tripod3
from hapid.experiment import (
    EstimateStatus,
    ImpedanceEstimate,
    Protocol,
    TimeSeries,
    estimate_frf,
    estimate_impedance,
    periodic_run,
)
from hapid.fit import (
    CRHPReport,
    CRHPStatus,
    EstimatorFits,
    FitQuality,
    FitStatus,
    ImpedanceFit,
    MLResult,
    NLSResult,
    QualityStatus,
    crhp_report,
    fit_estimators,
    fit_impedance,
    fit_nls,
)
from hapid.impedance import ImpedanceModel, SecondOrder
from hapid.paper import PaperStatus, PaperSummary
from hapid.robust import RobustResult, robust_from_files
from hapid.scene import SceneRun, SceneStatus
from hapid.sweep import SweepPoint, SweepResult, SweepStatus
from hapid.tune import (
    Binding,
    BindingStatus,
    Certificate,
    Choice,
    Decision,
    RobustDesign,
    StepResponse,
    StepStatus,
    TuneResult,
    TuneStatus,
    Validation,
    validate,
)
from hapid.tune._tune import scale_gain
from hapid.uncertainty import (
    BandCalibration,
    CalibrationStatus,
    DrawsStatus,
    LaplacePosterior,
    ModeStatus,
    NoError,
    PlantDraws,
    PoseLoop,
    PoseRow,
    PoseStudy,
    PosteriorSamples,
    RobustReport,
    SamplesStatus,
    band_calibration,
    initial_point,
    laplace_posterior,
    make_log_posterior,
    param_names,
    plant_draws,
)
from hapid.verdict import Check, Verdict
from hapid.wall import (
    ContactStatus,
    EquilibriumStatus,
    PerfectControlWall,
    WallMetrics,
    WallRun,
    WallSteadyState,
    WallUnstableWarning,
    closed_loop_wall_steady_state,
    perfect_control_wall,
    render_wall,
    wall_metrics,
)

PLAIN = (bool, int, float, str, type(None))


def _plain(x, where="summary"):
    """Every leaf a plain Python bool/int/float/str/None, containers plain dict/list."""
    if type(x) is dict:
        for k, v in x.items():
            assert type(k) is str, f"{where}: key {k!r}"
            _plain(v, f"{where}[{k!r}]")
    elif type(x) is list:
        for i, v in enumerate(x):
            _plain(v, f"{where}[{i}]")
    else:
        assert type(x) in PLAIN, f"{where}: {type(x).__name__} {x!r}"


def assert_convention(obj, enum_cls, ok_members):
    """The convention, and the status returned (for the caller's known-outcome check)."""
    st = obj.status
    assert isinstance(st, enum.Enum) and type(st) is enum_cls, (type(obj).__name__, st)
    assert bool(obj.ok) == (st in ok_members), (type(obj).__name__, st, obj.ok)
    s = obj.summary()
    assert type(s) is dict
    _plain(s, type(obj).__name__)
    assert json.loads(json.dumps(s, allow_nan=False)) == s  # strict JSON, round trip exact
    assert s["status"] == st.value and s["ok"] is bool(obj.ok)
    return st


# ---- fits -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def frf():
    return synthetic_frf(random_truth(2, seed=5), np.array([1.0, 3.0, 7.0, 15.0, 30.0]),
                         rel_noise=1e-4, seed=6)  # fmt: skip


def test_nls_result(frf):
    res = fit_nls(frf, f_max_hz=None)
    assert type(res) is NLSResult
    assert assert_convention(res, FitStatus, (FitStatus.CONVERGED,)) is FitStatus.CONVERGED
    assert res.summary()["n_steps"] == int(res.n_steps) and res.report().startswith("lm (")
    short = fit_nls(frf, f_max_hz=None, max_steps=1, ftol=0.0)  # cannot converge in one step
    assert assert_convention(short, FitStatus, (FitStatus.CONVERGED,)) is FitStatus.MAX_STEPS
    assert short.status == "max_steps"  # the StrEnum still compares as its string


def test_pipeline_fit(frf):
    closed = pipeline.fit(frf, "wls+positize")
    assert assert_convention(closed, FitStatus, (FitStatus.CLOSED_FORM, FitStatus.CONVERGED)) \
        is FitStatus.CLOSED_FORM  # fmt: skip
    assert closed.summary()["result"] is None
    nls = pipeline.fit(frf, "nls", f_max_hz=None)
    assert assert_convention(nls, FitStatus, (FitStatus.CLOSED_FORM, FitStatus.CONVERGED)) \
        is FitStatus.CONVERGED  # fmt: skip
    assert nls.summary()["result"]["status"] == "converged"


def test_control_fit(frf):
    cf = pipeline.control_fit(frf, f_max_hz=None)
    assert type(cf) is pipeline.ControlFit and type(cf.fit) is pipeline.Fit
    ok = (FitStatus.CLOSED_FORM, FitStatus.CONVERGED)
    assert assert_convention(cf, FitStatus, ok) is FitStatus.CONVERGED  # a regular fit: kept
    assert cf.summary()["refitted"] is False and cf.refit_pd_eps is None
    assert cf.summary()["result"] == cf.fit.summary()["result"]


def test_scene_run(tmp_path):
    kw = dict(out_dir=tmp_path, cache_dir=tmp_path / "cache")
    first = scene.run_scene(scene.merge({}), ["device"], **kw)
    assert type(first) is SceneRun and first.computed == ["device"]
    both = (SceneStatus.COMPUTED, SceneStatus.CACHED)
    assert assert_convention(first, SceneStatus, both) is SceneStatus.COMPUTED
    again = scene.run_scene(scene.merge({}), ["device"], **kw)  # every stage from the cache
    assert assert_convention(again, SceneStatus, both) is SceneStatus.CACHED
    assert again.summary()["cached"] == ["device"] and "device" in again.results


@pytest.mark.slow  # CI budget: five fits of one run (~13 s cold); fit_estimators is also in tests/test_fit_ml.py
def test_estimator_fits():
    """``fit_estimators`` on a 2-rod second-order device's periodic run: every iterative fit
    converges; a one-step NLS fit in its place makes the whole ``max_steps``."""
    t = random_truth(2, 5)
    dev = SecondOrderDevice(hand=t.hand, mechanism=t.mechanism)
    prot = Protocol(freq_hz=(1.0, 3.0, 7.0, 15.0, 30.0), n_periods=2, force_noise=0.01,
                    position_noise=2e-5, encoder_resolution=0.0, pattern="hadamard")  # fmt: skip
    run = periodic_run(dev, prot, hold="bandlimited")
    fits = fit_estimators(run, f_max_hz=None)
    assert type(fits) is EstimatorFits and type(fits.ml) is MLResult
    ok = (FitStatus.CONVERGED,)
    assert assert_convention(fits, FitStatus, ok) is FitStatus.CONVERGED
    assert list(fits.models()) == ["ML", "NLS relative", "NLS noise", "WLS"]
    assert fits.models()["WLS"] is fits.wls
    assert fits.summary()["fits"]["ML"] == fits.ml.summary()
    short = fit_nls(estimate_frf(run), f_max_hz=None, max_steps=1, ftol=0.0)
    bad = EstimatorFits(fits.ml, fits.nls_relative, short, fits.wls)
    assert assert_convention(bad, FitStatus, ok) is FitStatus.MAX_STEPS


# ---- sweeps and the paper summary -----------------------------------------------------------


def _sweep(stable, resolved):
    """A two-configuration sweep over ``controller.k`` with the given loop flags."""
    B = len(stable)
    m = {k: np.linspace(1.0, 2.0, B) for k in sweep.METRICS}
    m |= {"fit_ok": np.ones(B, bool), "fit_refit": np.zeros(B, bool)}
    m |= {"stable": np.asarray(stable), "nyquist_resolved": np.asarray(resolved)}
    m["iso_bandwidth_hz"] = np.where(m["stable"], 2.5, np.nan)  # undefined when unstable
    return SweepResult(("controller.k",), np.array([[0.5], [50.0]]), m, "wls+positize")


def test_sweep_result_and_point():
    ok = (SweepStatus.ALL_STABLE,)
    for flags, want in (([True, True], SweepStatus.ALL_STABLE),
                        ([True, False], SweepStatus.SOME_STABLE),
                        ([False, False], SweepStatus.NONE_STABLE)):  # fmt: skip
        res = _sweep(flags, [True, True])
        assert assert_convention(res, SweepStatus, ok) is want
        assert res.summary()["n_stable"] == sum(flags) and len(res) == 2
    res = _sweep([True, False], [True, False])
    assert res.summary()["metrics"]["iso_bandwidth_hz"] == [2.5, None]
    p0, p1 = res.point(0), res.point(1)
    assert type(p0) is SweepPoint and type(p0.metrics["stable"]) is bool
    stable = (LoopStatus.STABLE,)
    assert assert_convention(p0, LoopStatus, stable) is LoopStatus.STABLE
    assert assert_convention(p1, LoopStatus, stable) is LoopStatus.UNRESOLVED
    assert p1.summary()["params"] == {"controller.k": 50.0}
    assert p1.summary()["iso_bandwidth_hz"] is None
    p1 = _sweep([True, False], [True, True]).point(1)
    assert assert_convention(p1, LoopStatus, stable) is LoopStatus.UNSTABLE


def _paper_summary(nls_status=FitStatus.CONVERGED, tuned_stable=None):
    loop = {"stable": True, "iso_bandwidth_hz": 2.7, "gm_db": None}
    fits = {"wls": {"label": "paper WLS + positize", "mimo": loop},
            "nls": {"label": "hapid NLS + PD", "mimo": loop, "status": nls_status, "steps": 12}}  # fmt: skip
    tuned = None if tuned_stable is None else {"mimo": {"stable": tuned_stable}}
    return PaperSummary({"n": 5, "fs_hz": 1000.0, "delay_samples": 1}, [25.0, 50.0], fits,
                        {"c=1": {"c": 1.0, "stable": False}}, tuned)  # fmt: skip


def test_paper_summary():
    """The summary's status from the NLS fit and the MIMO loops (the SISO c = 1 loop is not
    one of them); ``summary()`` is ``status``, ``ok``, then the content of ``summary.json``."""
    ok = (PaperStatus.OK,)
    good = _paper_summary()
    assert assert_convention(good, PaperStatus, ok) is PaperStatus.OK
    s = good.summary()
    assert list(s)[:2] == ["status", "ok"] and "tuned" not in s
    assert {k: v for k, v in s.items() if k not in ("status", "ok")} == io.jsonable(good.numbers())
    assert assert_convention(_paper_summary(tuned_stable=True), PaperStatus, ok) is PaperStatus.OK
    assert assert_convention(_paper_summary(tuned_stable=False), PaperStatus, ok) \
        is PaperStatus.UNSTABLE_LOOP  # fmt: skip
    assert assert_convention(_paper_summary(FitStatus.MAX_STEPS, False), PaperStatus, ok) \
        is PaperStatus.FIT_NOT_CONVERGED  # fmt: skip


# ---- virtual wall ---------------------------------------------------------------------------


def test_wall_results():
    """tripod3 under a weak SISO force loop (c = 0.2): the contact with a 200 N/m wall is
    stable, with a 10⁶ N/m wall unstable (steady state, run and its metrics alike); perfect
    control has a finite equilibrium."""
    dev = tripod3()
    e = np.eye(dev.n)[0]
    pc = perfect_control_wall(dev, e, 200.0, 2.0)
    assert type(pc) is PerfectControlWall and pc.estimate < pc.penetration
    ok = (EquilibriumStatus.OK,)
    assert assert_convention(pc, EquilibriumStatus, ok) is EquilibriumStatus.OK
    nan = PerfectControlWall(float("nan"), 0.0)
    assert assert_convention(nan, EquilibriumStatus, ok) is EquilibriumStatus.NON_FINITE
    C = discretize_siso_controller(Compensator.paper(), 0.2, dev.ts, dev.n)
    soft = closed_loop_wall_steady_state(dev, C, e, 200.0, 2.0)
    assert type(soft) is WallSteadyState and len(soft.summary()["R_I"]) == dev.n
    stable = (ContactStatus.STABLE,)
    assert assert_convention(soft, ContactStatus, stable) is ContactStatus.STABLE
    stiff = closed_loop_wall_steady_state(dev, C, e, 1e6, 2.0)
    assert assert_convention(stiff, ContactStatus, stable) is ContactStatus.UNSTABLE
    run = render_wall(dev, C, e, k_wall=200.0, duration=0.2)
    assert type(run) is WallRun and run.xi.shape == (len(run.t), dev.n)
    assert assert_convention(run, ContactStatus, stable) is ContactStatus.STABLE
    m = wall_metrics(run, settle_s=0.1)
    assert type(m) is WallMetrics
    assert assert_convention(m, ContactStatus, stable) is ContactStatus.STABLE
    with pytest.warns(WallUnstableWarning):
        bad = render_wall(dev, C, e, k_wall=1e6, duration=0.2)
    assert assert_convention(bad, ContactStatus, stable) is ContactStatus.UNSTABLE
    assert assert_convention(wall_metrics(bad, settle_s=0.1), ContactStatus, stable) \
        is ContactStatus.UNSTABLE  # fmt: skip


@pytest.fixture(scope="module")
def estimate():
    """Welch estimate of a 1-DOF spring k = 2000 N/m from white-noise force records."""
    rng = np.random.default_rng(0)
    F = rng.standard_normal((1, 4096, 1))
    Y = F / 2000.0 + 1e-9 * rng.standard_normal(F.shape)
    return estimate_impedance(TimeSeries(fs_hz=1000.0, force=F, response=Y), estimate="welch",
                              nperseg=256, f_max_hz=100.0)  # fmt: skip


def test_impedance_estimate(estimate):
    assert type(estimate) is ImpedanceEstimate
    both = (EstimateStatus.OK, EstimateStatus.NOTES)
    st = assert_convention(estimate, EstimateStatus, both)
    assert st is (EstimateStatus.NOTES if estimate.notes else EstimateStatus.OK)
    assert np.allclose(np.real(np.asarray(estimate.frf.Z)), 2000.0, rtol=1e-3)


def test_impedance_fit_and_fit_quality(estimate):
    fit = fit_impedance(estimate.frf, method="wls")
    assert type(fit) is ImpedanceFit
    ok = (FitStatus.CLOSED_FORM, FitStatus.CONVERGED)
    assert assert_convention(fit, FitStatus, ok) is FitStatus.CLOSED_FORM
    assert float(np.asarray(fit.model.K)[0, 0]) == pytest.approx(2000.0, rel=1e-3)
    q = fit.quality
    assert type(q) is FitQuality
    st = assert_convention(q, QualityStatus, (QualityStatus.OK,))
    assert st is (QualityStatus.WARNINGS if q.warnings else QualityStatus.OK)
    assert fit.summary()["quality"] == q.summary()
    warned = q.with_warning("a warning")
    assert assert_convention(warned, QualityStatus, (QualityStatus.OK,)) is QualityStatus.WARNINGS
    assert warned.summary()["warnings"][-1] == "a warning"


# ---- controller realizability -------------------------------------------------------------


def test_crhp_report_and_controller_check():
    good = example_model(3, seed=0)
    h = good.hand
    bad = ImpedanceModel(SecondOrder(h.M, h.B, -h.K), good.total)  # det Ẑ_H gets a RHP root
    r, rb = crhp_report(good), crhp_report(bad)
    assert type(r) is CRHPReport
    assert assert_convention(r, CRHPStatus, (CRHPStatus.OK,)) is CRHPStatus.OK
    assert assert_convention(rb, CRHPStatus, (CRHPStatus.OK,)) is CRHPStatus.HAND
    assert rb.summary()["hand"] == int(rb.hand) > 0 and rb.summary()["total"] == 0
    c, cb = check_controller(good, warn=False), check_controller(bad, warn=False)
    assert type(c) is ControllerCheck
    assert assert_convention(c, ControllerStatus, (ControllerStatus.OK,)) is ControllerStatus.OK
    assert assert_convention(cb, ControllerStatus, (ControllerStatus.OK,)) \
        is ControllerStatus.UNSTABLE  # fmt: skip
    assert cb.summary()["n_crhp_hand_roots"] == int(rb.hand)


# ---- loops ------------------------------------------------------------------------------

OMEGA = np.geomspace(1e-2, 1e3, 200)


def _triple_lag(gain, n=2):
    """``L = gain/(s + 1)³ · I``: stable for gain < 8 (the critical gain), unstable above."""
    L = gain / (1j * OMEGA + 1.0) ** 3
    return L[:, None, None] * np.eye(n), np.broadcast_to(np.eye(n, dtype=complex), (len(L), n, n))


@pytest.mark.parametrize(("gain", "want"), [(2.0, LoopStatus.STABLE), (50.0, LoopStatus.UNSTABLE)])
def test_loop_metrics(gain, want):
    P, G = _triple_lag(gain, n=1)  # the convention does not depend on n; n = 1 compiles fastest
    m = loop_metrics(P, G, OMEGA, spec=MetricsSpec(disk=True))
    assert type(m) is LoopMetrics
    assert assert_convention(m, LoopStatus, (LoopStatus.STABLE,)) is want
    # non-finite numbers are null in summary() and kept by numbers() (for arithmetic)
    num, s = m.numbers(), m.summary()
    for k, v in num.items():
        if isinstance(v, float) and not np.isfinite(v):
            assert s[k] is None
    if want is LoopStatus.STABLE:  # GM of gain 2 vs critical 8: 20·log10(4)
        assert num["gm_db"] == pytest.approx(20 * np.log10(4.0), rel=1e-3)


def test_batched_loop_status_is_an_array_of_members():
    P2, G = _triple_lag(2.0)
    P50, _ = _triple_lag(50.0)
    # the verdict alone (pipeline.SPEC_VERDICT): the status is the point, not the metrics'
    # programs, whose compile would dominate this file
    rep = jax.vmap(lambda P: loop_metrics(P, G, OMEGA, spec=pipeline.SPEC_VERDICT))(
        np.stack([P2, P50])
    )
    st = rep.status
    assert st.shape == (2,) and all(type(x) is LoopStatus for x in st)
    assert list(st) == [LoopStatus.STABLE, LoopStatus.UNSTABLE] and list(st == "stable") == [
        True,
        False,
    ]
    s = rep.summary()
    _plain(s)
    assert s["status"] == ["stable", "unstable"] and s["ok"] == [True, False]


# ---- robust check, tuner, design, verdict -------------------------------------------------


def _robust(gm_db):
    ones = np.ones(20)
    return RobustReport(stable=ones.astype(bool), n_closed_loop_rhp=0 * ones, gm_db=gm_db * ones,
                        pm_deg=45 * ones, disk_margin=ones, disk_gm_db=ones, disk_pm_deg=ones,
                        iso_bandwidth_hz=ones, t_peak_db=ones)  # fmt: skip


def test_robust_report():
    ok = (Verdict.PASSED,)
    good, bad = _robust(10.0), _robust(3.0)  # GM requirement 6 dB
    assert assert_convention(good, Verdict, ok) is Verdict.PASSED and good.summary()["passed"]
    assert assert_convention(bad, Verdict, ok) is Verdict.FAILED and not bad.summary()["passed"]
    inf = _robust(np.inf)  # no phase crossover: an infinite GM quantile, null in JSON
    assert assert_convention(inf, Verdict, ok) is Verdict.PASSED
    assert inf.summary()["gm_db_q05"] is None and inf.numbers()["gm_db_q05"] == np.inf


def test_robust_report_draws():
    """The draw family a report was checked on (loop_gp_check's GP, parameter draws) is in
    its summary, after ``status`` and ``ok``."""
    rep = dataclasses.replace(_robust(10.0), draws={"draws": "params", "note": "x"})
    assert assert_convention(rep, Verdict, (Verdict.PASSED,)) is Verdict.PASSED
    assert list(rep.summary())[-3:] == ["status", "ok", "draws"]
    assert "draws" not in _robust(10.0).summary()


def test_robust_result(tmp_path, frf):
    """``robust_from_files`` on parameter draws: at best ``not established`` (parameter draws
    do not cover a model class that may be wrong), ``failed`` under an unmeetable PM."""
    res = fit_nls(frf, f_max_hz=None)
    rng = np.random.default_rng(1)
    theta = np.asarray(res.theta) + 1e-3 * rng.standard_normal((6, res.theta.shape[0]))
    names = tuple(param_names(2))
    io.save_samples(tmp_path / "s.npz", PosteriorSamples(theta, np.zeros(6), res.scale, 2, names))
    io.save_model(tmp_path / "m.npz", res.model)
    kw = dict(draws="params", max_samples=6, n_freq=60)
    ok = (Verdict.PASSED,)
    r = robust_from_files(tmp_path / "s.npz", tmp_path / "m.npz", tmp_path / "r.json", **kw)
    assert type(r) is RobustResult and r.device is None
    assert assert_convention(r, Verdict, ok) is Verdict.NOT_ESTABLISHED
    assert r.posterior.draws["draws"] == "params"
    assert json.loads((tmp_path / "r.json").read_text()) == io.jsonable(r.numbers())
    bad = robust_from_files(tmp_path / "s.npz", tmp_path / "m.npz", pm_deg=179.0, **kw)
    assert assert_convention(bad, Verdict, ok) is Verdict.FAILED


@pytest.mark.slow  # CI budget: two validations with time-domain steps (~20 s cold); validate is also in tests/test_tune.py
def test_validation_and_step_response():
    """``validate`` on a 2-rod device's true plant and in the time domain: the paper g meets
    6 dB / 30° (GM 16 dB, PM 60°), ten times its gain is unstable."""
    dev = second_order_device(2, seed=3, delay_samples=1)
    ok = (Verdict.PASSED,)
    v = validate(Compensator.paper(), dev.model, device=dev)
    assert type(v) is Validation and type(v.time_domain) is StepResponse
    assert assert_convention(v, Verdict, ok) is Verdict.PASSED
    assert v.summary()["true_plant"] == v.true_plant.summary() and v.posterior is None
    stable = (StepStatus.STABLE,)
    assert assert_convention(v.time_domain, StepStatus, stable) is StepStatus.STABLE
    bad = validate(scale_gain(Compensator.paper(), 10.0), dev.model, device=dev)
    assert assert_convention(bad, Verdict, ok) is Verdict.FAILED
    assert bad.verdicts() == {"true_plant": Verdict.FAILED, "time_domain": Verdict.FAILED}
    assert assert_convention(bad.time_domain, StepStatus, stable) is StepStatus.UNSTABLE
    assert assert_convention(Validation(), Verdict, ok) is Verdict.NOT_ESTABLISHED  # nothing


def test_tune_result():
    g = Compensator.paper()
    x = np.zeros(1)
    ok = (TuneStatus.FEASIBLE,)
    res = TuneResult(g, g, x, x, 12.0, 10.0, {"gm": -0.1, "pm": 0.2}, [], [], None, 1.0)
    assert assert_convention(res, TuneStatus, ok) is TuneStatus.INFEASIBLE  # pm > 0: not met
    assert res.summary()["constraints"]["pm"] == pytest.approx(0.2)
    met = TuneResult(g, g, x, x, 12.0, 10.0, {"gm": -0.1, "pm": -0.2}, [], [], None, 1.0,
                     training={"strict": (3, 3, 3)})  # fmt: skip
    assert assert_convention(met, TuneStatus, ok) is TuneStatus.FEASIBLE
    unstable = TuneResult(g, g, x, x, 12.0, 10.0, {"gm": -0.1}, [], [], None, 1.0,
                          training={"strict": (2, 3, 3)})  # fmt: skip
    assert assert_convention(unstable, TuneStatus, ok) is TuneStatus.UNSTABLE_ON_TRAINING


def test_robust_design_and_decision():
    """robust_design's result: the returned design's verdict is its status (not established
    when it was not re-checked), the Decision says which g and is strict JSON."""
    g = Compensator.paper()
    x = np.zeros(1)
    res = TuneResult(g, g, x, x, 12.0, 10.0, {"gm": -0.1}, [], [], None, 1.0)
    kept = Decision(Choice.START, "kept the start: no improvement", "held out")
    ok = (Verdict.PASSED,)
    unchecked = RobustDesign(res, res, kept, {"device": {"train": 3}})
    assert assert_convention(unchecked, Verdict, ok) is Verdict.NOT_ESTABLISHED
    assert unchecked.kept_start and unchecked.returned_row == {}
    assert unchecked.summary()["decision"] == {"choice": "start", "rule": "held out",
                                               "reason": kept.reason, "gain_scale": 1.0}  # fmt: skip
    for verdict in Verdict:
        check = Check(verdict, reason="" if verdict is Verdict.PASSED else "why", name="GM")
        d = RobustDesign(dataclasses.replace(res, check=check), res,
                         Decision(Choice.TUNED, "tuned g kept", "held out"), {},
                         {"start": {"a": 1.0}, "tuned": {"a": 2.0}})  # fmt: skip
        assert assert_convention(d, Verdict, ok) is verdict
        assert not d.kept_start and d.returned_row == {"a": 2.0}


def test_certificate_and_binding():
    """The evidence certificate fails exactly when the loop gain beyond the FRF exceeds κ
    (the model measured as it is, so every in-band figure is clean: closed form
    ``max |g| · m``, m = 1); the binding report is violated exactly when a constraint is."""
    from hapid._constants import TWO_PI
    from hapid.tune import (
        Family,
        Requirements,
        binding_constraints,
        certificate,
        evidence_from_frf,
        make_scenarios,
    )

    m = example_model(2, 0)
    om = TWO_PI * np.geomspace(1.0, 40.0, 30)
    ev = evidence_from_frf({"omega": om, "Z_H": np.asarray(m.Z_H(1j * om)),
                            "Z_T": np.asarray(m.Z_T(1j * om))}, m)  # fmt: skip
    g = Compensator.paper()
    ok = (Verdict.PASSED,)
    for a in (1e-2, 1.0, 1e2):
        c = certificate(ev, m, scale_gain(g, a))
        assert type(c) is Certificate and c.mismatch_bound == 1.0
        want = Verdict.PASSED if c.beyond_loop_gain <= 0.5 else Verdict.FAILED
        assert assert_convention(c, Verdict, ok) is want
        assert {k: v for k, v in c.summary().items() if k not in ("status", "ok")} == c.figures()
    assert certificate(ev, m, scale_gain(g, 1e-2)).ok and not certificate(ev, m, g).ok
    omg = TWO_PI * np.geomspace(0.1, 200.0, 200)
    fam = Family(make_scenarios(np.asarray(m.P(1j * omg)), m, omg), quantile=1.0, name="plant")
    dc = abs(complex(g(np.array([0.0]))[0]))
    met = (BindingStatus.MET,)
    for floor, want in ((0.5 * dc, BindingStatus.MET), (2.0 * dc, BindingStatus.VIOLATED)):
        b = binding_constraints(g, [fam], Requirements(min_dc_gain=floor), f_max_hz=1000.0)
        assert type(b) is Binding and assert_convention(b, BindingStatus, met) is want
        assert b["g/dc"].value == pytest.approx(np.log(floor / dc))
        assert b.summary()["constraints"]["g/dc"]["dc_gain"] == pytest.approx(dc)


def test_design_report_and_check(tmp_path):
    passed, failed = (
        Check(Verdict.PASSED, name="GM"),
        Check(Verdict.FAILED, reason="low", name="PM"),
    )
    ok = (DesignStatus.PASSED,)
    for checks, want in (((passed,), DesignStatus.PASSED), ((passed, failed), DesignStatus.FAILED),
                         ((), DesignStatus.NO_CONTROLLER)):  # fmt: skip
        rep = DesignReport(tmp_path, checks, {"fits": {}}, ())
        assert assert_convention(rep, DesignStatus, ok) is want
    for c in (passed, failed):
        assert assert_convention(c, Verdict, (Verdict.PASSED,)) is c.verdict


# ---- posterior samples and plant draws ----------------------------------------------------


def test_posterior_samples_and_plant_draws(frf):
    res = fit_nls(frf, f_max_hz=None)
    rng = np.random.default_rng(1)
    theta = np.asarray(res.theta) + 1e-3 * rng.standard_normal((6, res.theta.shape[0]))
    names = tuple(param_names(2))
    ps = PosteriorSamples(theta, np.zeros(6), res.scale, 2, names, {"method": "laplace"})
    ok = (SamplesStatus.CONVERGED,)
    assert assert_convention(ps, SamplesStatus, ok) is SamplesStatus.CONVERGED
    assert ps.summary()["n_samples"] == 6 and ps.report().startswith("laplace: 6 samples")
    stuck = PosteriorSamples(theta, np.zeros(6), res.scale, 2, names, {"converged_50tau": False})
    assert assert_convention(stuck, SamplesStatus, ok) is SamplesStatus.NOT_CONVERGED
    d = plant_draws(ps, OMEGA[::20], draws="params")
    assert type(d) is PlantDraws
    assert assert_convention(d, DrawsStatus, (DrawsStatus.OK,)) is DrawsStatus.OK
    P = np.array(d.P)
    P[0, 0, 0, 0] = np.nan
    bad = PlantDraws(d.omega, P, None, None, d.draws, d.model_error)
    assert assert_convention(bad, DrawsStatus, (DrawsStatus.OK,)) is DrawsStatus.NON_FINITE


def test_band_calibration():
    """Draws of a circular complex Gaussian at 300 frequencies: a truth from the same
    distribution is inside the 90 % ball at about 90 % of them (calibrated); a truth 10
    standard deviations away at none (overconfident)."""
    rng = np.random.default_rng(0)
    cz = lambda *s: (rng.standard_normal(s) + 1j * rng.standard_normal(s)) / np.sqrt(2)  # noqa: E731
    draws = cz(400, 300, 1, 1)
    good = band_calibration(draws, cz(300, 1, 1))
    assert type(good) is BandCalibration and good.goal == pytest.approx(0.85)
    ok = (CalibrationStatus.CALIBRATED,)
    assert assert_convention(good, CalibrationStatus, ok) is CalibrationStatus.CALIBRATED
    off = band_calibration(draws, 10.0 + cz(300, 1, 1))
    assert assert_convention(off, CalibrationStatus, ok) is CalibrationStatus.OVERCONFIDENT
    assert off.summary()["coverage"] == 0.0 and off.figures()["coverage"] == off.coverage
    assert list(good.figures()) == list(good.summary())[4:]  # status, ok, level, goal first


def test_laplace_posterior(frf):
    """The Laplace approximation of the 2-rod posterior: BFGS converges from the NLS optimum,
    and does not in one step."""
    res = fit_nls(frf, f_max_hz=None)
    post = make_log_posterior(frf, res.scale, f_max_hz=None, model_error=NoError())
    x0 = initial_point(post, res)
    lp = laplace_posterior(post, x0)
    assert type(lp) is LaplacePosterior and lp.cov.shape == (post.dim, post.dim)
    ok = (ModeStatus.CONVERGED,)
    assert assert_convention(lp, ModeStatus, ok) is ModeStatus.CONVERGED
    assert lp.summary()["dim"] == post.dim and lp.info()["converged"] is True
    short = laplace_posterior(post, x0 + 0.1, max_steps=1)
    assert assert_convention(short, ModeStatus, ok) is ModeStatus.NOT_CONVERGED


def test_pose_study():
    """A pose study passes exactly when the home-pose controller passes at every pose (built
    from rows: :func:`hapid.uncertainty.pose_study` itself runs for minutes)."""
    good = PoseLoop(True, 8.0, 45.0, 0.6, 5.0, 30.0, 2.5, 1.0, True)
    nan = float("nan")
    bad = good._replace(stable=False, iso_bandwidth_hz=nan, t_peak_db=nan, passed=False)
    home = PoseRow(0.0, 0.0, 0.0, good, good, FitStatus.CONVERGED)
    ok = (Verdict.PASSED,)
    assert assert_convention(PoseStudy((home,)), Verdict, ok) is Verdict.PASSED
    far = PoseRow(0.04, 0.0, 0.0, bad, good, FitStatus.CONVERGED)
    study = PoseStudy((home, far))
    assert assert_convention(study, Verdict, ok) is Verdict.FAILED
    s = study.summary()
    assert s["n_poses"] == len(study) == 2 and s["nominal_passed"] == 1 and study[1] is far
    assert s["rows"][1]["nominal_iso_bandwidth_hz"] is None
    assert s["rows"][1]["fit_status"] == "converged" and s["rows"][1]["reidentified_passed"]
    only = PoseStudy((PoseRow(0.0, 0.0, 0.0, good),))  # no re-identification
    assert "fit_status" not in only.summary()["rows"][0]


# ---- every public result type is covered ---------------------------------------------------

RESULT_TYPES = {
    NLSResult: FitStatus, ImpedanceFit: FitStatus, pipeline.Fit: FitStatus,
    FitQuality: QualityStatus, CRHPReport: CRHPStatus, ImpedanceEstimate: EstimateStatus,
    ControllerCheck: ControllerStatus, LoopMetrics: LoopStatus,
    RobustReport: Verdict, TuneResult: TuneStatus, PosteriorSamples: SamplesStatus,
    PlantDraws: DrawsStatus, DesignReport: DesignStatus, Check: Verdict,
    pipeline.ControlFit: FitStatus, SceneRun: SceneStatus, RobustResult: Verdict,
    Validation: Verdict, StepResponse: StepStatus, RobustDesign: Verdict, EstimatorFits: FitStatus,
    SweepResult: SweepStatus, SweepPoint: LoopStatus, PaperSummary: PaperStatus,
    PerfectControlWall: EquilibriumStatus, WallSteadyState: ContactStatus,
    WallRun: ContactStatus, WallMetrics: ContactStatus,
}  # fmt: skip
RESULT_TYPES |= {Certificate: Verdict, Binding: BindingStatus}  # the tuner's evidence reports
RESULT_TYPES |= {BandCalibration: CalibrationStatus, LaplacePosterior: ModeStatus,
                 PoseStudy: Verdict}  # fmt: skip


def test_every_result_type_has_status_ok_summary():
    assert issubclass(MLResult, NLSResult)  # fit_ml's result: NLSResult's status and summary
    for cls, enum_cls in RESULT_TYPES.items():
        assert issubclass(enum_cls, enum.StrEnum), enum_cls
        fields = (
            {f.name for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else set()
        )
        for attr in ("ok", "status", "summary"):
            assert hasattr(cls, attr) or attr in fields, f"{cls.__name__} has no {attr}"
