"""The one set of frequency-grid builders (hapid._grids) and the shared constants."""

import math
from math import tau as TWO_PI

import numpy as np
import pytest

from hapid import _grids
from hapid.scene import analysis_grid, merge
from hapid.tune import device_grid, posterior_grid
from hapid.uncertainty import posterior_omega, robust_omega


def test_two_pi_is_two_pi():
    assert TWO_PI == 2.0 * math.pi == 2.0 * np.pi


def test_log_grid_matches_numpy_logspace():
    om = _grids.log_grid_hz(0.1, 300.0, 57)
    ref = 2.0 * np.pi * np.logspace(np.log10(0.1), np.log10(300.0), 57)
    np.testing.assert_allclose(om, ref, rtol=1e-13)
    assert om.dtype == np.float64 and np.all(np.diff(om) > 0)


def test_nyquist_grid_ends_at_nyquist():
    fs = 1000.0
    om = _grids.nyquist_grid(fs, 200, 0.01)
    assert om.shape == (200,) and np.all(np.diff(om) > 0)
    assert om[-1] == pytest.approx(np.pi * fs, rel=1e-15)
    assert om[-2] < np.pi * fs and om[0] == pytest.approx(2 * np.pi * 0.01)


def test_named_grids_are_the_one_implementation():
    cfg = merge({})["analysis"]
    np.testing.assert_array_equal(
        analysis_grid(cfg, 1000.0), _grids.nyquist_grid(1000.0, cfg["n_freq"], cfg["f_min_hz"])
    )
    np.testing.assert_array_equal(device_grid(1000.0), _grids.nyquist_grid(1000.0))
    np.testing.assert_array_equal(posterior_grid(), posterior_omega())
    np.testing.assert_array_equal(posterior_omega(), _grids.continuous_grid())
    np.testing.assert_array_equal(robust_omega(300), _grids.sampled_grid(300))
    # documented bands (Hz)
    f = robust_omega() / (2 * np.pi)
    assert f[0] == pytest.approx(0.05) and f[-1] == pytest.approx(450.0) and f.size == 1000
    f = posterior_omega() / (2 * np.pi)
    assert f[0] == pytest.approx(0.005) and f[-1] == pytest.approx(5000.0) and f.size == 1500


@pytest.mark.parametrize("args", [(0.0, 10.0, 5), (10.0, 1.0, 5), (1.0, 10.0, 1), (1.0, np.inf, 5)])
def test_bad_grid_is_a_clear_error(args):
    with pytest.raises(ValueError, match="frequency grid"):
        _grids.log_grid_hz(*args)


def test_traced_bounds_give_the_same_grid():
    """A swept f_min_hz is traced inside the sweep's jit/vmap: same grid as the numpy path."""
    import jax

    from hapid import pipeline

    traced = jax.jit(lambda f: _grids.nyquist_grid(1000.0, 50, f))(0.02)
    np.testing.assert_allclose(
        np.asarray(traced), _grids.nyquist_grid(1000.0, 50, 0.02), rtol=1e-13
    )
    np.testing.assert_allclose(
        np.asarray(
            jax.vmap(lambda f: pipeline.analysis_grid(f, 30, f_max_hz=5e3))(np.array([0.01, 0.1]))
        )[1],
        _grids.log_grid_hz(0.1, 5e3, 30),
        rtol=1e-13,
    )
