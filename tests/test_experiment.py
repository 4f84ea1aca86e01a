"""Excitation, synthesis and empirical FRF estimation."""

import dataclasses

import numpy as np
import pytest
from helpers import rel_err, second_order_device

from hapid.device import cu5, hexapod6, tripod3
from hapid.experiment import (
    Protocol,
    Run,
    estimate_frf,
    estimate_frf_h1,
    multisine,
    paper_frequencies,
    patterns,
    periodic_run,
    time_domain_response,
    time_domain_run,
)


def test_paper_frequencies():
    f = paper_frequencies()
    assert len(f) == 28 and f[0] == 1 and f[9] == 10 and f[10] == 15 and f[-1] == 100


def test_multisine_equals_sum_of_cosines():
    ms = multisine(
        [3.0, 7.0, 20.0], fs_hz=500.0, period_samples=500, amplitude=[1.0, 0.5, 0.2], seed=3
    )
    t = np.arange(500) / 500.0
    ref = sum(
        a * np.cos(2 * np.pi * f * t + p)
        for f, a, p in zip(ms.freq_hz, ms.amplitude, ms.phase, strict=True)
    )
    np.testing.assert_allclose(np.asarray(ms.period()), ref, atol=1e-12)


def test_schroeder_and_min_crest_lower_the_crest_factor():
    f = paper_frequencies()
    rand = np.mean([multisine(f, phases="random", seed=s).crest_factor() for s in range(10)])
    schr = multisine(f, phases="schroeder").crest_factor()
    minc = multisine(f, phases="min_crest").crest_factor()
    assert schr < rand and minc <= schr


def test_off_grid_frequency_is_a_clear_error():
    with pytest.raises(ValueError, match="off the FFT grid.*typo"):
        multisine([1.0, 2.5], fs_hz=1000.0, period_samples=1000)
    with pytest.raises(ValueError, match="off the FFT grid"):
        Protocol(freq_hz=(1.0, 1.3))
    with pytest.raises(ValueError, match="Nyquist"):
        multisine([600.0], fs_hz=1000.0, period_samples=1000)


@pytest.mark.parametrize("n", [3, 4, 5, 6, 7])
def test_patterns(n):
    U = patterns(n, "paper")
    assert U.shape == (n, n) and np.linalg.matrix_rank(U) == n
    assert np.allclose(np.diag(U), -1) and np.sum(U == 1) == n * n - n
    H = patterns(n, "hadamard")
    assert H.shape[0] >= n and np.allclose(H.T @ H, H.shape[0] * np.eye(n))
    assert np.allclose(patterns(n, "one_at_a_time"), np.eye(n))


def test_singular_or_short_pattern_is_a_clear_error():
    with pytest.raises(ValueError, match="singular excitation pattern"):
        Protocol(pattern=((1, 1, 1), (1, 1, 1), (1, -1, 1))).pattern_matrix(3)
    with pytest.raises(ValueError, match="E = 2 experiments < n = 3"):
        Protocol(pattern=((1, 1, 1), (1, -1, 1))).pattern_matrix(3)


@pytest.mark.parametrize("make", [tripod3, cu5, hexapod6])
def test_noise_free_frf_equals_true_impedances(make):
    """Empirical Z_H, Z_T equal the device's truth at the excited frequencies, n = 3, 5, 6."""
    dev, prot = make(), Protocol(n_periods=2).noiseless()
    w = 2 * np.pi * np.asarray(prot.freq_hz)
    frf = estimate_frf(periodic_run(dev, prot, hold="bandlimited"))
    Z_H, Z_T = dev.impedances(1j * w)
    assert rel_err(frf.Z_H, Z_H) < 1e-9 and rel_err(frf.Z_T, Z_T) < 1e-9
    frf = estimate_frf(periodic_run(dev, prot))  # zero-order hold: the sampled truth
    Z_H, Z_T = dev.sampled_impedances(w)
    assert rel_err(frf.Z_H, Z_H) < 1e-9 and rel_err(frf.Z_T, Z_T) < 1e-9


def test_hadamard_patterns_least_squares_recover_truth():
    dev = cu5()
    prot = dataclasses.replace(Protocol(n_periods=2).noiseless(), pattern="hadamard")
    run = periodic_run(dev, prot)
    assert run.R_A.shape[0] == 8
    frf = estimate_frf(run)
    Z_H, Z_T = dev.sampled_impedances(frf.omega)
    assert rel_err(frf.Z_H, Z_H) < 1e-9 and rel_err(frf.Z_T, Z_T) < 1e-9


def test_periodic_and_time_domain_agree_cu5():
    dev, prot = cu5(), Protocol(n_periods=2).noiseless()
    a = estimate_frf(periodic_run(dev, prot))
    b = estimate_frf(time_domain_run(dev, prot))
    assert rel_err(b.Z_H, a.Z_H) < 1e-6 and rel_err(b.Z_T, a.Z_T) < 1e-6


def test_periodic_and_time_domain_agree_from_rest_after_transients():
    """From rest, the transients decay (slowest pole of tripod3 ≈ −1 rad/s) and the FRFs agree."""
    dev = tripod3()
    prot = dataclasses.replace(Protocol().noiseless(), transient_periods=20, n_periods=2)
    a = estimate_frf(periodic_run(dev, prot))
    b = estimate_frf(time_domain_run(dev, prot, initial="zero"))
    assert rel_err(b.Z_H, a.Z_H) < 1e-6 and rel_err(b.Z_T, a.Z_T) < 1e-6


