"""Inverse-model controller: realization, realizability verdict, SISO gain design."""

import jax.numpy as jnp
import numpy as np
import pytest
from oracle_loop import analyze_loop
from oracles import example_model

import hapid  # noqa: F401  (float64)
from hapid import ImpedanceModel, SecondOrder
from hapid.control import (
    Compensator,
    ControllerWarning,
    check_controller,
    controller_is_stable,
    controller_unstable_poles,
    inverse_model_response,
    inverse_model_state_space,
    max_siso_gain,
    siso_response,
)

W = np.logspace(-1, 3.5, 1200)


def test_state_space_realization_matches_frequency_response():
    m, g = example_model(5, seed=0), Compensator.paper()
    ss = inverse_model_state_space(m, g)
    assert ss.n_states == 5 * (g.order + 2)
    G = np.asarray(inverse_model_response(m, g, W))
    Gs = np.asarray(ss.at_omega(W))
    err = np.linalg.norm(Gs - G, 2, axis=(1, 2)) / np.linalg.norm(G, 2, axis=(1, 2))
    assert err.max() < 1e-10
    assert bool(controller_is_stable(m, g)) and bool(ss.is_stable())
    chk = check_controller(m, g)
    assert chk.stable and chk.minimum_phase


def test_crhp_hand_model_flags_unstable_controller():
    m = example_model(3, seed=2)
    K = np.asarray(m.hand.K).copy()
    K[0, 0] = -400.0  # an indefinite stiffness: det Ẑ_H gets a real RHP root
    hand = SecondOrder(m.hand.M, m.hand.B, K)
    bad = ImpedanceModel(hand=hand, total=m.total)
    assert not bool(controller_is_stable(bad))
    assert int(controller_unstable_poles(bad)) >= 1
    with pytest.warns(ControllerWarning, match="UNSTABLE"):
        chk = check_controller(bad, Compensator.paper())
    assert not chk.stable and chk.n_crhp_hand_roots >= 1
    # the realization is unstable too (its poles are the roots of det Ẑ_H)
    assert not bool(inverse_model_state_space(bad, Compensator.paper()).is_stable())
    # a singular M̂_H (roots at infinity) is not accepted as stable either
    sing = ImpedanceModel(hand=SecondOrder(np.zeros((3, 3)), m.hand.B, m.hand.K), total=m.total)
    assert not bool(controller_is_stable(sing))


def test_non_minimum_phase_total_model_warns():
    m = example_model(3, seed=4)
    B = np.asarray(m.total.B).copy()
    B[1, 1] = -200.0
    bad = ImpedanceModel(hand=m.hand, total=SecondOrder(m.total.M, B, m.total.K))
    with pytest.warns(ControllerWarning, match="non-minimum phase"):
        chk = check_controller(bad)
    assert chk.stable and not chk.minimum_phase


def test_max_siso_gain_sits_on_the_margin_boundary():
    truth, g = example_model(3, seed=5), Compensator.paper()
    w = jnp.logspace(-1, 3.7, 3000)
    P = truth.P(1j * w)
    c = float(max_siso_gain(P, w, g, gm_db=6.0, pm_deg=30.0))
    assert np.isfinite(c) and c > 0

    def worst(cc):
        r = analyze_loop(P, siso_response(g, w, 3, cc), w)
        return bool(r.stable), abs(float(r.gm_db)), abs(float(r.pm_deg))

    st, gm, pm = worst(c * (1 - 1e-6))
    assert st and gm >= 6.0 - 1e-3 and pm >= 30.0 - 1e-3
    st, gm, pm = worst(c * 1.01)
    assert (not st) or gm < 6.0 or pm < 30.0
