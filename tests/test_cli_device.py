"""The ``--device`` options of every command (hapid/_cli_device.py) and the scene's
``[device]`` keys ``delay_samples``, ``rod_compliance`` reach the simulated device: checked
against the Python ``preset(...)`` and the closed form of a delay, e^{-jωT} per sample."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from helpers import rel_err
from helpers_cli import assert_clean_error, run_cli, write_valid_files

from hapid import io as hio
from hapid import pipeline, scene
from hapid.device import PRESETS, preset


def _same_device(dev, ref):
    """The same device: equal parameter leaves and structure (delay, encoder, modes, n are
    static fields of the tree)."""
    la, ta = jax.tree_util.tree_flatten(dev)
    lb, tb = jax.tree_util.tree_flatten(ref)
    assert ta == tb
    assert all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(la, lb, strict=True))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("devargs")
    return d, write_valid_files(d)


def test_preset_names_in_help_and_errors_are_the_registry():
    from hapid._cli_device import PRESET_NAMES

    assert sorted(PRESET_NAMES) == sorted(PRESETS)


def test_plant_options_equal_the_python_preset(tmp_path):
    rc, out, err, _, _ = run_cli(["plant", "--device", "cu5", "--delay", "2", "--rod-compliance",
                                  "2.0", "--f-min-hz", "1", "--f-max-hz", "450", "--n-freq", "30",
                                  "--out", "p.npz"], tmp_path)  # fmt: skip
    assert rc == 0, err
    frf = hio.load_frf(tmp_path / "p.npz")
    ref = preset("cu5", delay_samples=2, rod_compliance=2.0)
    for a, b in zip((frf.Z_H, frf.Z_T), ref.sampled_impedances(frf.omega), strict=True):
        assert rel_err(a, b) < 1e-12
    # the options changed the plant (it is not the preset's default)
    ZT0 = np.asarray(preset("cu5").sampled_impedances(frf.omega)[1])
    change = np.linalg.norm(frf.Z_T - ZT0, axis=(1, 2)) / np.linalg.norm(ZT0, axis=(1, 2))
    assert change.max() > 0.1


def test_simulate_delay_adds_the_delay_phase_to_Z_T_only(tmp_path):
    """One more sample of delay: the run's empirical Z_T = −𝓡_A 𝓛⁻¹ gains e^{+jωT} (the
    command leads the delayed motion by one more sample), Z_H = −𝓡_I 𝓛⁻¹ is unchanged
    (noise-free periodic steady state: exact)."""
    from hapid.experiment import estimate_frf

    common = ["--freqs", "2,10,50,120", "--periods", "1", "--noise", "0", "--encoder-res", "0"]
    frfs = []
    for extra in ([], ["--delay", "2"]):
        name = f"run{len(frfs)}.npz"
        rc, _, err, _, _ = run_cli(["simulate", "--device", "cu5", *extra, *common, "--out", name],
                                   tmp_path)  # fmt: skip
        assert rc == 0, err
        frfs.append(estimate_frf(hio.load_run(tmp_path / name)))
    f1, f2 = frfs  # cu5's own delay is 1 sample
    phase = np.exp(1j * np.asarray(f1.omega) * 1e-3)[:, None, None]
    assert rel_err(f2.Z_T, phase * np.asarray(f1.Z_T)) < 1e-9
    assert rel_err(f2.Z_H, f1.Z_H) < 1e-9
    assert rel_err(f2.Z_T, f1.Z_T) > 0.1  # the delay is really there at 50, 120 Hz


class _Stop(Exception):
    pass


def _capture(monkeypatch, module, name, argv, cwd):
    """Run ``hapid argv`` with ``module.name`` replaced by a stub that records its ``device``
    keyword and stops: the device the command would validate on."""
    got = {}

    def stub(*args, **kw):
        got["device"] = kw.get("device")
        raise _Stop

    monkeypatch.setattr(module, name, stub)
    monkeypatch.setenv("HAPID_DEBUG", "1")  # let _Stop through main's error handling
    with pytest.raises(_Stop):
        run_cli(argv, cwd)
    return got["device"]


def test_tune_robust_analyze_validate_on_the_varied_device(files, monkeypatch):
    import hapid.robust
    import hapid.tune

    d, _ = files
    ref = preset("cu5", delay_samples=2, rod_compliance=2.0)
    var = ["--device", "cu5", "--delay", "2", "--rod-compliance", "2.0"]
    dev = _capture(monkeypatch, hapid.tune, "tune_from_files",
                   ["tune", "--model", "model.npz", *var, "--out", "d.npz"], d)  # fmt: skip
    _same_device(dev, ref)
    var3 = ["--device", "tripod3", "--delay", "2", "--rod-compliance", "2.0"]  # model.npz: n = 3
    dev = _capture(monkeypatch, hapid.robust, "robust_from_files",
                   ["robust", "--samples", "samples.npz", "--model", "model.npz", *var3], d)  # fmt: skip
    _same_device(dev, preset("tripod3", delay_samples=2, rod_compliance=2.0))
    got = {}

    def plant_stub(device, *a, **k):
        got["device"] = device
        raise _Stop

    monkeypatch.setattr(pipeline, "device_plant", plant_stub)
    monkeypatch.setenv("HAPID_DEBUG", "1")
    with pytest.raises(_Stop):  # model.npz has n = 3: tripod3
        run_cli(["analyze", "--model", "model.npz", "--device", "tripod3", "--delay", "2"], d)
    _same_device(got["device"], preset("tripod3", delay_samples=2))


def test_scene_delay_and_compliance_reach_every_preset():
    for name in PRESETS:  # unset: the preset's own (cu5_soft keeps 2 samples, compliance 2)
        _same_device(pipeline.device(scene.merge({"device": {"preset": name}})["device"]),
                     preset(name))  # fmt: skip
    o = scene.merge({"device": {"preset": "tripod3", "delay_samples": 2, "rod_compliance": 2.0}})
    _same_device(
        pipeline.device(o["device"]), preset("tripod3", delay_samples=2, rod_compliance=2.0)
    )
    o = scene.set_option(scene.merge({"device": {"preset": "quad4"}}), "device.delay_samples", 2)
    _same_device(pipeline.device(o["device"]), preset("quad4", delay_samples=2))


def test_default_scene_device_is_unchanged():
    """The paper scene's device (no delay/compliance keys set) is cu5 exactly."""
    from hapid.device import cu5

    _same_device(pipeline.device(scene.merge({})["device"]), cu5())


