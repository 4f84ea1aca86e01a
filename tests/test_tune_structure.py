"""Tuned structure of g(s) (issue 14): richer templates and the binding-constraint diagnosis.

- :func:`hapid.tune.extend_structure` adds terms that leave g's response unchanged (a tuner
  start identical to the paper g), and rejects bad frequencies.
- :func:`hapid.tune.binding_constraints` finds limits imposed on purpose: a resonance of the
  plant at a known frequency (the loci disc binds there), a |g(0)| floor above g's, a
  small-gain level below |g| beyond the data, a parameter at the box's edge — checked against
  a direct numpy evaluation.
- (slow) A richer template continued from the tuned paper g does no worse than the paper form
  on the plant it is tuned on, judged by the non-smooth analysis
  (:func:`oracle_loop.analyze_loop`).
"""

from __future__ import annotations

from math import tau as TWO_PI

import numpy as np
import pytest
from oracle_loop import analyze_loop

from hapid.control import Compensator, inverse_model_response
from hapid.tune import (
    Family,
    ParamMap,
    Requirements,
    binding_constraints,
    extend_structure,
    make_scenarios,
    tune,
)
from tests.helpers import random_model

F_BUMP = 12.0  # Hz: the imposed resonance of the synthetic plant


def _model(n=2, seed=0):
    return random_model(n, seed)


def _bump(om, f=F_BUMP, zn=0.3, zd=0.02):
    """A resonant gain bump (×zn/zd = 15 at ``f``) times a 1 ms delay: what the model misses."""
    w, s = TWO_PI * f, 1j * om
    return (s**2 + 2 * zn * w * s + w**2) / (s**2 + 2 * zd * w * s + w**2) * np.exp(-s * 1e-3)


@pytest.fixture(scope="module")
def plant():
    model = _model()
    om = TWO_PI * np.geomspace(1e-3, 300.0, 240)
    Ph = np.asarray(model.P(1j * om))
    P = _bump(om)[:, None, None] * Ph  # Q = P P̂⁻¹ = bump · I
    return model, om, P


def test_extend_structure_starts_at_the_same_response_and_rejects_bad_input():
    g = Compensator.paper()
    h = extend_structure(g, lag_hz=[20.0, 3.0], notch_hz=[9.0])
    om = TWO_PI * np.geomspace(0.01, 499.0, 300)
    np.testing.assert_allclose(np.asarray(h.at_omega(om)), np.asarray(g.at_omega(om)), rtol=1e-12)
    assert abs(complex(h(np.array([0.0]))[0])) == pytest.approx(abs(complex(g(np.array([0.0]))[0])))
    pm, pm0 = ParamMap.from_template(h), ParamMap.from_template(g)
    assert pm.dim == pm0.dim + 2 * 2 + 3 * 1
    assert h.order == g.order + 2 + 2
    x = pm.vector(h)
    np.testing.assert_allclose(
        np.asarray(pm.compensator(x).at_omega(om)), np.asarray(h.at_omega(om))
    )
    assert extend_structure(g).order == g.order
    for bad in ({"lag_hz": [0.0]}, {"notch_hz": [-3.0]}, {"lag_hz": [np.nan]}):
        with pytest.raises(ValueError, match="extend_structure"):
            extend_structure(g, **bad)


