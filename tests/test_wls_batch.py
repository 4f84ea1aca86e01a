"""wls_batch_coefficients (issue 13) against wls_coefficients and an independent numpy
least-squares reference, for every input form it takes: complex numpy, complex JAX, float
pairs ((re, im) interleaved, numpy and JAX), and traced inside a caller's jit; programs reused
across values; its input checks."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers_fit import PAPER_FREQ_HZ

from hapid.fit import OMEGA_C_PAPER, wls, wls_batch_coefficients, wls_coefficients
from hapid.fit._checks import band_mask

F_MAX = 40.0  # Hz: the band of the masked cases


def _lstsq_reference(w, Z, omega_c=OMEGA_C_PAPER, mask=None):
    """min_θ Σ_k |h_k z_k − h_k·[s², s, 1]_k θ|² with θ real: numpy lstsq on the stacked
    [Re; Im] system of the kept frequencies (columns scaled to unit norm, undone after);
    Z ``(B, N, ...)`` complex → ``(B, 3, E)``."""
    keep = np.ones(len(w), bool) if mask is None else np.asarray(mask) != 0
    s = 1j * w[keep]
    h = 1.0 / (s + omega_c) ** 2
    A = h[:, None] * np.stack([s**2, s, np.ones_like(s)], axis=1)  # (N', 3)
    Ar = np.concatenate([A.real, A.imag])  # (2N', 3)
    c = np.linalg.norm(Ar, axis=0)
    B = Z.shape[0]
    Y = h[:, None, None] * np.moveaxis(Z.reshape(B, len(w), -1)[:, keep], 1, 0)  # (N', B, E)
    Y = Y.reshape(len(s), -1)
    theta = np.linalg.lstsq(Ar / c, np.concatenate([Y.real, Y.imag]), rcond=None)[0] / c[:, None]
    return np.moveaxis(theta.reshape(3, B, -1), 0, 1)


def _reference(w, Z, mask):
    """wls_coefficients on the frequency-first stack, as (B, 3, E)."""
    th = wls_coefficients(jnp.asarray(w), jnp.asarray(np.moveaxis(Z, 1, 0)), OMEGA_C_PAPER, mask)
    return np.moveaxis(np.asarray(th), 0, 1).reshape(Z.shape[0], 3, -1)


def _assert_close(got, want, tol=1e-12):
    """Relative to each row's (m, b or k) largest magnitude: the rows differ by ~10⁴."""
    got, want = np.asarray(got), np.asarray(want)
    assert got.shape == want.shape
    scale = np.abs(want).max(axis=(0, 2))[None, :, None]
    err = np.max(np.abs(got - want) / scale)
    assert err < tol, err


def _all_forms(w, Z, mask, traced=True):
    """θ of every input form: {name: (B, 3, E)}; ``traced``: also inside a caller's jit."""
    wj = jnp.asarray(w)
    pairs = Z.view(np.float64)  # (B, N, ..., 2m): (re, im) interleaved
    call = lambda z, **kw: wls_batch_coefficients(wj, z, OMEGA_C_PAPER, mask, **kw)  # noqa: E731
    out = {
        "numpy complex": call(Z),
        "jax complex": call(jnp.asarray(Z)),
        "numpy float pairs": call(pairs, float_pairs=True),
        "jax float pairs": call(jnp.asarray(pairs), float_pairs=True),
    }
    if traced:
        in_jit = jax.jit(
            lambda w_, z_, p_: (
                wls_batch_coefficients(w_, z_, OMEGA_C_PAPER, mask),
                wls_batch_coefficients(w_, p_, OMEGA_C_PAPER, mask, float_pairs=True),
            )
        )
        out["jax complex in a jit"], out["float pairs in a jit"] = in_jit(
            wj, jnp.asarray(Z), jnp.asarray(pairs)
        )
    return out


@pytest.mark.parametrize("n", [3, 5, 6])
def test_every_input_form_equals_wls_coefficients_and_numpy_lstsq(n):
    """Random FRFs scaled like impedances (∝ 1 + ω²), B = 3, the paper's 28 frequencies, all
    and a 40 Hz band: every form equals wls_coefficients and the numpy lstsq reference to
    1e-12."""
    rng = np.random.default_rng(n)
    w = 2 * np.pi * PAPER_FREQ_HZ
    B = 3
    Z = rng.standard_normal((B, len(w), 2, n, n)) + 1j * rng.standard_normal((B, len(w), 2, n, n))
    Z *= (1 + w**2)[None, :, None, None, None]
    for mask in (None, np.asarray(band_mask(jnp.asarray(w), F_MAX))):
        ref = _reference(w, Z, mask)
        _assert_close(ref, _lstsq_reference(w, Z, mask=mask))  # the two references agree
        for name, got in _all_forms(w, Z, mask, traced=mask is not None).items():
            assert got.shape == (B, 3, 2 * n * n), name
            _assert_close(got, ref)


def test_cu5_simulated_frfs_equal_per_frf_wls_and_lstsq():
    """Two noisy periodic runs of the cu5 device (paper protocol, hapid.experiment), stacked
    (B, N, 2, 5, 5): the batch equals wls() of each FRF (Z_H → hand, Z_T → total) and the
    numpy lstsq reference, in a 40 Hz band (and the whole grid against lstsq)."""
    from hapid.device import cu5
    from hapid.experiment import Protocol, estimate_frf, periodic_run

    dev = cu5()
    frfs = [estimate_frf(periodic_run(dev, Protocol(), noise_seed=s)) for s in (0, 1)]
    w = np.asarray(frfs[0].omega)
    Z = np.stack([np.stack([np.asarray(f.Z_H), np.asarray(f.Z_T)], axis=1) for f in frfs])
    mask = np.asarray(band_mask(jnp.asarray(w), F_MAX))
    ref = _lstsq_reference(w, Z, mask=mask)
    forms = _all_forms(w, Z, mask, traced=False)
    for got in forms.values():
        _assert_close(got, ref)
    _assert_close(wls_batch_coefficients(w, Z), _lstsq_reference(w, Z))  # whole grid
    th = np.asarray(forms["jax complex"]).reshape(2, 3, 2, 5, 5)
    for b, f in enumerate(frfs):
        model = wls(f, f_max_hz=F_MAX)
        for j, so in enumerate((model.hand, model.total)):
            for r, A in enumerate((so.M, so.B, so.K)):
                A = np.asarray(A)
                np.testing.assert_allclose(th[b, r, j], A, rtol=0, atol=1e-12 * np.abs(A).max())