def test_friction_changes_the_frf():
    dev, prot = cu5(), Protocol(n_periods=2, transient_periods=2).noiseless()
    a = estimate_frf(time_domain_run(dev, prot))
    b = estimate_frf(time_domain_run(dev, prot, friction=True))
    assert np.all(np.isfinite(np.asarray(b.Z_T))) and rel_err(b.Z_T, a.Z_T) > 1e-2


def test_reported_std_matches_monte_carlo_scatter():
    """Seeded Monte Carlo: the reported element std matches the actual scatter within 20 %."""
    dev = cu5()
    prot = dataclasses.replace(Protocol(n_periods=4, encoder_resolution=0.0, position_noise=2e-7),
                               force_noise=5e-3)  # fmt: skip
    Z_H, Z_T = dev.sampled_impedances(2 * np.pi * np.asarray(prot.freq_hz))
    errs_H, errs_T, std_H, std_T = [], [], [], []
    for seed in range(40):
        frf = estimate_frf(periodic_run(dev, prot, noise_seed=100 + seed))
        errs_H.append(np.abs(np.asarray(frf.Z_H) - np.asarray(Z_H)) ** 2)
        errs_T.append(np.abs(np.asarray(frf.Z_T) - np.asarray(Z_T)) ** 2)
        std_H.append(np.asarray(frf.Z_H_std) ** 2)
        std_T.append(np.asarray(frf.Z_T_std) ** 2)
    for errs, std in ((errs_H, std_H), (errs_T, std_T)):
        actual = np.sqrt(np.mean(errs, axis=0))
        reported = np.sqrt(np.mean(std, axis=0))
        ratio = reported / actual
        # per frequency, pooled over the n² elements (each element has only 40 draws)
        pooled = np.sqrt(np.mean(reported**2, axis=(1, 2)) / np.mean(actual**2, axis=(1, 2)))
        assert np.all(np.abs(pooled - 1) < 0.2), pooled
        assert 0.8 < np.median(ratio) < 1.2


def _run(**kw):
    base = periodic_run(tripod3(), Protocol(n_periods=2))
    d = dict(fs_hz=base.fs_hz, period_samples=base.period_samples, freq_hz=base.freq_hz,
             R_A=base.R_A, R_I=base.R_I, L=base.L)  # fmt: skip
    d.update(kw)
    return d


def test_bad_runs_are_clear_errors():
    good = _run()
    L = good["L"].copy()
    L[1, 7, 0] = np.nan
    with pytest.raises(ValueError, match="L contains NaN"):
        Run(**_run(L=L))
    with pytest.raises(ValueError, match="same .E, T, n. shape"):
        Run(**_run(L=good["L"][:, :, :2]))
    with pytest.raises(ValueError, match="not a whole number of periods"):
        Run(**_run(R_A=good["R_A"][:, :-10], R_I=good["R_I"][:, :-10], L=good["L"][:, :-10]))
    with pytest.raises(ValueError, match="E = 2 experiments < n = 3"):
        Run(**_run(R_A=good["R_A"][:2], R_I=good["R_I"][:2], L=good["L"][:2]))
    with pytest.raises(ValueError, match="off the FFT grid"):
        Run(**_run(freq_hz=good["freq_hz"] + 0.5))
    with pytest.raises(ValueError, match="inf"):
        Run(**_run(R_I=np.where(good["R_I"] > 0.1, np.inf, good["R_I"])))


def test_rank_deficient_L_is_a_clear_error():
    good = _run()
    L = good["L"].copy()
    L[2] = L[0] + L[1]  # third experiment moves the rods in a dependent direction
    with pytest.raises(ValueError, match="rank-deficient displacement matrix"):
        estimate_frf(Run(**_run(L=L)))


def test_poor_conditioning_warns():
    good = _run()
    L = good["L"].copy()
    L[2] = L[0] + L[1] + 1e-5 * L[2]
    with pytest.warns(UserWarning, match="poorly conditioned"):
        estimate_frf(Run(**_run(L=L)))


def test_h1_estimator_on_noise_excitation():
    dev = second_order_device(3, seed=1)
    rng = np.random.default_rng(0)
    R_A = rng.normal(size=(6, 2**14, 3))
    L, R_I = time_domain_response(dev, R_A)
    f = np.array([2.0, 5.0, 10.0, 20.0, 50.0])
    for ref in ("L", "R_A"):
        frf = estimate_frf_h1(1000.0, R_A, R_I, L, nperseg=1024, freq_hz=f, reference=ref)
        Z_H, Z_T = dev.sampled_impedances(frf.omega)
        assert rel_err(frf.Z_H, Z_H) < 1e-2 and rel_err(frf.Z_T, Z_T) < 1e-2
        assert np.all(np.asarray(frf.Z_H_std) > 0)


def test_hann_window_is_scipys_periodic_hann_bit_for_bit():
    """The segment window is built without importing scipy.signal (start-up time): it must be
    scipy's periodic Hann exactly, so every FRF estimate is unchanged."""
    import scipy.signal

    from hapid.experiment._estimate import window_array

    for n in (1, 2, 3, 8, 255, 256, 1000, 4097):
        assert np.array_equal(window_array("hann", n), scipy.signal.get_window("hann", n)), n
