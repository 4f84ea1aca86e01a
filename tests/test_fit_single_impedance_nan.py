"""A single impedance loaded into the hand/total pair (Z_H = Z_T, or Z_H = 0) fits.

Regression for issue 15: ``project_pd`` floored the zero mechanism at ~1e-154, the total was
stored as hand + mechanism, the mechanism re-derived as total − hand rounded back to exactly 0
and the Cholesky in ``model_to_theta`` returned NaN (fit failed after one step); with
Z_H = 0 the relative weights were 1/0.
"""

import numpy as np
import pytest
from helpers_fit import PAPER_FREQ_HZ, random_truth, synthetic_frf

from hapid.fit import fit_nls, model_to_theta, project_pd, solver_from, wls
from hapid.frf import as_frf
from hapid.impedance import ImpedanceModel


def test_model_to_theta_of_a_zero_mechanism_is_finite():
    truth = random_truth(3, seed=4)
    single = ImpedanceModel(hand=truth.total, total=truth.total)  # mechanism exactly 0
    theta = np.asarray(model_to_theta(project_pd(single)))
    assert np.all(np.isfinite(theta))
    theta0 = np.asarray(
        model_to_theta(ImpedanceModel(hand=truth.total - truth.total, total=truth.total))
    )
    assert np.all(np.isfinite(theta0))


def test_single_impedance_as_Z_H_equal_Z_T_fits_noise_free():
    truth = random_truth(2, seed=3)
    Z = np.asarray(synthetic_frf(truth, rel_noise=0.0).Z_T)
    frf = as_frf(PAPER_FREQ_HZ, Z, Z)
    start = wls(frf)  # the start really has a zero mechanism (what made the Cholesky NaN)
    assert float(np.max(np.abs(np.asarray(start.mechanism.K)))) == 0.0
    res = fit_nls(frf, f_max_hz=None, solver=solver_from("lm", rtol=1e-12, atol=1e-14))
    assert res.ok, res.summary()
    assert np.isfinite(float(res.cost))
    tot = res.model.total
    for a, b in ((tot.M, truth.total.M), (tot.B, truth.total.B), (tot.K, truth.total.K)):
        assert np.linalg.norm(np.asarray(a) - np.asarray(b)) <= 1e-6 * np.linalg.norm(b)


@pytest.mark.slow  # CI budget (~16 s); …_equal_Z_T_fits_noise_free keeps the single-impedance fit fast
def test_single_impedance_as_Z_H_zero_fits_through_the_cli_without_nan(tmp_path, capsys):
    from hapid import io
    from hapid.cli import main

    truth = random_truth(2, seed=3)
    Z = np.asarray(synthetic_frf(truth, rel_noise=0.0).Z_T)
    assert float(np.max(np.abs(np.asarray(wls(as_frf(PAPER_FREQ_HZ, 0 * Z, Z)).hand.K)))) == 0.0
    io.save_frf(tmp_path / "z0.npz", as_frf(PAPER_FREQ_HZ, np.zeros_like(Z), Z))
    out = tmp_path / "m.npz"
    assert main(["fit", str(tmp_path / "z0.npz"), "--method", "nls", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "nan" not in text.lower() and "inf dB" not in text
    assert "Z_H: the data are zero" in text and "data-fit relative error of Z_T" in text
    tot = io.load_model(out).total
    for a, b in ((tot.M, truth.total.M), (tot.B, truth.total.B), (tot.K, truth.total.K)):
        assert np.linalg.norm(np.asarray(a) - np.asarray(b)) <= 1e-6 * np.linalg.norm(b)
    assert float(io.load_model_metadata(out)["quality_median_db"][0]) < -100  # Z_T
