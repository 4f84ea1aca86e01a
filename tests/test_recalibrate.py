"""The params band of P recalibrated on its left-out errors (hapid.uncertainty.recalibration,
``hapid predict``; issue 29): the direction split against its definition, the shrink and the
added term against their closed forms, and on a right model class the band still holds."""

import numpy as np
import pytest

from hapid.uncertainty import (
    HoldoutCheck,
    direction_split,
    recalibration,
)
from hapid.uncertainty import _recalibrate as R


def _draws(rng, S, N, n, sd=1.0):
    base = rng.standard_normal((N, n, n)) + 1j * rng.standard_normal((N, n, n))
    noise = (rng.standard_normal((S, N, n, n)) + 1j * rng.standard_normal((S, N, n, n))) * sd
    return base[None] + noise * np.sqrt(0.5)


def test_direction_split_is_the_frobenius_error_split_in_the_median_basis():
    rng = np.random.default_rng(0)
    X = _draws(rng, 300, 4, 3, sd=0.1)
    M = np.median(X.real, 0) + 1j * np.median(X.imag, 0)
    U, _, Vh = np.linalg.svd(M)
    delta = np.array([0.3, -0.2j, 0.1 + 0.1j, 0.5])
    along = M + delta[:, None, None] * (U[..., :, :1] @ Vh[..., :1, :])  # along u₁ v₁ᴴ
    sp = direction_split(X, along, M)
    assert np.allclose(sp[0, :, 0], np.abs(delta) ** 2) and np.allclose(sp[1, :, 0], 0, atol=1e-24)
    T = M + 0.05 * (rng.standard_normal(M.shape) + 1j * rng.standard_normal(M.shape))
    sp = direction_split(X, T)
    assert np.allclose(sp[0, :, 0] + sp[1, :, 0], np.linalg.norm(T - M, axis=(-2, -1)) ** 2)
    total = np.mean(np.linalg.norm(X - M[None], axis=(-2, -1)) ** 2, axis=0)
    assert np.allclose(sp[0, :, 1] + sp[1, :, 1], total)


def _check(lead, rest, f=(2.0, 5.0, 10.0, 20.0)):
    f = np.asarray(f)
    meas = np.concatenate([[1.0], f, [40.0]])
    k = f.size
    return HoldoutCheck(f, np.ones(k), np.ones(k), meas, 0.9, np.asarray(lead, float),
                        np.asarray(rest, float))  # fmt: skip


def test_recalibration_closed_form():
    v = 1e-4
    # lead: 9× its variance at 10 Hz (excess 8v), 3× at 20 Hz (2v), calibrated below; rest: no
    # error. 30 Hz lies beyond the last left-out frequency: its end value (2v), not the max
    lead = [[v, v], [v, v], [9 * v, v], [3 * v, v]]
    rest = [[0.0, v], [0.0, v], [0.0, v], [0.0, v]]
    f = np.array([1.5, 7.0, 15.0, 30.0])
    rc = recalibration(_check(lead, rest), f)
    c2 = R.EXCESS_FRACTION**2
    # the added lead variance: the larger excess of the left-out frequencies around f, times
    # 4t(1 − t) of f's place t in its gap between measured frequencies (ln f)
    meas = np.array([1.0, 2.0, 5.0, 10.0, 20.0, 40.0])
    t = np.array([np.log(1.5), np.log(7 / 5) / np.log(2), np.log(1.5), np.log(1.5)])
    t /= np.array([np.log(2.0), 1.0, np.log(2.0), np.log(2.0)])
    assert np.allclose(R.gap_shape(f, meas), 4 * t * (1 - t))
    assert np.allclose(R.gap_shape([2.0, 0.5, 50.0], meas), [0.0, 1.0, 1.0])  # ends; outside
    assert np.allclose(rc.add[:, 0], np.array([0.0, 8.0, 8.0, 2.0]) * c2 * v * 4 * t * (1 - t))
    assert np.allclose(rc.add[:, 1], 0.0)
    assert np.allclose(rc.shrink[:, 0][f >= 7], 1.0)  # never widened by the shrink
    w = np.exp(-0.5 * ((np.log(f)[:, None] - np.log([2.0, 5.0, 10.0, 20.0])) / R.KERNEL_LN_F) ** 2)
    zbar = R.PSEUDO / (w.sum(1) + R.PSEUDO)  # the rest: ratio 0 at every left-out frequency
    assert np.allclose(rc.shrink[:, 1], np.sqrt(np.clip(zbar, R.SHRINK_FLOOR, 1.0)))
    assert np.all(rc.shrink[:, 1] >= 0.5) and np.all(rc.shrink[:, 1] < 1.0)
    # applied: the spread along u₁ v₁ᴴ becomes v₀ s² + add, the rest's v₀ s² (per entry)
    rng = np.random.default_rng(1)
    n, sd = 3, 0.01
    X = _draws(rng, 8000, f.size, n, sd=sd)
    Y = rc.apply(X, seed=2)
    sp = direction_split(Y, np.zeros((f.size, n, n)))
    lead_var = sd**2 * rc.shrink[:, 0] ** 2 + rc.add[:, 0]
    rest_var = (n * n - 1) * sd**2 * rc.shrink[:, 1] ** 2
    assert np.allclose(sp[0, :, 1], lead_var, rtol=0.08)
    assert np.allclose(sp[1, :, 1], rest_var, rtol=0.04)
    M = np.median(X.real, 0) + 1j * np.median(X.imag, 0)
    My = np.median(Y.real, 0) + 1j * np.median(Y.imag, 0)
    assert np.max(np.abs(My - M)) < 0.05 * np.sqrt(np.max(lead_var))  # centred as before
    with pytest.raises(ValueError, match="draws"):
        rc.apply(X[:, :2])
    with pytest.raises(ValueError, match="positive"):
        recalibration(_check(lead, rest), [0.0, 1.0])


def test_band_figure_draws_the_measured_plant_with_and_without_the_band_as_drawn():
    from hapid import plot

    rng = np.random.default_rng(3)
    X = _draws(rng, 40, 6, 2, sd=0.05)
    f = np.geomspace(1.0, 40.0, 6)
    for raw in (None, X):
        fig, axes = plot.predictive_band(f, X, measured=(f[::2], X[0, ::2]), raw=raw)
        labels = [ln.get_label() for ln in axes[0][0].get_lines()]
        assert "measured P" in labels and ("band as drawn" in labels) == (raw is not None)
        plot.close(fig)
    fig, axes = plot.predictive_band(f, X, raw=X)  # no measured plant
    assert "measured P" not in [ln.get_label() for ln in axes[0][0].get_lines()]
    plot.close(fig)
