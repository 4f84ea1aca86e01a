"""fit_ml: the frequency-domain sample maximum-likelihood (errors-in-variables) estimator.

Checks: recovery of a strictly second-order truth from noise-free spectra; the cost against
an independent numpy implementation written from the raw time series; the FRF rejection;
the Cramér–Rao band against a Monte-Carlo of the fitted model; and (slow) consistency —
the ML parameter error shrinks like 1/√periods with noise on force and position.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers_fit import random_truth

import hapid  # noqa: F401
from hapid.device import SecondOrderDevice
from hapid.experiment import Protocol, estimate_frf, periodic_run
from hapid.fit import (
    cramer_rao,
    data_scale,
    fit_ml,
    ml_cost,
    model_relative_errors,
    model_to_theta,
    project_pd,
)
from hapid.fit._ml import REL_JITTER, _inverse_cholesky, _quantization_step
from hapid.impedance import ImpedanceModel, SecondOrder

FREQ_HZ = (1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0, 30.0, 40.0)


def _device(n=3, seed=3) -> SecondOrderDevice:
    t = random_truth(n, seed)
    return SecondOrderDevice(hand=t.hand, mechanism=t.mechanism)


def _perturbed(model: ImpedanceModel, rel=0.3, seed=0) -> ImpedanceModel:
    rng = np.random.default_rng(seed)

    def pert(so):
        return SecondOrder(
            *(np.asarray(a) * (1 + rel * rng.uniform(-1, 1)) for a in (so.M, so.B, so.K))
        )

    return project_pd(ImpedanceModel.from_hand_mechanism(pert(model.hand), pert(model.mechanism)))


@pytest.mark.slow  # CI budget (~11 s); the numpy cost reference and test_fit_band_default keep ML fast
def test_recovers_truth_on_noise_free_spectra():
    dev = _device()
    prot = Protocol(freq_hz=FREQ_HZ, n_periods=2, pattern="hadamard").noiseless()
    run = periodic_run(dev, prot, hold="bandlimited")
    res = fit_ml(run, _perturbed(dev.model), f_max_hz=None)
    assert res.status == "converged"
    assert float(np.max(model_relative_errors(res.model, dev.model))) < 1e-8


def _reference_cost(run, model: ImpedanceModel, phi: float, f_max_hz: float, q: float) -> float:
    """Σ_k Σ_e eᴴ S⁻¹ e written from scratch: explicit DFT sums, per-frequency loops."""
    E, T, n = run.R_A.shape
    Tp, P = run.period_samples, T // run.period_samples
    t = np.arange(Tp)
    total = 0.0
    for f in np.asarray(run.freq_hz):
        if f > f_max_hz:
            continue
        kbin = int(round(f * Tp / run.fs_hz))
        ph = np.exp(-2j * np.pi * kbin * t / Tp) * 2.0 / Tp
        spec = {}
        for name in ("R_I", "R_A", "L"):
            x = getattr(run, name).reshape(E, P, Tp, n)
            spec[name] = np.einsum("eptn,t->epn", x, ph)  # (E, P, n)
        Xp = np.concatenate([spec["R_I"], spec["R_A"], spec["L"]], axis=-1)  # (E, P, 3n)
        mean = Xp.mean(axis=1)
        C = np.zeros((3 * n, 3 * n), complex)
        for e in range(E):
            for p in range(P):
                d = Xp[e, p] - mean[e]
                C += np.outer(d, d.conj())
        C /= E * (P - 1) * P
        C[2 * n :, 2 * n :] += np.eye(n) * q**2 / (3 * Tp)
        s = 2j * np.pi * f
        ZH = (
            np.asarray(model.hand.M) * s**2
            + np.asarray(model.hand.B) * s
            + np.asarray(model.hand.K)
        )
        ZT = (
            np.asarray(model.total.M) * s**2
            + np.asarray(model.total.B) * s
            + np.asarray(model.total.K)
        )
        A = np.block([[np.eye(n), np.zeros((n, n)), ZH], [np.zeros((n, n)), np.eye(n), ZT]])
        S = A @ C @ A.conj().T
        pH = np.mean(np.abs(mean[:, :n]) ** 2)
        pT = np.mean(np.abs(mean[:, n : 2 * n]) ** 2)
        S += (phi**2 + REL_JITTER) * np.diag(np.r_[np.full(n, pH), np.full(n, pT)])
        S += REL_JITTER * np.trace(S).real / (2 * n) * np.eye(2 * n)
        for e in range(E):
            err = A @ mean[e]
            total += float(np.real(err.conj() @ np.linalg.solve(S, err)))
    return total


@pytest.mark.parametrize("phi", [0.0, 0.05])
def test_cost_matches_numpy_reference(phi):
    dev = _device(n=2, seed=5)
    prot = Protocol(freq_hz=FREQ_HZ, n_periods=4, force_noise=0.02, position_noise=3e-6, pattern="hadamard",
                    encoder_resolution=1e-6)  # fmt: skip
    run = periodic_run(dev, prot, hold="bandlimited")
    assert _quantization_step(run.L) == pytest.approx(1e-6, rel=1e-9)
    scale = data_scale(estimate_frf(run), 30.0)
    model = _perturbed(dev.model, rel=0.2, seed=2)
    theta = model_to_theta(model, scale)
    got = float(ml_cost(theta, run, scale, f_max_hz=30.0, model_floor=phi))
    ref = _reference_cost(run, model, phi, 30.0, 1e-6)
    assert got == pytest.approx(ref, rel=1e-9)


def test_inverse_cholesky_whitens():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((4, 6, 6)) + 1j * rng.standard_normal((4, 6, 6))
    S = A @ np.conj(np.swapaxes(A, -1, -2)) + 0.1 * np.eye(6)
    T = np.asarray(_inverse_cholesky(S))
    assert np.allclose(np.triu(T, 1), 0)
    assert np.allclose(T @ S @ np.conj(np.swapaxes(T, -1, -2)), np.eye(6), atol=1e-10)


def test_rejects_an_frf_and_single_period():
    dev = _device(n=2)
    prot = Protocol(freq_hz=FREQ_HZ, n_periods=1, pattern="hadamard")
    run = periodic_run(dev, prot, hold="bandlimited")
    with pytest.raises(ValueError, match="needs the run"):
        fit_ml(estimate_frf(run))
    with pytest.raises(ValueError, match="≥ 2 periods"):
        fit_ml(run)


def _ml_and_nls_errors(dev, periods, seeds, force_noise, position_noise):
    from hapid.fit import fit_estimators

    names = {"ml": "ML", "nls": "NLS relative", "nls_noise": "NLS noise"}
    out = {k: [] for k in names}
    for seed in seeds:
        prot = Protocol(freq_hz=FREQ_HZ, n_periods=periods, force_noise=force_noise,
                        position_noise=position_noise, encoder_resolution=0.0, seed=seed,
                        pattern="hadamard")  # fmt: skip
        fits = fit_estimators(periodic_run(dev, prot, hold="bandlimited"), f_max_hz=None)
        assert fits.ml.ok
        models = fits.models()
        for k, name in names.items():
            out[k].append(float(np.max(model_relative_errors(models[name], dev.model))))
    return {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in out.items()}


@pytest.mark.slow
def test_ml_error_shrinks_like_one_over_sqrt_periods():
    dev = _device(n=2, seed=5)
    e4 = _ml_and_nls_errors(dev, 4, range(6), 0.05, 2e-5)
    e64 = _ml_and_nls_errors(dev, 64, range(6), 0.05, 2e-5)
    # 16× the periods: an efficient consistent estimator's rms error drops ≈ 4×
    ratio = e4["ml"] / e64["ml"]
    assert 2.5 < ratio < 6.5, (e4, e64)
    # and ML beats the FRF fits at both lengths
    assert e4["ml"] < min(e4["nls"], e4["nls_noise"])
    assert e64["ml"] < min(e64["nls"], e64["nls_noise"])


@pytest.mark.slow  # CI budget (make test-all runs it)
def test_cli_fit_ml_writes_model_and_rejects_frf(tmp_path, capsys):
    from hapid import io
    from hapid.cli import main

    dev = _device(n=2, seed=5)
    prot = Protocol(freq_hz=FREQ_HZ, n_periods=3, pattern="hadamard", force_noise=0.01)
    run = periodic_run(dev, prot, hold="bandlimited")
    io.save_run(tmp_path / "run.npz", run)
    io.save_frf(tmp_path / "frf.npz", estimate_frf(run))
    out = tmp_path / "ml.npz"
    assert main(["fit", str(tmp_path / "frf.npz"), "--method", "ml", "--out", str(out)]) == 2
    assert "needs the run file" in capsys.readouterr().err and not out.exists()
    args = [
        "fit",
        str(tmp_path / "run.npz"),
        "--method",
        "ml",
        "--model-floor",
        "0",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "Cramér–Rao limit" in text and "ml: converged" in text
    assert io.load_model_metadata(out)["method"] == "ml"
    assert float(np.max(model_relative_errors(io.load_model(out), dev.model))) < 0.05


@pytest.mark.slow
def test_crb_matches_monte_carlo_spread():
    """The Cramér–Rao bound (matrix coordinates) against the spread of ML estimates over
    noise realizations: an efficient estimator's covariance equals it (sample ML: ≈, a few
    tens of percent above for ν = E(P − 1) = 28 degrees of freedom)."""
    from hapid.fit._ml import _sym_to_vec
    from hapid.fit._pd import model_to_scaled

    dev = _device(n=2, seed=5)
    vs, crb, scale = [], None, None
    for seed in range(24):
        prot = Protocol(freq_hz=FREQ_HZ, n_periods=8, force_noise=0.05, position_noise=2e-5,
                        encoder_resolution=0.0, seed=seed, pattern="hadamard")  # fmt: skip
        run = periodic_run(dev, prot, hold="bandlimited")
        res = fit_ml(run, f_max_hz=None)
        if crb is None:  # the bound at the truth, with this run's noise covariances
            scale = res.scale
            crb = np.asarray(cramer_rao(run, dev.model, f_max_hz=None, scale=scale).crb)
        vs.append(np.asarray(_sym_to_vec(model_to_scaled(res.model, scale))))
    emp = np.cov(np.array(vs).T)
    ratio = np.trace(np.linalg.solve(crb, emp)) / crb.shape[0]  # 1 when emp == crb
    assert 0.6 < ratio < 2.0, ratio
