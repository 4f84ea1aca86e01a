"""One loop, four commands, one answer: ``hapid analyze``, ``hapid sweep``, the paper scene
(``hapid paper``/``run``) and ``hapid tune``'s re-check on the true plant agree on cu5 with
the WLS + positize model and the paper's g to 0.05 dB / 0.1° / 0.01 Hz (issue 16).

The experiment is noise-free (no force/position noise, no quantization) so that the scene's
time-domain-free periodic run and the sweep's closed-form simulated FRF give the same model.

Margins are read on each command's grid with the crossing interpolation of
``hapid.control.analyze_loop`` (the refined crossings of ``loop_metrics`` are not on main
yet); all four commands use the same grid and the same stage, which is what this test pins.
"""

import json

import numpy as np
import pytest

import hapid  # noqa: F401  (float64)
from hapid import io, scene, sweep
from hapid.cli import main
from hapid.control import Compensator
from hapid.tune import true_plant_loop

TOL = {"iso_bandwidth_hz": 0.01, "gm_db": 0.05, "pm_deg": 0.1, "t_peak_db": 0.05, "t_peak_hz": 0.01}


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_analyze_sweep_scene_and_tune_agree_on_one_loop(tmp_path, capsys):
    cfg = scene.merge({"protocol": {"noise": 0.0, "position_noise": 0.0, "encoder_res": 0.0}})
    res, _ = scene.run_scene(cfg, ["device", "wls", "mimo"], out_dir=tmp_path, cache_dir=None)
    model, dev = res["wls"]["model"], res["device"]
    numbers = {"scene": res["mimo"]["wls"]["report"].summary()}

    io.save_model(tmp_path / "wls.npz", model, method="wls+positize")
    assert main(["analyze", "--model", str(tmp_path / "wls.npz"), "--device", "cu5",
                 "--out", str(tmp_path / "a.json")]) == 0  # fmt: skip
    numbers["analyze"] = json.loads((tmp_path / "a.json").read_text())

    keys, rows, m = sweep.run_sweep(
        cfg, {"controller.k": [0.85]}, progress=False, estimator="wls+positize"
    )
    numbers["sweep"] = {k: float(v[0]) for k, v in m.items()}

    numbers["tune"] = true_plant_loop(Compensator.paper(), model, dev)

    ref = numbers["scene"]
    assert ref["stable"]
    for name, got in numbers.items():
        assert bool(got["stable"]) == ref["stable"], name
        for k, tol in TOL.items():
            if k in got:
                assert abs(float(got[k]) - float(ref[k])) <= tol, (name, k, got[k], ref[k])
    # the sweep's closed-form FRF and the scene's periodic run give the same model
    assert np.isfinite(numbers["sweep"]["gm_db"])
