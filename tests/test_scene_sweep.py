"""Scenes compute only what their outputs need; sweeps batch configurations exactly."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from hapid import scene, sweep


def test_zh_only_scene_runs_no_controller_stages(tmp_path):
    cfg = scene.merge({"outputs": {"want": ["fig6"]}})
    log = scene.run_scene(cfg, out_dir=tmp_path, cache_dir=tmp_path / "cache")
    ran = set(log.computed)
    assert {"device", "run", "frf", "wls", "nls", "fig6"} == ran
    # the controller-side stages exist in the graph (so "did not run" can fail) and did not run
    controller_side = {"controller", "mimo", "siso", "plant", "tuned", "tuned_mimo"}
    assert controller_side <= set(scene.graph().stages)
    assert not ran & controller_side
    assert (tmp_path / "fig6.png").exists()


@pytest.mark.slow  # CI budget (~30 s): stage skipping stays in test_zh_only_scene_runs_no_controller_stages, cache keys in test_stage_cache
def test_changing_the_gain_reruns_only_controller_and_analysis(tmp_path):
    cfg = scene.merge({"analysis": {"n_freq": 300}})
    want = ["fig5", "fig6", "fig9"]  # fig10/summary (with the tuned g): the paper notebook test
    first = scene.run_scene(cfg, want, out_dir=tmp_path, cache_dir=tmp_path / "c")
    assert "mimo" in first.computed and "run" in first.computed
    cfg2 = scene.set_option(cfg, "controller.k", 0.6)
    second = scene.run_scene(cfg2, want, out_dir=tmp_path, cache_dir=tmp_path / "c")
    cached_stages = {"device", "run", "frf", "wls", "nls", "plant"}
    assert cached_stages <= set(second.cached)
    assert {"controller", "mimo", "siso"} <= set(second.computed)
    assert not cached_stages & set(second.computed)
    # the same config again: every cacheable stage comes from disk
    third = scene.run_scene(cfg2, want, out_dir=tmp_path, cache_dir=tmp_path / "c")
    assert set(third.computed) <= {"fig5", "fig6", "fig9"}


def test_scene_errors_are_clear(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[device]\npreset = 'cu5'\nwheels = 4\n")
    with pytest.raises(ValueError, match="unknown key device.wheels"):
        scene.load_scene(bad)
    with pytest.raises(ValueError, match="unknown output"):
        scene.run_scene(scene.merge({}), ["fig11"], out_dir=tmp_path, cache_dir=None)


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_sweep_of_256_configurations_matches_single_runs():
    cfg = scene.merge({"analysis": {"n_freq": 200}})
    vary = {"controller.k": [0.4, 0.6, 0.85, 1.0], "protocol.noise": [1e-3, 5e-3, 2e-2, 5e-2],
            "fit.omega_c_hz": [3.0, 7.0, 12.0, 20.0], "protocol.seed": [0, 1, 2, 3]}  # fmt: skip
    res = sweep.run_sweep(cfg, vary, chunk=256, progress=False)
    keys, rows, batched = res.keys, res.params, res.metrics
    assert rows.shape == (256, 4)
    # each single run builds and loads its own program (5-50 s): 16 of the 256, chosen so
    # that every value of every option is among them
    pick = np.random.default_rng(3).choice(256, 16, replace=False)
    for j, values in enumerate(vary.values()):
        assert set(rows[pick, j]) == set(values)
    singles = [sweep.run_single(cfg, keys, r) for r in rows[pick]]
    for m in sweep.METRICS:
        b = np.asarray(batched[m], float)[pick]
        s = np.asarray([x.metrics[m] for x in singles], float)
        np.testing.assert_allclose(b, s, rtol=1e-7, atol=1e-9, equal_nan=True, err_msg=m)
    # physically sensible: more gain, wider isotropic bandwidth while stable
    assert np.any(batched["stable"]) and not np.all(np.isnan(batched["iso_bandwidth_hz"]))


def test_sweep_rejects_unknown_options():
    cfg = scene.merge({})
    for bad in ("device.preset", "device.wheels", "protocol.encoder_res", "controller.notch_hz[7]"):
        with pytest.raises(ValueError, match="cannot sweep"):
            sweep.run_sweep(cfg, {bad: [1.0]}, progress=False)
    with pytest.raises(ValueError, match="not an option of estimator"):
        sweep.run_sweep(cfg, {"fit.rtol": [1e-6]}, progress=False, estimator="wls+positize")
    assert sweep.classify("fit.rtol", cfg, "nls") == "traced"
    assert sweep.classify("analysis.n_freq", cfg, "nls") == "static"
    assert sweep.classify("controller.lowpass_hz[1]", cfg, "nls") == "traced"


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_sweep_shards_over_two_host_devices(tmp_path):
    code = textwrap.dedent("""
        import jax, numpy as np
        from hapid import scene, sweep
        assert jax.device_count() == 2
        cfg = scene.merge({"analysis": {"n_freq": 100}})
        r = sweep.run_sweep(cfg, {"controller.k": [0.5, 0.7, 0.85, 1.0]}, chunk=4, progress=False)
        s = sweep.run_single(cfg, r.keys, r.params[2])
        np.testing.assert_allclose(r.metrics["disk_margin"][2], s.metrics["disk_margin"], rtol=1e-8)
        print("OK")
    """)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    res = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=1100
    )
    assert res.returncode == 0 and "OK" in res.stdout, res.stderr[-2000:]
