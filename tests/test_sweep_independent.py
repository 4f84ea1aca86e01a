"""Batched sweeps give exactly the verdicts and metrics of single analyses computed through an
independent path: the closed-loop state-space eigenvalues (no Nyquist count) for the verdict,
numpy/scipy for the controller's frequency response, T, S, σ(T − I), the bandwidth, the T peak
and the disk margin refined on the exact loop (``helpers_loop``), numpy eigenvalues for the controller's unstable poles, and the LAPACK
reference ``analyze_loop`` (unbatched, refined on the exact L) for the loci margins."""

import copy

import jax.numpy as jnp
import numpy as np
import pytest
from helpers_loop import refined_numbers

import hapid  # noqa: F401  (float64)
from hapid import pipeline, scene, sweep

TWO_PI = 2 * np.pi


def _cfg_with(cfg, keys, params):
    c = copy.deepcopy(cfg)
    for k, v in zip(keys, params, strict=True):
        sweep._set(c, k, float(v))
    return c


def reference(cfg, keys, params, estimator, margins=True):
    """One configuration through an independent analysis path (module docstring)."""
    from oracle_loop import analyze_loop

    from hapid.closed_loop import closed_loop
    from hapid.control import discretize_controller

    c = _cfg_with(cfg, keys, params)
    d, p = c["device"], c["protocol"]
    dev = pipeline.vary_device(pipeline.base_device(d), d["move"], d["subject_seed"])
    # a sweep's protocol.seed is the noise realization; the phases are the scene's protocol's
    frf = pipeline.simulated_frf(dev, pipeline.protocol(cfg["protocol"]), int(p["seed"]), noise=p["noise"],
                                 position_noise=p["position_noise"], periods=p["periods"])  # fmt: skip
    fo = sweep._fit_options(c["fit"], estimator)
    if estimator == "nls":  # the one NLS fit for control use (boundary refit), at the edge
        model = pipeline.control_fit(frf, **fo).model
    else:
        model = pipeline.fit(frf, estimator, **fo).model
    g = pipeline.compensator(c["controller"])
    ctrl = discretize_controller(model, g, dev.ts)
    A, B, C, D = (np.asarray(x) for x in (ctrl.A, ctrl.B, ctrl.C, ctrl.D))
    p_ol = int(np.sum(np.abs(np.linalg.eigvals(A)) > 1.0))  # unstable poles of G (numpy)
    stable = bool(np.max(np.abs(np.linalg.eigvals(np.asarray(closed_loop(dev, ctrl).A)))) < 1.0)
    fs = dev.fs_hz
    n_freq = int(c["analysis"]["n_freq"])
    f = np.append(np.geomspace(c["analysis"]["f_min_hz"], 0.49999 * fs, n_freq - 1), 0.5 * fs)
    omega = TWO_PI * f
    eye_x = np.eye(A.shape[0])

    def G_at(w):
        return np.stack(
            [C @ np.linalg.solve(zi * eye_x - A, B) + D for zi in np.exp(1j * w * dev.ts)]
        )

    def L_at(w):
        return np.asarray(dev.sampled_P(w)) @ G_at(w)

    P = np.asarray(dev.sampled_P(omega))
    G = G_at(omega)
    out = {"stable": stable, "p_ol": p_ol}
    if margins:  # loci margins: the LAPACK reference refined on the exact L

        def L_jax(w):  # the same L, traceable: the reference refines inside vmap/fori_loop
            z = jnp.exp(1j * w * dev.ts)[:, None, None]
            Bw = jnp.broadcast_to(B, (w.shape[0],) + B.shape)
            return jnp.asarray(dev.sampled_P(w)) @ (C @ jnp.linalg.solve(z * eye_x - A, Bw) + D)

        lap = analyze_loop(P, G, omega, P_ol_rhp=p_ol, L_fn=L_jax)
        out["gm_db"], out["pm_deg"] = float(lap.gm_db), float(lap.pm_deg)
    if stable:  # refined crossings and peaks of σ̄ (numpy/scipy on the exact L)
        out |= {
            k: v for k, v in refined_numbers(L_at, omega).items() if k != "iso_bandwidth_literal_hz"
        }
    else:
        out |= {"iso_bandwidth_hz": np.nan, "t_peak_db": np.nan, "disk_margin": 0.0}
    return out


def _check(cfg, vary, estimator, chunk, margins=True):
    res = sweep.run_sweep(cfg, vary, chunk=chunk, progress=False, estimator=estimator)
    keys, rows, m = res.keys, res.params, res.metrics
    for i in range(rows.shape[0]):
        ref = reference(cfg, keys, rows[i], estimator, margins)
        where = dict(zip(keys, rows[i], strict=True))
        assert bool(m["stable"][i]) == ref["stable"], where
        assert int(m["p_ol"][i]) == ref["p_ol"], where
        for k in ("iso_bandwidth_hz", "t_peak_db", "disk_margin") + (
            ("gm_db", "pm_deg") if margins else ()
        ):
            np.testing.assert_allclose(m[k][i], ref[k], rtol=1e-5, atol=1e-7, equal_nan=True,
                                       err_msg=f"{k} at {where}")  # fmt: skip
    return keys, rows, m


@pytest.mark.slow  # CI budget (~30 s); test_scene_sweep.py keeps the sweep route fast
def test_sweep_with_crhp_wls_positize_models_matches_closed_loop_eigenvalues():
    """tripod3, 4 N force noise, ω_c = 3 Hz: positizing leaves two CRHP roots of det Ẑ_H
    (two unstable controller poles). Seed 1: det(I + L) does not encircle 0 — the old sweep
    rule (``enc == 0``) called that stable; the closed loop is unstable. Seed 2: two
    counter-clockwise encirclements — stable, which the old rule called unstable."""
    cfg = scene.merge({"device": {"preset": "tripod3"}, "analysis": {"n_freq": 120},
                       "fit": {"omega_c_hz": 3.0}, "protocol": {"noise": 4.0}})  # fmt: skip
    # (margins: the slow test below compares GM/PM with the unbatched LAPACK reference)
    keys, rows, m = _check(
        cfg, {"protocol.seed": [1.0, 2.0]}, "wls+positize", chunk=2, margins=False
    )
    assert np.all(m["crhp_hand"] == 2) and np.all(m["p_ol"] == 2)
    assert np.all(m["nyquist_resolved"])
    old_rule = m["nyquist_resolved"] & (m["n_encirclements"] == 0)
    assert list(m["stable"]) == [False, True]
    assert list(old_rule) == [True, False]  # the bug issue 12 names, on both sides


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_sweep_over_nls_options_and_g_parameters_on_cu5_matches_single_analyses():
    cfg = scene.merge({})
    vary = {"fit.f_max_hz": [30.0, 40.0], "fit.rtol": [1e-8, 1e-6], "controller.k": [0.6, 0.85],
            "controller.notch_hz[0]": [15.0, 17.0], "analysis.n_freq": [200.0, 300.0]}  # fmt: skip
    keys, rows, m = _check(cfg, vary, "nls", chunk=16)
    assert rows.shape == (32, 5) and np.all(m["fit_ok"]) and np.any(m["stable"])
