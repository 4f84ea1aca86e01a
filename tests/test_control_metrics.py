"""loop_metrics (screened XLA kernels, refined crossings) against analyze_loop (LAPACK reference)."""

import jax.numpy as jnp
import numpy as np
import pytest

import hapid  # noqa: F401  (float64)
from hapid.control import (
    Compensator,
    MetricsSpec,
    analyze_loop,
    inverse_model_response,
    loop_metrics,
)
from hapid.control._examples import example_model
from hapid.impedance import ImpedanceModel, SecondOrder

SPEC = MetricsSpec(disk=True)


def _perturbed(m: ImpedanceModel, eps: float, seed: int) -> ImpedanceModel:
    rng = np.random.default_rng(seed)

    def p(x):
        x = np.asarray(x)
        E = eps * rng.standard_normal(x.shape)
        return x + 0.5 * (E + E.T) * np.abs(x).max()

    h, t = m.hand, m.total
    return ImpedanceModel(
        hand=SecondOrder(p(h.M), p(h.B), p(h.K)), total=SecondOrder(p(t.M), p(t.B), p(t.K))
    )


def _loop(n=5, eps=0.03, seed=0):
    m = example_model(n, seed=seed)
    mh = _perturbed(m, eps, seed + 7)
    g = Compensator.paper()

    def L_fn(om):
        return m.P(1j * om) @ inverse_model_response(mh, g, om)

    def on(N, lo=-1.0, hi=3.5):
        w = jnp.logspace(lo, hi, N)
        return m.P(1j * w), inverse_model_response(mh, g, w), w

    return on, L_fn


@pytest.mark.slow  # CI budget: covered in the default run by test_one_answer / test_readme_table
def test_verdict_and_refined_metrics_match_the_reference_and_do_not_depend_on_the_grid():
    on, L_fn = _loop()
    P, G, w = on(3000)
    ref = analyze_loop(P, G, w, L_fn=L_fn)
    q = loop_metrics(P, G, w, spec=SPEC)
    assert bool(q.stable) == bool(ref.stable) and bool(q.stable)
    assert not bool(q.exact_fallback)  # a near-scalar loop is decided by the screen
    # margins: the reference refines them exactly on L_fn
    np.testing.assert_allclose(float(q.pm_deg), float(ref.pm_deg), atol=1e-6)
    np.testing.assert_allclose(float(q.pm_freq_hz), float(ref.pm_freq_hz), rtol=1e-7)
    assert float(q.gm_db) == pytest.approx(float(ref.gm_db), abs=1e-6) or (
        np.isinf(float(q.gm_db)) and np.isinf(float(ref.gm_db))
    )
    # grid values of the reference are within a grid step of the refined ones
    dlog = np.log(float(w[1] / w[0]))
    assert abs(np.log(float(q.iso_bandwidth_hz) / float(ref.iso_bandwidth_hz))) < dlog
    assert float(q.t_peak_db) >= float(ref.t_peak_db) - 1e-9
    assert float(q.t_peak_db) - float(ref.t_peak_db) < 1e-3
    # the same loop on other grids (and exactly on L_fn): 0.05 dB / 0.1° / 0.01 Hz
    exact = loop_metrics(P, G, w, spec=SPEC, L_fn=L_fn)
    for N, lo, hi in ((700, -1.0, 3.5), (1500, -2.0, 4.0)):
        o = loop_metrics(*on(N, lo, hi), spec=SPEC)
        assert abs(float(o.pm_deg) - float(exact.pm_deg)) < 0.1
        assert abs(float(o.t_peak_db) - float(exact.t_peak_db)) < 0.05
        for f in ("iso_bandwidth_hz", "pm_freq_hz", "t_peak_hz"):
            assert abs(float(getattr(o, f)) - float(getattr(exact, f))) < 0.01, f


@pytest.mark.slow  # two compiles of the full analysis (~1 min on a loaded 2-core machine)
def test_xla_kernels_equal_the_lapack_path():
    on, _ = _loop(n=4, eps=0.05, seed=3)
    P, G, w = on(1200)
    a = loop_metrics(P, G, w, spec=SPEC).summary()
    b = loop_metrics(P, G, w, spec=MetricsSpec(disk=True, kernels="lapack")).summary()
    for k, v in a.items():
        if isinstance(v, float):
            # the location of a smooth maximum is only determined to ~√ε (flat top)
            rtol = 1e-6 if k == "t_peak_hz" else 1e-9
            np.testing.assert_allclose(v, b[k], rtol=rtol, atol=1e-12, err_msg=k)
        else:
            assert v == b[k], k


@pytest.mark.slow
def test_unstable_and_singular_loops_have_the_reference_verdict():
    on, _ = _loop(n=3, eps=0.02, seed=1)
    P, G, w = on(800)
    for k, p_ol in ((40.0, 0), (1.0, 1)):  # too much gain; a claimed open-loop RHP pole
        ref = analyze_loop(P, k * G, w, p_ol)
        q = loop_metrics(P, k * G, w, p_ol=p_ol)
        assert bool(q.stable) == bool(ref.stable)
        assert int(q.n_closed_loop_rhp) == int(ref.n_closed_loop_rhp)
        assert not bool(q.stable) and np.isnan(float(q.iso_bandwidth_hz))
    ws = np.logspace(-1, 2, 301)
    Ps = (ws[150] ** 2 / (1j * ws) ** 2)[:, None, None] * np.eye(2)
    Gs = np.broadcast_to(np.eye(2), Ps.shape)
    q = loop_metrics(Ps, Gs, ws)
    assert bool(q.singular) and not bool(q.stable) and q.status == "singular"


def test_bad_shapes_are_a_clear_error():
    with pytest.raises(ValueError, match="omega"):
        loop_metrics(np.zeros((5, 2, 2)), np.zeros((5, 2, 2)), np.ones(4))


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_nyquist_family_verdicts_equal_the_reference():
    """Random loops of the Nyquist test family (tests/test_control_nyquist.py): loop_metrics'
    verdict and closed-loop RHP count equal analyze_loop's and the state-space truth."""
    import jax
    from test_control_nyquist import _family

    groups, _ = _family(30, seed=2, N=1500)
    spec = MetricsSpec(bandwidth=False, t_peak=False)
    va = jax.jit(jax.vmap(analyze_loop))
    n_loops = 0
    for _, items in sorted(groups.items()):
        Pj, Gj, W, pol, Z = (np.stack(x) for x in zip(*items, strict=True))
        ref = va(Pj, Gj, W, pol)
        for i in range(len(Z)):
            q = loop_metrics(Pj[i], Gj[i], W[i], p_ol=pol[i], spec=spec)
            assert bool(q.stable) == bool(ref.stable[i]) == (Z[i] == 0)
            assert int(q.n_closed_loop_rhp) == int(ref.n_closed_loop_rhp[i])
            n_loops += 1
    assert n_loops >= 25