def test_binding_constraints_find_imposed_limits(plant):
    model, om, P = plant
    g = Compensator.paper()
    sc = make_scenarios(P, model, om)
    fam = Family(sc, quantile=1.0, name="plant")
    dc = abs(complex(g(np.array([0.0]))[0]))
    sg = TWO_PI * np.geomspace(150.0, 300.0, 20)
    g_sg = np.abs(np.asarray(g.at_omega(sg)))
    req = Requirements(min_dc_gain=2.0 * dc, sg_omega=tuple(sg), sg_g_max=0.5 * float(g_sg.max()))
    # a low-pass pole 1 % above the box's top (f_max 150 Hz)
    g2 = Compensator.paper(lowpass=[100.0 * TWO_PI, 1.01 * 150.0 * TWO_PI])
    b = binding_constraints(g2, [fam], req, f_max_hz=150.0, constraints={"g/dc": 0.002}, mu=1e4)
    assert b["g/dc"].active and b["g/dc"].value == pytest.approx(np.log(2.0))
    assert b["g/dc"].multiplier == pytest.approx(40.0)
    assert b["evidence/small_gain"].active
    assert b["evidence/small_gain"].value == pytest.approx(np.log(2.0) + np.log(
        np.abs(np.asarray(g2.at_omega(sg))).max() / g_sg.max()), abs=1e-12)  # fmt: skip
    assert b["box"].active and b["box"].parameter == "low-pass 2"
    assert b["box"].edge == "upper" and b["box"].value == pytest.approx(np.log(1.01))
    # the loci disc: worst where the imposed resonance sits, value = direct numpy evaluation
    ms = req.ms
    lam = np.linalg.eigvals(P @ np.linalg.inv(np.asarray(model.P(1j * om))))
    G = np.asarray(inverse_model_response(model, g2, om))
    dist = np.abs(1 + np.linalg.eigvals(P @ G)).min(axis=1)
    assert np.allclose(lam, _bump(om)[:, None])
    e = b["plant/ms"]
    assert e.active and e.value == pytest.approx(-np.log(dist.min() * ms), rel=1e-9)
    assert e.where_hz[0] == pytest.approx(om[dist.argmin()] / TWO_PI)
    assert 0.5 * F_BUMP < e.where_hz[0] < 2.0 * F_BUMP  # at the imposed resonance
    # slack constraints are reported slack
    loose = Requirements(min_dc_gain=0.5 * dc)
    assert not binding_constraints(g, [fam], loose, f_max_hz=150.0)["g/dc"].active


@pytest.mark.slow
def test_richer_template_continued_from_the_tuned_paper_g_does_no_worse():
    """The recipe of docs/robust-design.md: tune the paper form, then add a lag/lead pair and
    a notch (identity at the start, :func:`extend_structure`) to the *tuned* g and continue on
    the same scenarios. The richer design meets the margins on the non-smooth analysis
    (:func:`analyze_loop`) and reaches at least the paper form's bandwidth. ~60 s on 2 cores.
    (A cold start of the richer template is not monotone: measured here with a
    (100, 1e4) schedule, the richer template ended with its smooth margin constraint violated.)"""
    model = _model()
    om = TWO_PI * np.geomspace(1e-3, 3000.0, 300)  # the loop rolls off inside the grid
    P = _bump(om, zd=0.06)[:, None, None] * np.asarray(model.P(1j * om))
    fam = Family(make_scenarios(P, model, om), quantile=1.0, name="plant")
    g0 = Compensator.paper()
    req = Requirements(min_dc_gain=abs(complex(g0(np.array([0.0]))[0])))
    r1 = tune([fam], g0, requirements=req, mu_schedule=(100.0, 1e4), max_steps=150)
    tpl = extend_structure(r1.g, lag_hz=[8.0], notch_hz=[F_BUMP])
    r2 = tune([fam], tpl, requirements=req, mu_schedule=(1e3, 1e4), max_steps=150)
    assert r1.feasible and r2.feasible, (r1.constraints, r2.constraints)
    assert r2.bandwidth_hz >= r1.bandwidth_hz
    bw = []
    for r in (r1, r2):
        rep = analyze_loop(P, np.asarray(inverse_model_response(model, r.g, om)), om)
        assert bool(rep.stable)
        assert float(rep.gm_db) >= 6.0 - 0.3 and abs(float(rep.pm_deg)) >= 30.0 - 1.0
        bw.append(float(rep.iso_bandwidth_hz))
    assert bw[1] >= 0.98 * bw[0], bw


@pytest.mark.parametrize("flag", ["--extra-lag", "--extra-notch"])
def test_cli_rejects_a_non_positive_added_frequency(tmp_path, flag):
    from helpers_cli import assert_clean_error, write_valid_files

    write_valid_files(tmp_path)
    argv = ["tune", "--model", "model.npz", "--device", "cu5", flag, "20", "0", "--out", "d.npz"]
    assert_clean_error(argv, tmp_path, f"{flag} must be one or more frequencies > 0 Hz, got 20 0")
