"""Diagnostics: singular values of Z vs Ẑ and of P P̂⁻¹, band and anisotropy reduction."""

import jax.numpy as jnp
import numpy as np
import pytest
from helpers_fit import random_truth, synthetic_frf

from hapid.fit import (
    anisotropy_reduction,
    impedance_singular_values,
    model_relative_errors,
    pphat_band_db,
    pphat_singular_values,
)
from hapid.impedance import ImpedanceModel, SecondOrder


def _perturbed(truth, eps=0.05, seed=0):
    rng = np.random.default_rng(seed)
    p = lambda A: jnp.asarray(np.asarray(A) * (1 + eps * rng.standard_normal(np.shape(A))))  # noqa: E731
    return ImpedanceModel(
        hand=SecondOrder(p(truth.hand.M), p(truth.hand.B), p(truth.hand.K)),
        total=SecondOrder(p(truth.total.M), p(truth.total.B), p(truth.total.K)),
    )


def test_exact_model_gives_identity():
    truth = random_truth(4, seed=1)
    frf = synthetic_frf(truth, rel_noise=0.0)
    lo, hi = pphat_band_db(frf.P, truth, frf.omega, f_max_hz=30.0)
    assert abs(float(lo)) < 1e-9 and abs(float(hi)) < 1e-9
    sv = np.asarray(frf.P)
    sp = np.linalg.svd(sv, compute_uv=False)
    span = sp[:, 0] / sp[:, -1]
    keep = np.asarray(frf.freq_hz) <= 30.0
    amin, amax = anisotropy_reduction(frf.P, truth, frf.omega, f_max_hz=30.0)
    np.testing.assert_allclose(
        [float(amin), float(amax)], [span[keep].min(), span[keep].max()], rtol=1e-8
    )
    s = impedance_singular_values(frf, truth)
    np.testing.assert_allclose(np.asarray(s.Z_H), np.asarray(s.Z_H_hat), rtol=1e-10)
    np.testing.assert_allclose(np.asarray(s.Z_T), np.asarray(s.Z_T_hat), rtol=1e-10)
    assert np.asarray(model_relative_errors(truth, truth)).max() == 0.0


def test_against_numpy_for_a_perturbed_model():
    truth = random_truth(3, seed=2)
    frf = synthetic_frf(truth, rel_noise=0.0)
    model = _perturbed(truth)
    w = np.asarray(frf.omega)
    s = 1j * w[:, None, None]
    ZH = np.asarray(model.hand.M) * s**2 + np.asarray(model.hand.B) * s + np.asarray(model.hand.K)
    ZT = (
        np.asarray(model.total.M) * s**2 + np.asarray(model.total.B) * s + np.asarray(model.total.K)
    )
    P = np.asarray(frf.P)
    Q = P @ ZT @ np.linalg.inv(ZH)
    sv = np.linalg.svd(Q, compute_uv=False)
    np.testing.assert_allclose(
        np.asarray(pphat_singular_values(frf.P, model, frf.omega)), sv, rtol=1e-9
    )
    keep = np.asarray(frf.freq_hz) <= 30.0
    db = 20 * np.log10(sv[keep])
    lo, hi = pphat_band_db(frf.P, model, frf.omega, 30.0)
    np.testing.assert_allclose([float(lo), float(hi)], [db.min(), db.max()], rtol=1e-9)
    sp = np.linalg.svd(P, compute_uv=False)
    ratio = (sp[:, 0] / sp[:, -1]) / (sv[:, 0] / sv[:, -1])
    amin, amax = anisotropy_reduction(frf.P, model, frf.omega, 30.0)
    np.testing.assert_allclose(
        [float(amin), float(amax)], [ratio[keep].min(), ratio[keep].max()], rtol=1e-9
    )


def test_empty_band_raises():
    truth = random_truth(3, seed=3)
    frf = synthetic_frf(truth, rel_noise=0.0)
    with pytest.raises(ValueError, match="no frequencies"):
        pphat_band_db(frf.P, truth, frf.omega, f_max_hz=0.5)
