"""One answer per quantity (issue 16): every command reports the same refined numbers for the
same loop, whatever its grid, and those numbers are the loop's own (independent references).

* fast: a SISO-diagonal loop (three different scalar loops on the diagonal) through
  ``hapid.pipeline``'s backend against python-control's ``stability_margins`` (exact, on the
  transfer functions) and a numpy/scipy refinement of the σ̄ crossings, on two grids;
* slow: cu5 with the WLS + positize model and the paper's g through ``hapid analyze``,
  ``hapid sweep`` (n_freq 1500 and 3000), the paper scene (its summary numbers), ``tune``'s
  re-check on the true plant (its own grid) and ``robust_check`` of the nominal device plant —
  all within 0.05 dB / 0.1° / 0.01 Hz of each other — and against the numpy/scipy refinement
  on the exact loop and a 40 000-point brute-force grid for the loci margins.
"""

import json

import control
import jax.numpy as jnp
import numpy as np
import pytest
from helpers_loop import refined_numbers

import hapid  # noqa: F401  (float64)
from hapid import pipeline

TWO_PI = 2 * np.pi
TOL = {"iso_bandwidth_hz": 0.01, "gm_db": 0.05, "pm_deg": 0.1, "t_peak_db": 0.05,
       "t_peak_hz": 0.01, "disk_margin": 1e-3}  # fmt: skip

# three scalar loops l_i(s) = k_i / ((s + 1)(s/a_i + 1)(s/b_i + 1)): different margins each
_LOOPS = [(8.0, 5.0, 20.0), (12.0, 8.0, 30.0), (5.0, 3.0, 40.0)]


def _diag_L(w, xp=np):
    s = 1j * xp.asarray(w)
    ls = xp.stack([k / ((s + 1) * (s / a + 1) * (s / b + 1)) for k, a, b in _LOOPS], axis=-1)
    return ls[:, :, None] * xp.eye(3)


_EXACT = lambda w: _diag_L(w, jnp)  # noqa: E731


@pytest.mark.parametrize(
    "grids",
    [
        pytest.param([(400, None)], marks=pytest.mark.slow),  # the default run: one compile
        pytest.param([(300, None), (1700, _EXACT)], marks=pytest.mark.slow),
    ],
)
def test_siso_diagonal_loop_matches_python_control_and_scipy(grids):
    gms, pms = [], []
    for k, a, b in _LOOPS:
        tf = control.tf([k], np.polymul([1, 1], np.polymul([1 / a, 1], [1 / b, 1])))
        gm, pm, *_ = control.stability_margins(tf)
        gms.append(20 * np.log10(gm))
        pms.append(pm)
    ref_gm, ref_pm = min(gms), min(pms)
    results = []
    # (slow: a coarse grid refined on the interpolant, a fine one on the exact loop)
    for n_freq, L_fn in grids:
        omega = np.geomspace(1e-2, 1e4, n_freq)
        L = _diag_L(omega)
        G = np.broadcast_to(np.eye(3), L.shape)
        r = pipeline._loop._backend(L, G, omega, 0, pipeline.SPEC_REPORT, L_fn)
        assert bool(r.stable)
        results.append(r.numbers())
        ref = refined_numbers(_diag_L, omega)
    for s in results:
        assert abs(s["gm_db"] - ref_gm) < 0.01 and abs(s["pm_deg"] - ref_pm) < 0.02, s
        for k in ("iso_bandwidth_hz", "iso_bandwidth_literal_hz", "t_peak_db", "t_peak_hz",
                  "disk_margin"):  # fmt: skip
            assert abs(s[k] - ref[k]) <= 1e-3 * abs(ref[k]), (k, s[k], ref[k])
    # the balanced disk margin is conservative: its GM/PM never exceed the loop-at-a-time ones
    s = results[-1]
    assert s["disk_gm_db"] <= ref_gm + 1e-9 and s["disk_pm_deg"] <= ref_pm + 1e-9


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_analyze_sweep_scene_tune_and_robust_give_one_answer_on_cu5(tmp_path):
    from oracle_loop import analyze_loop

    from hapid import io, scene, sweep
    from hapid._grids import nyquist_grid
    from hapid.cli import main
    from hapid.control import Compensator
    from hapid.tune import true_plant_loop
    from hapid.uncertainty import robust_check

    cfg = scene.merge({"protocol": {"noise": 0.0, "position_noise": 0.0, "encoder_res": 0.0}})
    res = scene.run_scene(cfg, ["device", "wls", "mimo"], out_dir=tmp_path, cache_dir=None).results
    model, dev = res["wls"]["model"], res["device"]
    rep = res["mimo"]["wls"]["report"]
    numbers = {"scene": rep.numbers()}
    assert np.shape(rep.sv_T_minus_I)[1] == dev.n  # figures get every singular value

    io.save_model(tmp_path / "wls.npz", model, method="wls+positize")
    assert main(["analyze", "--model", str(tmp_path / "wls.npz"), "--device", "cu5",
                 "--out", str(tmp_path / "a.json")]) == 0  # fmt: skip
    numbers["analyze"] = json.loads((tmp_path / "a.json").read_text())

    sw = sweep.run_sweep(
        cfg, {"analysis.n_freq": [1500, 3000]}, progress=False, estimator="wls+positize"
    )
    for i, nf in enumerate(sw.params[:, 0]):
        numbers[f"sweep n_freq {int(nf)}"] = {k: float(v[i]) for k, v in sw.metrics.items()}

    g = Compensator.paper()
    numbers["tune"] = true_plant_loop(g, model, dev).numbers()  # its own grid (device_grid)

    omega = nyquist_grid(dev.fs_hz, 2500)
    ctrl = pipeline.controller(model, g, ts=dev.ts)
    rb = robust_check(np.asarray(dev.sampled_P(omega))[None], np.asarray(ctrl.response(omega)),
                      omega, controller_rhp=int(ctrl.p_rhp), metrics="all")  # fmt: skip
    numbers["robust"] = rb.rows()[0]

    ref = numbers["scene"]
    assert ref["stable"]
    for name, got in numbers.items():
        assert bool(got["stable"]) == ref["stable"], name
        for k, tol in TOL.items():
            if k in got:
                assert abs(float(got[k]) - float(ref[k])) <= tol, (name, k, got[k], ref[k])

    # independent references on the exact loop
    C = ctrl.discrete()
    A, B, Cm, D = (np.asarray(x) for x in (C.A, C.B, C.C, C.D))
    eye = np.eye(A.shape[0])

    def G_at(w):
        return np.stack([Cm @ np.linalg.solve(z * eye - A, B) + D for z in np.exp(1j * w * dev.ts)])

    def L_at(w):
        return np.asarray(dev.sampled_P(w)) @ G_at(w)

    om = scene.analysis_grid(cfg["analysis"], dev.fs_hz)
    num = refined_numbers(L_at, om)
    for k in ("iso_bandwidth_hz", "iso_bandwidth_literal_hz", "t_peak_db", "t_peak_hz",
              "disk_margin"):  # fmt: skip
        assert abs(ref[k] - num[k]) <= 1e-4 * abs(num[k]), (k, ref[k], num[k])
    dense = nyquist_grid(dev.fs_hz, 40000)
    brute = analyze_loop(np.asarray(dev.sampled_P(dense)), G_at(dense), dense, int(ctrl.p_rhp))
    assert abs(ref["gm_db"] - float(brute.gm_db)) < 0.01
    assert abs(ref["pm_deg"] - float(brute.pm_deg)) < 0.02
