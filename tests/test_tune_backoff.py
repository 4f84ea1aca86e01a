"""Gain back-off (hapid.tune._tune.gain_backoff): from a start that leaves training plants
unstable the tuner first lowers the loop gain until every strict scenario is stable, then
tunes; checked against analyze_loop (the reference Nyquist analysis) on every plant."""

from math import tau as TWO_PI

import numpy as np
import pytest
from oracle_loop import analyze_loop

from hapid.control import Compensator, inverse_model_response
from hapid.tune import Family, Requirements, make_scenarios, tune
from hapid.tune._tune import gain_backoff
from tests.test_tune import TS, _model


@pytest.fixture(scope="module")
def case():
    """n = 2 model; 3 jittered plants with 3 samples of delay; the paper g with 8× its gain,
    which leaves them unstable."""
    n = 2
    model = _model(n, 0)
    om = TWO_PI * np.geomspace(1e-3, 450.0, 400)
    delay = np.exp(-3j * om * TS)[:, None, None]
    P = np.stack([np.asarray(_model(n, 0, jitter=0.03 * (k + 1)).P(1j * om)) for k in range(3)])
    g0 = Compensator.paper(k=8.0 * float(Compensator.paper().k))
    return model, om, P * delay, g0


def _stable(model, g, P, om):
    G = np.asarray(inverse_model_response(model, g, om))
    return [bool(analyze_loop(P[k], G, om).stable) for k in range(P.shape[0])]


def test_backoff_finds_a_gain_that_stabilizes_every_scenario(case):
    model, om, P, g0 = case
    fam = Family(make_scenarios(P, model, om), quantile=1.0)
    assert not all(_stable(model, g0, P, om))  # the case needs an unstable start
    g1, alpha = gain_backoff(g0, [fam], Requirements().ms)
    assert 0.0 < alpha < 1.0
    assert float(g1.k) == pytest.approx(alpha * float(g0.k))
    assert all(_stable(model, g1, P, om))
    # the start meets the disc (margins) on the grid: the reference's margins agree
    G = np.asarray(inverse_model_response(model, g1, om))
    for k in range(P.shape[0]):
        rep = analyze_loop(P[k], G, om)
        assert float(rep.gm_db) >= 6.0 - 0.3 and float(rep.pm_deg) >= 30.0 - 1.0
    # a stable start is left alone
    assert gain_backoff(g1, [fam]) == (g1, 1.0)


def test_tune_from_an_unstable_start_returns_a_stable_design_with_margins(case):
    model, om, P, g0 = case
    fam = Family(make_scenarios(P, model, om), quantile=1.0, name="train")
    res = tune([fam], g0, mu_schedule=(100.0, 1e4), max_steps=150)
    assert res.gain_backoff < 1.0 and res.feasible, res.constraints
    G = np.asarray(inverse_model_response(model, res.g, om))
    for k in range(P.shape[0]):
        rep = analyze_loop(P[k], G, om)
        assert bool(rep.stable)
        assert float(rep.gm_db) >= 6.0 - 0.3 and float(rep.pm_deg) >= 30.0 - 1.0
