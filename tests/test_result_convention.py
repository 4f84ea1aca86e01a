"""One result convention: every result object exposes ``ok``, ``status`` and ``summary()``,
and they agree with the object's own verdict fields."""

import json

import numpy as np
import pytest
from oracles import example_model

from hapid import io
from hapid.control import Compensator, analyze_loop, check_controller
from hapid.fit import crhp_report
from hapid.impedance import ImpedanceModel, SecondOrder
from hapid.tune._tune import TuneResult
from hapid.uncertainty._robust import RobustReport


def _loop(gain):
    omega = np.geomspace(1e-2, 1e3, 300)
    L = gain / (1j * omega + 1.0) ** 3  # triple lag: critical gain 8
    P = L[:, None, None] * np.eye(2)
    return analyze_loop(P, np.broadcast_to(np.eye(2, dtype=complex), P.shape), omega)


@pytest.mark.parametrize(("gain", "status"), [(2.0, "stable"), (50.0, "unstable")])
def test_loop_report(gain, status):
    rep = _loop(gain)
    assert rep.status == status and bool(rep.ok) == (status == "stable") == rep.summary()["stable"]


def test_controller_check_and_crhp_report():
    good = example_model(3, seed=0)
    chk = check_controller(good, warn=False)
    assert chk.ok and chk.status == "ok" and chk.summary()["n_crhp_hand_roots"] == 0
    assert bool(crhp_report(good).ok) and crhp_report(good).status == "ok"
    # negate the hand's stiffness: det Ẑ_H gets a real positive root → unstable controller
    h = good.hand
    bad = ImpedanceModel(SecondOrder(h.M, h.B, -h.K), good.total)
    chk = check_controller(bad, warn=False)
    assert not chk.ok and chk.status.startswith("unstable") and chk.n_crhp_hand_roots > 0
    r = crhp_report(bad)
    assert not bool(r.ok) and "det Ẑ_H" in r.status and r.summary()["hand"] == int(r.hand) > 0


def test_robust_report_and_tune_result():
    S = 20
    ones = np.ones(S)
    rep = RobustReport(stable=ones.astype(bool), n_closed_loop_rhp=0 * ones, gm_db=10 * ones, pm_deg=45 * ones,
                       disk_margin=ones, disk_gm_db=ones, disk_pm_deg=ones, iso_bandwidth_hz=ones, t_peak_db=ones)  # fmt: skip
    assert rep.ok and rep.status == "passed" and rep.summary()["passed"]
    rep2 = RobustReport(**{**rep.__dict__, "gm_db": 3 * ones})
    assert not rep2.ok and rep2.status == "failed"
    g = Compensator.paper()
    x = np.zeros(1)
    res = TuneResult(g, g, x, x, 12.0, 10.0, {"gm": -0.1, "pm": 0.2}, [], [], None, 1.0)
    assert not res.ok and res.status == "infeasible"
    s = res.summary()
    assert s["constraints"]["pm"] == pytest.approx(0.2) and s["bandwidth_hz"] == 12.0
    json.loads(io.to_json(s))


def test_every_result_class_has_ok_status_summary():
    from hapid.control import ControllerCheck, LoopReport
    from hapid.fit import NLSResult
    from hapid.fit._positize import CRHPReport
    from hapid.fit._quality import FitQuality
    from hapid.uncertainty import PosteriorSamples

    for cls in (
        NLSResult,
        FitQuality,
        CRHPReport,
        ControllerCheck,
        LoopReport,
        RobustReport,
        TuneResult,
        PosteriorSamples,
    ):
        for attr in ("ok", "status", "summary"):
            assert hasattr(cls, attr), f"{cls.__name__} has no {attr}"
