"""Grid exchange (hapid.tune._exchange): the margin constraint holds between the training
grid's points. Synthetic scenarios with a lightly damped resonance placed between two
training frequencies at the loop's phase crossover: without the dense grid the tuner is
fooled (its loci enter the 1/M_s disc there), with it the dense constraint is met."""

from math import tau as TWO_PI

import numpy as np
import pytest
from oracle_loop import analyze_loop

from hapid.control import Compensator, inverse_model_response
from hapid.tune import Family, Requirements, make_scenarios, tune
from hapid.tune._exchange import TOL, locus_violation, merge_freqs, violations
from tests.test_tune import TS, _model

N_TRAIN, FACTOR = 120, 16  # dense spacing 0.7 %: resolves the ζ = 1 % mode
TARGET = 0.8  # |locus| at the resonance: inside the 1/M_s disc around −1


def _resonant(om, f_r, c, zeta=1e-2):
    s, w = 1j * om, TWO_PI * f_r
    return 1.0 + c * (2 * zeta * w * s) / (s * s + 2 * zeta * w * s + w * w)


@pytest.fixture(scope="module")
def case():
    """n = 2 model; 3 plants = jittered models × one sample of delay × a sharp resonance
    (ζ = 1 %) half-way between two training points near the paper g's phase crossover,
    with a gain that takes the locus through −1 there."""
    n = 2
    model = _model(n, 0)
    om_tr = TWO_PI * np.geomspace(1e-3, 5000.0, N_TRAIN)
    om_d = TWO_PI * np.geomspace(1e-3, 5000.0, FACTOR * (N_TRAIN - 1) + 1)
    plants = [_model(n, 0, jitter=0.03 * (k + 1)) for k in range(3)]

    def P_of(om, f_r=None, c=0.0):
        P = (
            np.stack([np.asarray(m.P(1j * om)) for m in plants])
            * np.exp(-1j * om * TS)[:, None, None]
        )
        return P if f_r is None else P * _resonant(om, f_r, c)[:, None, None]

    # the paper g's phase crossover of the nominal-ish loci (largest |ℓ| with phase ≈ −180°)
    g = Compensator.paper()
    G = np.asarray(inverse_model_response(model, g, om_d))
    lam = np.linalg.eigvals(P_of(om_d)[0] @ G)
    ang = np.angle(lam)
    k = np.argmin(np.abs(np.abs(ang) - np.pi).min(axis=1) + (om_d < TWO_PI * 5.0) * 10)
    j = np.searchsorted(om_tr, om_d[k])
    f_r = np.sqrt(om_tr[j - 1] * om_tr[j]) / TWO_PI  # half-way (log) between two training points
    c = TARGET / np.abs(lam[k]).max() - 1.0
    sc_tr = make_scenarios(P_of(om_tr, f_r, c), model, om_tr)
    sc_d = make_scenarios(P_of(om_d, f_r, c), model, om_d)
    return model, om_d, lambda om: P_of(om, f_r, c), sc_tr, sc_d, f_r


def test_violations_find_the_mode_between_points_and_merge_is_exact(case):
    model, om_d, P, sc_tr, sc_d, f_r = case
    fam = Family(sc_tr, quantile=1.0, dense=sc_d)
    ms = Requirements().ms
    g = Compensator.paper()
    idx = violations(g, fam, ms)
    assert idx.size >= 1
    # the dense points added sit at the resonance (within its few half-power widths)
    assert np.min(np.abs(np.log(om_d[idx] / (TWO_PI * f_r)))) < 0.02
    v_tr, v_d = locus_violation(g, sc_tr, ms), locus_violation(g, sc_d, ms)
    assert v_d.max() > max(v_tr.max(), 0.0) + TOL  # the training grid misses it
    merged = merge_freqs(sc_tr, sc_d, idx)
    om_m = np.asarray(merged.omega)
    assert np.all(np.diff(om_m) > 0) and om_m.size == np.asarray(sc_tr.omega).size + idx.size
    # merged entries are the dense scenarios' own (no recomputation, same order)
    pos = np.searchsorted(om_m, om_d[idx])
    np.testing.assert_array_equal(np.asarray(merged.lam)[:, pos], np.asarray(sc_d.lam)[:, idx])
    # after the merge the training grid sees the dense worst case
    assert locus_violation(g, merged, ms).max() == pytest.approx(v_d.max(), abs=TOL)


@pytest.mark.slow
def test_tune_with_dense_grid_meets_margins_between_training_points(case):
    model, om_d, P, sc_tr, sc_d, f_r = case
    ms = Requirements().ms
    opts = dict(mu_schedule=(100.0, 1e4), max_steps=120)
    fooled = tune([Family(sc_tr, quantile=1.0, name="train")], Compensator.paper(), **opts)
    fixed = tune(
        [Family(sc_tr, quantile=1.0, name="train", dense=sc_d)], Compensator.paper(), **opts
    )
    # without the dense grid the design misses the resonance (else this case shows nothing)
    assert locus_violation(fooled.g, sc_d, ms).max() > TOL
    # (whether points were added depends on the path: the guard counts on the dense grid too)
    assert fixed.feasible
    assert locus_violation(fixed.g, sc_d, ms).max() <= TOL
    # the non-smooth reference on a 20 000-point grid: margins met on every training plant
    om_ref = TWO_PI * np.geomspace(1e-3, 5000.0, 20000)
    G, P_ref = np.asarray(inverse_model_response(model, fixed.g, om_ref)), P(om_ref)
    for k in range(P_ref.shape[0]):
        rep = analyze_loop(P_ref[k], G, om_ref)
        assert bool(rep.stable)
        assert float(rep.gm_db) >= 6.0 - 0.3 and float(rep.pm_deg) >= 30.0 - 1.0
