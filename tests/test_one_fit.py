"""One fit route: the same FRF gives the same fitted model in ``hapid fit``, ``hapid
posterior``, a scene and a sweep (same options), PSD-boundary refit included
(:func:`hapid.pipeline.control_fit`). The cases are FRFs where the refit triggers (a hand acting
in a subspace of the rods, as on hexapod6), so a command that fits the bare NLS model instead
fails these tests."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers_cli import run_cli
from helpers_fit import random_truth, synthetic_frf
from test_fit_pd_eps import _subspace_hand_truth

import hapid  # noqa: F401  (float64)
from hapid import io, pipeline
from hapid.fit import fit_nls, theta_to_model
from hapid.fit._problem import PD_EPS

MATS = (("hand", "M"), ("hand", "B"), ("hand", "K"), ("mechanism", "M"), ("mechanism", "B"),
        ("mechanism", "K"))  # fmt: skip


def _mats(m):
    return [np.asarray(getattr(getattr(m, part), name)) for part, name in MATS]


def _rel_diff(a, b) -> float:
    """Largest difference of the six matrices, relative to each matrix's largest entry."""
    return max(
        float(np.max(np.abs(x - y)) / np.max(np.abs(y)))
        for x, y in zip(_mats(a), _mats(b), strict=True)
    )


@pytest.fixture(scope="module")
def boundary_frf():
    """3 rods, a hand singular along (1, 1, 1)/√3: the bare fit's Ẑ_H has a root at ∞."""
    return synthetic_frf(_subspace_hand_truth(), rel_noise=1e-2, seed=15)


@pytest.mark.slow  # CI budget (~20 s); test_keep_boundary_… keeps fit → posterior fast
def test_posterior_is_built_around_the_model_hapid_fit_writes(tmp_path, boundary_frf):
    """``hapid posterior`` fits what ``hapid fit`` writes (refit included, said in its output
    and file) and holds the refit's strictly PD matrices where the fit's L Lᵀ part is on the
    boundary, in every draw."""
    from hapid.io import load_samples

    io.save_frf(tmp_path / "frf.npz", boundary_frf)
    bare = fit_nls(boundary_frf.band(0.0, 40.0), f_max_hz=None).model
    assert not pipeline.controller_ready(bare)  # the case exercises the refit
    rc, out_f, err, _, _ = run_cli(["fit", "frf.npz", "--out", "m.npz"], tmp_path)
    assert rc == 0, err
    rc, out_p, err, _, _ = run_cli(["posterior", "frf.npz", "--method", "laplace", "--samples",
                                    "40", "--model-error", "none", "--out", "s.npz"], tmp_path)  # fmt: skip
    assert rc == 0, err
    assert "pd_eps = 0.001" in out_f and "pd_eps = 0.001" in out_p
    model = io.load_model(tmp_path / "m.npz")
    ps = load_samples(tmp_path / "s.npz", n=3)
    behind = theta_to_model(jnp.asarray(ps.diagnostics["fit_theta"]), ps.scale)
    assert _rel_diff(behind, model) < 1e-12  # the same fit, to rounding
    assert float(ps.diagnostics["fit_pd_eps"]) == PD_EPS
    assert _rel_diff(model, bare) > 1e-5 and pipeline.controller_ready(model)  # not the bare fit
    # the boundary-held matrices are the refit's, strictly PD, in every draw
    held = {str(x) for x in np.atleast_1d(ps.diagnostics["fit_fixed"])}
    assert "M_H" in held
    draws = ps.physical()
    names = ("M_H", "B_H", "K_H", "M_M", "B_M", "K_M")
    for name in held:
        ref = _mats(model)[names.index(name)]
        np.testing.assert_allclose(draws[name], np.broadcast_to(ref, draws[name].shape),
                                   rtol=1e-9, atol=1e-12 * np.abs(ref).max())  # fmt: skip
    assert np.linalg.eigvalsh(draws["M_H"])[:, 0].min() > 0
    # the fit's own Laplace draws (laplace_samples) hold the same refitted matrices
    from hapid.uncertainty import laplace_samples
    from hapid.uncertainty._files import posterior_fit

    cf = posterior_fit(boundary_frf)
    nls, eps = cf.fit.result, cf.refit_pd_eps
    assert eps == PD_EPS and _rel_diff(nls.model, model) < 1e-12
    lap = laplace_samples(nls, 20).physical()
    np.testing.assert_allclose(lap["M_H"], np.broadcast_to(_mats(model)[0], lap["M_H"].shape),
                               rtol=1e-9, atol=1e-12 * np.abs(_mats(model)[0]).max())  # fmt: skip
    assert np.linalg.eigvalsh(lap["M_H"])[:, 0].min() > 0


