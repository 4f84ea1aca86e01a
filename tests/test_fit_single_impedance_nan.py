"""A single impedance loaded into the hand/total pair (Z_H = Z_T, or Z_H = 0) fits.

Regression for issue 15: ``project_pd`` floored the zero mechanism at ~1e-154, the total was
stored as hand + mechanism, the mechanism re-derived as total − hand rounded back to exactly 0
and the Cholesky in ``model_to_theta`` returned NaN (fit failed after one step); with
Z_H = 0 the relative weights were 1/0.
"""

import numpy as np
import pytest
from helpers_fit import random_truth, synthetic_frf

from hapid.fit import fit_nls, model_to_theta, project_pd, wls
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


@pytest.mark.parametrize("layout", ["ZH=ZT", "ZH=0"])
def test_single_impedance_in_the_pair_fits_noise_free(layout):
    truth = random_truth(2, seed=3)
    f = synthetic_frf(truth, rel_noise=0.0)
    Z = np.asarray(f.Z_T)
    ZH = Z if layout == "ZH=ZT" else np.zeros_like(Z)
    frf = as_frf(f.freq_hz, ZH, Z)
    # the start really has a zero block (what made the Cholesky NaN)
    start = wls(frf)
    block = start.mechanism if layout == "ZH=ZT" else start.hand
    assert float(np.max(np.abs(np.asarray(block.K)))) == 0.0
    res = fit_nls(frf, f_max_hz=None, rtol=1e-12, atol=1e-14)
    assert res.ok, res.summary()
    assert np.isfinite(float(res.cost))
    tot = res.model.total
    for a, b in ((tot.M, truth.total.M), (tot.B, truth.total.B), (tot.K, truth.total.K)):
        assert np.linalg.norm(np.asarray(a) - np.asarray(b)) <= 1e-6 * np.linalg.norm(b)
