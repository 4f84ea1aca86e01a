"""The loci screen of loop_metrics (``_metrics_loci._loci_screen``): an interval it leaves out has no
unresolved locus step and no margin candidate for ANY pairing of numpy's eigenvalues, and the
analysis with the screen equals the analysis with eigenvalues at every frequency."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hapid  # noqa: F401  (float64)
import hapid.control._metrics as M
import hapid.control._metrics_loci as ML
from hapid.control import MetricsSpec
from hapid.control import _kernels as K


def _clustered_loops(n: int, N: int, spread: float, seed: int):
    """``L(jω_k) = g_k (I + E_k)``: a loop gain spiralling through the unit circle and the
    negative real axis several times (a delay), with a smooth random spread ``E`` (relative
    size ``spread``, growing with frequency) — loci clustered about ``g`` as where the model
    is right, spreading where it is not."""
    rng = np.random.default_rng(seed)
    w = np.geomspace(0.1, 300.0, N)
    g = 40.0 / (1j * w / 2.0 + 1.0) ** 2 * np.exp(-1j * w * 0.02)
    A, B = rng.standard_normal((2, n, n)) + 1j * rng.standard_normal((2, n, n))
    s = spread * (w / w[-1]) ** 0.5
    E = s[:, None, None] * (
        A[None] * np.cos(w)[:, None, None] + B[None] * np.sin(w / 3)[:, None, None]
    )
    return g[:, None, None] * (np.eye(n)[None] + E / np.sqrt(n))


def _np_crossings(a, b):
    """numpy restatement of the reference rules on paired ends ``a``, ``b`` ``(M, n)``: the
    phase step of ``1 + λ``, a negative-real-axis crossing (``Im`` changes sign, ``Re < 0``
    at the linearly interpolated crossing) and a unit-circle crossing."""
    dphi = np.abs(np.angle((1.0 + b) / (1.0 + a)))
    ch = (a.imag >= 0) != (b.imag >= 0)
    t = np.clip(np.where(ch, a.imag / np.where(ch, a.imag - b.imag, 1.0), 0.0), 0.0, 1.0)
    axis = ch & (a.real + t * (b.real - a.real) < 0)
    circle = (np.abs(a) >= 1) != (np.abs(b) >= 1)
    return dphi, axis, circle


@pytest.mark.parametrize(
    "n,spread,seed",
    [pytest.param(3, 0.05, 0, marks=pytest.mark.slow), (4, 0.3, 2)],  # CI budget
)
def test_left_out_intervals_have_nothing_for_any_pairing(n, spread, seed):
    L = _clustered_loops(n, 800, spread, seed)
    spec = MetricsSpec()
    keep = np.asarray(ML._loci_screen(K.to_entries(jnp.asarray(L)), spec))
    out = np.flatnonzero(~keep)
    assert out.size >= 0.3 * keep.size, out.size  # the screen has work to skip here
    e = np.linalg.eigvals(L)  # the independent reference's eigenvalues
    a = e[out]
    found = np.zeros(len(e) - 1, bool)
    for perm in itertools.permutations(range(n)):
        dphi, axis, circle = _np_crossings(a, e[out + 1][:, perm])
        assert np.all(dphi < spec.max_phase_step)
        assert not axis.any() and not circle.any()
        _, ax_all, ci_all = _np_crossings(e[:-1], e[1:][:, perm])
        found |= ax_all.any(1) | ci_all.any(1)
    assert found.any() and keep[found].all()  # it keeps every interval with a crossing


@pytest.mark.slow  # CI budget (~12 s); test_left_out_intervals_… keeps the screen fast
def test_nan_and_spread_loops_keep_everything():
    L = _clustered_loops(3, 200, 0.05, 0)
    L[50, 0, 0] = np.nan
    keep = np.asarray(ML._loci_screen(K.to_entries(jnp.asarray(L)), MetricsSpec()))
    assert keep[49] and keep[50]
    # loci spread over decades about their mean: nothing can be left out
    rng = np.random.default_rng(0)
    D = np.diag([1.0, 1e-3, 1e-6]) * 3.0
    V = rng.standard_normal((3, 3))
    L = (
        np.broadcast_to(V @ D @ np.linalg.inv(V), (50, 3, 3))
        * np.exp(-1j * np.linspace(0, 3, 50))[:, None, None]
    )
    assert np.all(np.asarray(ML._loci_screen(K.to_entries(jnp.asarray(L)), MetricsSpec())))


@pytest.mark.slow  # two compiles of the whole analysis
def test_screened_analysis_equals_eigenvalues_everywhere(monkeypatch):
    L = jnp.asarray(_clustered_loops(4, 1200, 0.1, 3))
    w = jnp.asarray(np.geomspace(0.1, 300.0, 1200))
    eye = jnp.broadcast_to(jnp.eye(4, dtype=L.dtype), L.shape)
    spec = MetricsSpec(disk=True)
    res = {}
    for flag in (True, False):
        monkeypatch.setattr(ML, "SCREEN_LOCI", flag)
        f = jax.jit(lambda P, w, p: M.metrics_screened(P, eye, w, p, None, spec))  # fresh trace
        res[flag] = {k: np.asarray(v) for k, v in f(L, w, jnp.asarray(0.0)).items()}
    for k, v in res[True].items():
        np.testing.assert_array_equal(v, res[False][k], err_msg=k)
    assert bool(res[True]["stable"]) or np.isfinite(res[True]["gm_db"])