def test_keep_boundary_keeps_the_bare_fit_in_fit_and_posterior(tmp_path, boundary_frf, monkeypatch):
    """The opt-out is one flag with one meaning: ``--keep-boundary`` reaches the posterior's
    fit, which is then ``hapid fit --keep-boundary``'s bare model (and without it, the
    refitted one)."""
    import hapid.uncertainty as hu
    from hapid.uncertainty._files import posterior_fit

    seen = {}

    def record(*args, **kwargs):  # the posterior's options, then stop before any work
        seen.update(kwargs)
        raise ValueError("recorded")

    monkeypatch.setattr(hu, "posterior_from_files", record)
    io.save_frf(tmp_path / "frf.npz", boundary_frf)
    for keep in (True, False):
        flag = ["--keep-boundary"] if keep else []
        rc, out, err, _, _ = run_cli(["fit", "frf.npz", "--out", "m.npz", *flag], tmp_path)
        assert rc == 0, err
        assert ("pd_eps" in out) == (not keep)
        cf = posterior_fit(boundary_frf, boundary_refit=not keep)
        nls, eps = cf.fit.result, cf.refit_pd_eps
        assert (eps is None) == keep
        assert _rel_diff(nls.model, io.load_model(tmp_path / "m.npz")) < 1e-12
        rc, _, err, _, _ = run_cli(["posterior", "frf.npz", "--out", "s.npz", *flag], tmp_path)
        assert rc == 2 and "recorded" in err
        assert seen["boundary_refit"] is (not keep)


@pytest.mark.slow  # CI budget (~18 s cold); the slow hexapod6 sweep test covers the traced path too
def test_control_fit_traced_equals_the_edge_fit(boundary_frf):
    """Under ``vmap`` (a sweep) the control fit selects per element: a batch of a boundary FRF
    (refitted) and a regular one (kept) gives the edge's two fits."""
    regular = synthetic_frf(random_truth(3, 5), rel_noise=1e-2, seed=15)
    batch = jax.tree.map(lambda a, b: jnp.stack([a, b]), boundary_frf, regular)
    o = {"weight": "relative", "f_max_hz": 40.0, "omega_c_hz": 7.0, "max_steps": 500}
    both = jax.jit(jax.vmap(lambda f: pipeline.control_fit(f, **o)))(batch)
    fits = both.fit
    assert np.asarray(both.refitted).tolist() == [True, False]
    for i, frf in enumerate((boundary_frf, regular)):
        cf = pipeline.control_fit(frf, **o)
        edge = cf.fit
        assert cf.refit_pd_eps == (PD_EPS if i == 0 else None)
        one = jax.tree.map(lambda x, i=i: x[i] if eqx.is_array(x) else x, fits.model)
        assert _rel_diff(one, edge.model) < 1e-9
        assert bool(fits.ok[i]) and int(fits.crhp_hand[i]) == int(edge.crhp_hand)


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_hexapod6_sweep_and_posterior_use_the_control_fit(tmp_path):
    """hexapod6 (the development device where the refit triggers): a sweep's ``nls`` fit is
    the control fit — its P·P̂⁻¹ band, CRHP count and refit flag are those of
    :func:`hapid.pipeline.control_fit`'s model — and ``hapid posterior`` is centred on the model
    ``hapid fit`` writes for the same FRF."""
    from hapid import scene, sweep
    from hapid.fit import pphat_band_db
    from hapid.io import load_samples

    cfg = scene.merge({"device": {"preset": "hexapod6"}})
    vary = {"protocol.seed": [0.0, 1.0]}
    m = sweep.run_sweep(cfg, vary, chunk=2, progress=False, estimator="nls").metrics
    assert np.all(m["fit_refit"]) and np.all(m["fit_ok"])
    o = {k: cfg["fit"][k] for k in scene.NLS_KEYS}
    d, p = cfg["device"], cfg["protocol"]
    dev = pipeline.vary_device(pipeline.base_device(d), d["move"], d["subject_seed"])
    for i, seed in enumerate((0, 1)):
        frf = pipeline.simulated_frf(dev, pipeline.protocol(p), seed, noise=p["noise"],
                                     position_noise=p["position_noise"], periods=p["periods"])  # fmt: skip
        cf = pipeline.control_fit(frf, **o)
        f = cf.fit
        assert cf.refit_pd_eps == PD_EPS
        P = dev.sampled_P(frf.omega)
        lo, hi = (
            float(x) for x in pphat_band_db(P, f.model, frf.omega, cfg["analysis"]["band_hz"])
        )
        assert m["pphat_min_db"][i] == pytest.approx(lo, abs=1e-6)
        assert m["pphat_max_db"][i] == pytest.approx(hi, abs=1e-6)
        assert m["crhp_hand"][i] == int(f.crhp_hand) == 0
        bare = pipeline.fit(frf, "nls", **o)
        blo, bhi = (
            float(x) for x in pphat_band_db(P, bare.model, frf.omega, cfg["analysis"]["band_hz"])
        )
        assert abs(blo - lo) + abs(bhi - hi) > 1e-3  # the bare fit would be told apart
        if i == 0:
            io.save_frf(tmp_path / "frf.npz", frf)
    for argv in (["fit", "frf.npz", "--out", "m.npz"],
                 ["posterior", "frf.npz", "--method", "laplace", "--samples", "20",
                  "--model-error", "white", "--out", "s.npz"]):  # fmt: skip
        rc, out, err, _, _ = run_cli(argv, tmp_path)
        assert rc == 0, err
        assert "pd_eps = 0.001" in out
    model = io.load_model(tmp_path / "m.npz")
    ps = load_samples(tmp_path / "s.npz", n=6)
    behind = theta_to_model(jnp.asarray(ps.diagnostics["fit_theta"]), ps.scale)
    assert _rel_diff(behind, model) < 1e-12
    assert float(ps.diagnostics["fit_pd_eps"]) == PD_EPS
