"""fit_nls's PD floor (``pd_eps = PD_EPS``, fit_ml's default): no closed-RHP root of det Ẑ
when the hand is singular (a hand acting in a subspace of the rods, as on hexapod6)."""

import numpy as np
import pytest
from helpers_fit import random_truth, synthetic_frf

import hapid  # noqa: F401
from hapid.fit import crhp_report, fit_nls, nls_cost, theta_to_model
from hapid.fit._problem import PD_EPS
from hapid.impedance import ImpedanceModel, SecondOrder, plant


def _subspace_hand_truth(seed=5):
    """3 rods, a hand whose M, B, K all vanish along (1, 1, 1)/√3 (singular Z_H)."""
    t = random_truth(3, seed)
    v = np.ones(3) / np.sqrt(3)
    Pr = np.eye(3) - np.outer(v, v)
    hand = SecondOrder(*(Pr @ np.asarray(A) @ Pr for A in (t.hand.M, t.hand.B, t.hand.K)))
    return ImpedanceModel.from_hand_mechanism(hand, t.mechanism)


def _max_real_root(so: SecondOrder) -> float:
    r = np.asarray(so.roots())
    return float(np.max(np.where(np.isfinite(r), r.real, np.inf)))


def test_pd_floor_keeps_a_singular_hand_free_of_crhp_roots():
    truth = _subspace_hand_truth()
    frf = synthetic_frf(truth, rel_noise=1e-2, seed=15)
    w = np.asarray(frf.omega)
    P_true = np.asarray(plant(truth.hand.at_omega(w), truth.total.at_omega(w)))
    bare = fit_nls(frf, pd_eps=0.0)
    res = fit_nls(frf, pd_eps=PD_EPS)
    assert bare.ok and res.ok
    # the case exercises the boundary: the bare L Lᵀ fit puts the hand on it, with a root
    # of det Ẑ_H in the closed RHP (at s = 0 or ∞)
    assert "M_H" in bare.boundary and int(crhp_report(bare.model).hand) >= 1
    # the floored fit: its L Lᵀ part is on the same boundary, yet every matrix is PD and all
    # roots are finite and strictly in the left half plane
    assert "M_H" in res.boundary
    c = crhp_report(res.model)
    assert int(c.hand) == 0 and int(c.total) == 0
    assert _max_real_root(res.model.hand) < 0 and _max_real_root(res.model.total) < 0
    for A in (res.model.hand.M, res.model.hand.B, res.model.hand.K):
        assert np.linalg.eigvalsh(np.asarray(A))[0] > 0
    # and the floor does not cost accuracy: the plant error against the true (singular) plant
    # over 1–30 Hz is no larger (P·P̂⁻¹ has a zero singular value here, so no dB band)
    band = np.asarray(frf.freq_hz) <= 30.0

    def plant_err(m):
        Ph = np.asarray(plant(m.hand.at_omega(w), m.total.at_omega(w)))
        e = np.linalg.norm(Ph - P_true, axis=(-2, -1)) / np.linalg.norm(P_true, axis=(-2, -1))
        return float(np.max(e[band]))

    assert plant_err(res.model) <= 1.05 * plant_err(bare.model), (
        plant_err(res.model),
        plant_err(bare.model),
    )
    # the result's θ is the Cholesky factor of the fitted (floored) matrices: it maps back to
    # the model and its cost without any eps, as every θ consumer (posterior, Laplace) reads it
    back = theta_to_model(res.theta, res.scale)
    for a, b in ((back.hand.K, res.model.hand.K), (back.total.M, res.model.total.M)):
        np.testing.assert_allclose(
            np.asarray(a), np.asarray(b), rtol=1e-9, atol=1e-12 * np.abs(b).max()
        )
    assert float(nls_cost(res.theta, frf, scale=res.scale)) == pytest.approx(
        float(res.cost), rel=1e-8
    )
    # the floor is PD_EPS·I in scaled units: the smallest hand-K eigenvalue is ≥ PD_EPS·z_ref
    z_ref = float(res.scale.z_ref)
    assert np.linalg.eigvalsh(np.asarray(res.model.hand.K))[0] >= PD_EPS * z_ref * (1 - 1e-9)


@pytest.mark.slow
def test_hexapod6_nls_has_no_crhp_roots():
    from hapid.device import preset
    from hapid.experiment import Protocol, estimate_frf, periodic_run

    dev = preset("hexapod6")
    run = periodic_run(dev, Protocol(n_periods=6, force_noise=5e-3, position_noise=0.0, seed=0))
    res = fit_nls(estimate_frf(run), pd_eps=PD_EPS)
    assert res.ok
    c = crhp_report(res.model)
    assert int(c.hand) == 0 and int(c.total) == 0


def test_scene_refits_a_boundary_hand_for_a_realizable_controller():
    """The scene's NLS stage: a fit whose Ẑ_H has a root at ∞ or on the imaginary axis (an
    inverse-model controller that is improper or marginal) is refitted with ``PD_EPS`` and
    says so; a fit off the boundary is left alone (bit for bit), and ``boundary_refit =
    False`` keeps the boundary fit."""
    from hapid import pipeline, scene
    from hapid.control import controller_is_stable

    o = {k: scene.DEFAULTS["fit"][k] for k in scene.NLS_KEYS}
    frf = synthetic_frf(_subspace_hand_truth(), rel_noise=1e-2, seed=15)
    out = scene._nls(o, frf)
    assert out["refit_pd_eps"] == PD_EPS
    assert pipeline.controller_ready(out["model"])
    kept = scene._nls(o | {"boundary_refit": False}, frf)
    assert kept["refit_pd_eps"] is None and not pipeline.controller_ready(kept["model"])
    assert not bool(controller_is_stable(kept["model"]))
    regular = synthetic_frf(random_truth(3, 5), rel_noise=1e-2, seed=15)
    a, b = scene._nls(o, regular), fit_nls(regular, pd_eps=0.0)
    assert a["refit_pd_eps"] is None
    np.testing.assert_array_equal(np.asarray(a["model"].hand.M), np.asarray(b.model.hand.M))
