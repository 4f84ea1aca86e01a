"""The tuner's collapse to a safe but useless g (quad4 with 2 samples of delay: 0.04 Hz where
the paper g gives 5.8 Hz on the true plant) and its cause: the loop draws below the lowest
measured frequency reverted to a prior σ² a(u_1)² — σ² the between-points calibration (7.1
there) — so a third of the draws had a left-half-plane eigenvalue of Q below 1 Hz, where the
inverse-model loop has |g| ≈ 40, and no g with the paper's static gain could hold them
(docs/robust-design.md, "The collapse"). Now the continuation below ω_1 reverts to the size
the lowest measured frequencies show, a(u_1)², conditioned on the draw's value at ω_1."""

from math import tau as TWO_PI

import numpy as np
import pytest

from hapid.uncertainty._loopgp import LoopGP, conditional, loop_gp_draws


def _m52(d, ell):  # Matérn-5/2, written out independently
    r = abs(d) / ell
    return (1 + np.sqrt(5) * r + 5 * r * r / 3) * np.exp(-np.sqrt(5) * r)


def _gp(s2, eta=1e-6, ell=0.6, n=2, K=9, seed=0):
    rng = np.random.default_rng(seed)
    u = np.log(TWO_PI * np.geomspace(1.0, 100.0, K))
    D = 0.3 * (rng.normal(size=(K, n * n)) + 1j * rng.normal(size=(K, n * n)))
    r = 0.2 + np.abs(np.sin(u))
    return LoopGP(u, D, r, ell, eta, s2, n, 0.0)


@pytest.mark.parametrize("s2", [0.5, 9.0])
def test_below_the_data_the_draws_revert_to_the_size_measured_there_not_sigma2(s2):
    """Far below ω_1 the real part of every element has variance a(u_1)²/2 (circular complex,
    imaginary part scaled to 0 at DC) whatever σ² — the old continuation gave σ² a(u_1)²/2
    (9× too wide for σ² = 9); a decade below, the mean is ρ · (the conditional mean at u_1)
    with ρ the Matérn correlation over that distance (an independent formula)."""
    gp = _gp(s2)
    u1 = gp.u[0]
    a1 = float(gp.envelope(gp.u[:1])[0])
    om = np.exp(np.array([u1 - 8.0, u1 - np.log(10.0), u1 + 0.1]))
    S = 20000
    D = (loop_gp_draws(gp, om, S, seed=1) - np.eye(2)).reshape(S, 3, 4)
    far = np.mean(D[:, 0].real ** 2)
    assert far == pytest.approx(a1**2 / 2, rel=0.06)
    assert np.max(np.abs(D[:, 0].imag)) < 1e-3 * np.max(np.abs(D[:, 0].real))
    m1, v1 = conditional(gp, np.array([u1]))
    rho = _m52(np.log(10.0), gp.ell)
    se = np.sqrt((a1**2 + v1[0, 0]) / 2 / S)  # bound on the mean's standard error
    np.testing.assert_allclose(D[:, 1].real.mean(0), rho * m1[0].real, atol=5 * se)
    # the imaginary part a decade down is the same continuation scaled by ω/ω_1 = 0.1
    np.testing.assert_allclose(D[:, 1].imag.mean(0), 0.1 * rho * m1[0].imag, atol=5 * se)


def test_just_below_the_data_the_draw_continues_its_value_at_omega_1():
    """Continuity at ω_1: δ = 0.05 in ln ω below it a draw departs from its own value at ω_1
    by the Matérn process' change over δ, conditioned on that value: variance
    a(u_1)² (1 − ρ(δ)²) (circular complex: half in the real part) — whatever σ² (the old
    continuation: σ² times that)."""
    gp = _gp(9.0)
    u1, d = gp.u[0], 0.05
    a1 = float(gp.envelope(gp.u[:1])[0])
    m1, v1 = conditional(gp, np.array([u1]))
    om = np.exp(np.array([u1 - d]))
    S = 20000
    D = (loop_gp_draws(gp, om, S, seed=2) - np.eye(2)).reshape(S, 4)
    rho = _m52(d, gp.ell)
    var = 0.5 * (a1**2 * (1 - rho**2) + rho**2 * v1[0, 0])
    np.testing.assert_allclose(np.var(D.real, axis=0), var, rtol=0.06)


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_quad4_with_two_samples_of_delay_does_not_collapse():
    """``hapid tune``'s default route (loop draws on the paper protocol's FRF, evidence with the
    1 kHz controller; quick sizes) on quad4 with 2 samples of delay, seeds 0–2: every returned
    g is stable on the true sampled plant, and most keep a useful bandwidth there — at least
    half the paper g's (which is at the edge: GM 0.8 dB). Before the fix: 0.04 Hz (gain backed
    off to 0.026 of the paper's, then stuck at the topology guard), 0.7 % of the paper g's
    5.8 Hz. At these quick sizes (60 training draws) one seed in three still ends at low
    bandwidth, whichever construction of the draws (measured: without the FRF's measurement
    noise seed 1 gave 0.78 Hz; with it seed 0 gave 1.92 Hz; the others 5.3–6.1 Hz); the
    default sizes gave 5.6–6.0 Hz on seeds 0 and 1 (benchmarks/study_tune_stop.py)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
    from calibrate_robust import parse_device, setup

    from hapid.control import Compensator
    from hapid.tune import Recipe, robust_design, true_plant_loop
    from hapid.uncertainty import LoopDraws

    dev = parse_device("quad4:delay=2")
    frf, fit = setup(dev)
    paper = true_plant_loop(Compensator.paper(), fit.model, dev).numbers()
    assert paper["stable"]
    useful = []
    for seed in (0, 1, 2):
        out = robust_design(fit.model, LoopDraws(frf), ts=dev.ts,
                            recipe=Recipe(n_train=60, n_holdout=100, n_freq=200, max_steps=150,
                                          seed=seed))  # fmt: skip
        got = true_plant_loop(out.g, fit.model, dev).numbers()
        assert got["stable"], (seed, out.decision.reason)
        useful.append(got["iso_bandwidth_hz"] >= 0.5 * paper["iso_bandwidth_hz"])
    assert sum(useful) >= 2, useful