def test_scene_file_keys_are_read(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('[device]\npreset = "hexapod6"\ndelay_samples = 2\nrod_compliance = 2.0\n')
    _same_device(pipeline.device(scene.load_scene(p)["device"]),
                 preset("hexapod6", delay_samples=2, rod_compliance=2.0))  # fmt: skip


@pytest.mark.parametrize(
    "argv, message",
    [(["plant", "--delay", "-1", "--out", "p.npz"], "--delay must be an integer in [0, 1000], got -1"),
     (["simulate", "--delay", "0.5", "--out", "r.npz"], "invalid int value: '0.5'"),
     (["simulate", "--rod-compliance", "0", "--out", "r.npz"], "--rod-compliance must be in [0.001, 1000], got 0"),
     (["demo", "--rod-compliance", "-2", "--out", "o"], "--rod-compliance must be in [0.001, 1000], got -2"),
     (["analyze", "--model", "model.npz", "--device", "cu5", "--rod-compliance", "nan"],
      "--rod-compliance must be in [0.001, 1000], got nan"),
     (["analyze", "--model", "model.npz", "--frf", "frf.npz", "--delay", "2"],
      "--delay: a variant of the --device preset; give --device too"),
     (["robust", "--samples", "samples.npz", "--model", "model.npz", "--rod-compliance", "2.0"],
      "--rod-compliance: a variant of the --device preset"),
     (["tune", "--model", "model.npz", "--samples", "samples.npz", "--move", "0.01", "0", "0",
       "--out", "d.npz"], "--move: a variant of the --device preset"),
     (["simulate", "--device", "quad5", "--out", "r.npz"], "--device must be a preset device (cu5, "),
     (["run", "scene.toml", "--set", "device.delay_samples=-1"],
      "device.delay_samples must be an integer in [0, 1000]"),
     (["run", "scene.toml", "--set", "device.delay_samples=1.5"], "device.delay_samples must be"),
     (["run", "scene.toml", "--set", "device.rod_compliance=0"],
      "device.rod_compliance must be a number in [0.001, 1000]"),
     (["sweep", "scene.toml", "--vary", "device.delay_samples=1.5", "--out", "sw"],
      "--vary device.delay_samples must be an integer, got 1.5"),
     (["sweep", "scene.toml", "--vary", "device.rod_compliance=0", "--out", "sw"],
      "device.rod_compliance must be a number in [0.001, 1000]")],
)  # fmt: skip
def test_bad_device_options_are_one_line_errors(files, argv, message):
    assert_clean_error(argv, files[0], message)


def test_sweep_static_device_values_reach_the_device(monkeypatch):
    """``--vary device.delay_samples`` / ``device.rod_compliance`` are static sweep options
    (one compile per value): each value, as the integer / number it is, builds the device."""
    from hapid import sweep

    seen = []

    def stub(o, *a, **k):
        seen.append((o["delay_samples"], o["rod_compliance"]))
        raise _Stop

    monkeypatch.setattr(pipeline, "base_device", stub)
    cfg = scene.merge({"device": {"preset": "tripod3"}})
    assert sweep.classify("device.delay_samples", cfg, "wls") == "static"
    for vary, want in (({"device.delay_samples": [2.0]}, (2, None)),
                       ({"device.rod_compliance": [2.0]}, (None, 2.0))):  # fmt: skip
        with pytest.raises(_Stop):
            sweep.run_sweep(cfg, vary, progress=False)
        assert seen[-1] == want and type(seen[-1][0]) is type(want[0])
