"""Fits on the cu5 device, which is not strictly second order."""

import numpy as np
import pytest

from hapid.device import cu5
from hapid.experiment import Protocol, estimate_frf, periodic_run
from hapid.fit import crhp_report, fit_nls, positize, pphat_band_db, wls


@pytest.fixture(scope="module")
def data():
    dev = cu5()
    frf = estimate_frf(periodic_run(dev, Protocol()))
    return dev, frf, np.asarray(dev.sampled_P(frf.omega))


@pytest.mark.parametrize("weight", ["relative", "paper", "blend"])
def test_nls_models_have_all_roots_in_the_open_left_half_plane(data, weight):
    _, frf, _ = data
    res = fit_nls(frf, weight=weight)
    assert res.status in ("converged", "max_steps")
    roots = np.concatenate(
        [np.asarray(res.model.hand.roots()), np.asarray(res.model.total.roots())]
    )
    assert np.all(roots.real < 0), roots[roots.real >= 0]
    for A in (res.model.hand.M, res.model.hand.B, res.model.hand.K, res.model.mechanism.M,
              res.model.mechanism.B, res.model.mechanism.K):  # fmt: skip
        A = np.asarray(A)
        assert np.allclose(A, A.T) and np.linalg.eigvalsh(A).min() >= -1e-9 * np.abs(A).max()


def test_wls_needs_positize_and_nls_band_is_narrower(data):
    """The paper's WLS has CRHP roots on cu5; positizing removes them. The NLS + PD model's
    P·P̂⁻¹ band to 30 Hz (max − min, dB, true sampled plant) is narrower than WLS + positize."""
    _, frf, P = data
    raw = wls(frf)
    assert int(crhp_report(raw).hand) + int(crhp_report(raw).total) > 0
    pos = positize(raw)
    assert int(crhp_report(pos).hand) == 0 and int(crhp_report(pos).total) == 0
    w_lo, w_hi = (float(x) for x in pphat_band_db(P, pos, frf.omega, 30.0))
    res = fit_nls(frf)
    n_lo, n_hi = (float(x) for x in pphat_band_db(P, res.model, frf.omega, 30.0))
    print(f"WLS+positize {w_lo:+.1f}/{w_hi:+.1f} dB, NLS {n_lo:+.1f}/{n_hi:+.1f} dB")
    assert n_hi - n_lo < w_hi - w_lo