def test_more_than_64_frequencies_and_odd_element_counts():
    """N = 70 (the GEMM branch of both kernels) and an odd element count E = 3."""
    rng = np.random.default_rng(0)
    for N, tail in ((70, (2, 3, 3)), (28, (3,))):
        w = 2 * np.pi * np.sort(rng.uniform(0.5, 90.0, N))
        Z = rng.standard_normal((2, N) + tail) + 1j * rng.standard_normal((2, N) + tail)
        mask = (w < 2 * np.pi * 60.0).astype(float)
        ref = _lstsq_reference(w, Z, mask=mask)
        for got in _all_forms(w, Z, mask, traced=N > 64).values():
            _assert_close(got, ref)


def test_calls_that_change_only_values_of_grid_corner_or_mask_follow_them():
    """The compiled programs are reused across calls of the same shapes: a call that changes
    only the grid's values, the corner or the mask gets its own fit, a repeated call the same."""
    rng = np.random.default_rng(1)
    Z = rng.standard_normal((2, 28, 8)) + 1j * rng.standard_normal((2, 28, 8))
    w1 = 2 * np.pi * PAPER_FREQ_HZ
    w2 = w1 * 1.1
    band = (PAPER_FREQ_HZ <= 40.0).astype(float)
    for w, oc, mask in ((w1, OMEGA_C_PAPER, None), (w2, OMEGA_C_PAPER, None),
                        (w1, 2 * np.pi * 3.0, None), (w1, OMEGA_C_PAPER, band),
                        (w1, OMEGA_C_PAPER, None)):  # fmt: skip
        ref = _lstsq_reference(w, Z, oc, mask)
        _assert_close(wls_batch_coefficients(w, Z, oc, mask), ref)
        _assert_close(
            wls_batch_coefficients(w, Z.view(np.float64), oc, mask, float_pairs=True), ref
        )


@pytest.mark.parametrize(
    "args,kwargs,match",
    [
        ((np.ones((2, 28)), np.ones((2, 28, 4), complex)), {}, r"omega must be \(N,\)"),
        ((np.ones(28), np.ones((2, 27, 4), complex)), {}, r"Z must be \(B, N, \.\.\.\) with N = "),
        ((np.ones(28), np.ones(28, complex)), {}, r"Z must be \(B, N, \.\.\.\)"),
        ((np.ones(28), np.ones((2, 28, 4), complex), OMEGA_C_PAPER, np.ones(27)), {},
         r"mask must be \(N,\)"),
        ((np.ones(28), np.ones((2, 28, 5))), {"float_pairs": True}, r".*even last axis"),
        ((np.ones(28), np.ones((2, 28))), {"float_pairs": True}, r".*\(B, N, \.\.\., 2m\)"),
        ((np.ones(28), np.ones((2, 28, 4), complex)), {"float_pairs": True},
         r".*needs real floating Z"),
        ((np.full(28, np.nan), np.ones((2, 28, 4), complex)), {}, r"omega contains NaN or inf"),
        ((np.ones(28), np.ones((2, 28, 4), complex), np.inf), {}, r"omega_c contains NaN"),
        ((np.ones(28), np.ones((2, 28, 4), complex), -1.0), {}, r"omega_c must be > 0"),
        ((np.ones(28), np.ones((2, 28, 4), complex), OMEGA_C_PAPER, np.full(28, np.nan)), {},
         r"mask contains NaN or inf"),
    ],
)  # fmt: skip
def test_bad_input_raises_a_clear_error(args, kwargs, match):
    with pytest.raises(ValueError, match="wls_batch_coefficients: " + match):
        wls_batch_coefficients(*args, **kwargs)


@pytest.mark.parametrize("form", ["numpy", "jax", "pairs", "masked"])
def test_nan_or_inf_in_z_is_named_with_its_index(form):
    """A NaN or inf anywhere in Z (also at a masked-out frequency) raises, naming the first bad
    index of Z as given; a finite Z passes."""
    w = 2 * np.pi * np.linspace(1.0, 50.0, 12)
    Z = np.ones((3, 12, 2, 2), complex)
    Z[1, 11, 0, 1] = np.nan if form != "pairs" else complex(1.0, np.inf)
    mask = (w < 2 * np.pi * 30.0).astype(float) if form == "masked" else None
    z = {"numpy": Z, "jax": jnp.asarray(Z), "masked": Z, "pairs": Z.view(np.float64)}[form]
    where = "(1, 11, 0, 3)" if form == "pairs" else "(1, 11, 0, 1)"
    with pytest.raises(
        ValueError, match=r"Z contains NaN or inf \(first at index " + re.escape(where)
    ):
        wls_batch_coefficients(w, z, OMEGA_C_PAPER, mask, float_pairs=form == "pairs")
    Z[1, 11, 0, 1] = 1.0
    assert np.isfinite(np.asarray(wls_batch_coefficients(w, Z, OMEGA_C_PAPER, mask))).all()
