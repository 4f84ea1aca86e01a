"""One verdict per loop: the checks that report a requirement say passed / failed / not
established for the same loop at the same rate, and name that loop.

* ``hapid robust`` with a device: the loop draws conditioned on a noise-free dense FRF of the
  device's sampled plant give the device row's (= ``hapid analyze``'s) margins — the draws are
  checked with the controller discretized at the device's rate, not the continuous one;
* the tuned design's verdict (:func:`hapid.tune._check.design_check`): a failure on any
  evidence (true plant, held-out draws, measured loop) is ``failed`` even when the evidence
  certificate holds; a loop gain above the band beyond κ is ``not established``.
"""

from math import tau as TWO_PI

import numpy as np
import pytest

from hapid import io as hio
from hapid.frf import as_frf
from hapid.tune._check import design_check
from hapid.verdict import Verdict
from tests.helpers import second_order_device


@pytest.mark.slow  # ~1 min on 2 cores (compiles the sampled and continuous loop programs)
def test_robust_loop_draws_and_the_device_row_give_one_answer(tmp_path):
    from hapid.robust import robust_from_files

    dev = second_order_device(2, seed=3, delay_samples=2)
    model = dev.model
    f = np.geomspace(0.5, 400.0, 150)
    P = np.asarray(dev.sampled_P(TWO_PI * f))
    ZT = np.asarray(model.Z_T(1j * TWO_PI * f))
    s = np.full(P.shape, 1e-9)
    hio.save_frf(tmp_path / "frf.npz", as_frf(f, P @ ZT, ZT, s, s))
    hio.save_model(tmp_path / "model.npz", model)
    res = robust_from_files(None, tmp_path / "model.npz", frf_path=tmp_path / "frf.npz",
                            device=dev, max_samples=20)  # fmt: skip
    post, devr = res.posterior.numbers(), res.device.numbers()
    # the same loop at the same rate: the draws (collapsed on the noise-free dense FRF) give
    # the true sampled loop's margins (the continuous controller's differ by ~1.4 dB)
    assert post["gm_db_q50"] == pytest.approx(devr["gm_db_q50"], abs=0.05)
    assert post["pm_deg_q50"] == pytest.approx(devr["pm_deg_q50"], abs=0.1)
    assert post["iso_bandwidth_hz_q50"] == pytest.approx(devr["iso_bandwidth_hz_q50"], abs=0.01)
    assert post["verdict"] == devr["verdict"] == "passed"
    assert "sampled at 1000 Hz" in post["loop"] and "sampled at 1000 Hz" in devr["loop"]


_CERT = {"nominal_stable": True, "frf_min_loci_distance": 0.7, "beyond_loop_gain": 0.3,
         "evidence_hz": 100.0, "certified": True, "posterior_frac_meeting_margins": 1.0}  # fmt: skip


def test_design_verdict_fails_on_any_evidence_and_names_the_loop():
    kw = dict(gm_db=6.0, pm_deg=30.0, quantile=0.95)
    ck = design_check(_CERT, **kw, ts=1e-3)
    assert ck.verdict is Verdict.PASSED and "sampled at 1000 Hz" in ck.name
    assert "continuous-time" in design_check(_CERT, **kw).name
    # certified by the evidence, but the true plant at the device rate has PM 24.7°: failed
    row = _CERT | {"true_stable": True, "true_gm_db": 7.0, "true_pm_deg": 24.7}
    ck = design_check(row, **kw, ts=1e-3)
    assert ck.verdict is Verdict.FAILED and "24.7" in ck.reason
    # a signed negative PM of a stable loop is a margin of 35°: passes (|PM|, as analyze)
    assert design_check(row | {"true_pm_deg": -35.0}, **kw).ok
    # held-out draws below the chance level: failed
    ck = design_check(_CERT | {"posterior_frac_meeting_margins": 0.9}, **kw)
    assert ck.verdict is Verdict.FAILED
    # nothing failed, loop gain above the band 0.8 > κ: not established, with a remedy
    ck = design_check(_CERT | {"beyond_loop_gain": 0.8}, **kw, g_max=0.4)
    assert ck.verdict is Verdict.NOT_ESTABLISHED and "0.4" in ck.remedy and "100" in ck.remedy
    # parameter draws only (no FRF, no device): not established
    ck = design_check({"posterior_frac_meeting_margins": 1.0}, **kw)
    assert ck.verdict is Verdict.NOT_ESTABLISHED and "--frf" in ck.remedy


def test_negative_margins_of_a_stable_loop_are_explained():
    from hapid._analyze_check import margin_words

    assert margin_words(7.0, 35.0) == "GM 7.0 dB, PM 35.0°"
    w = margin_words(-3.1, 35.0)
    assert "GM 3.1 dB (signed -3.1 dB" in w and "gain decrease" in w and "PM 35.0°" in w
    assert "phase lead of 20.0°" in margin_words(7.0, -20.0)


@pytest.mark.slow  # ~1 min on 2 cores (compiles the loop program on a 400-point FRF)
def test_analyze_on_a_dense_frf_names_its_band_and_prints_the_verdict_first(tmp_path):
    """A 400-point plant FRF is not 'few frequencies'; the verdict (with its loop and rate)
    comes first. An FRF never reaches DC and fs/2, so the sampled loop's Nyquist count on it is
    unresolved: not established (never STABLE/passed on a partial contour), and a loop whose
    gain at the FRF's top is above κ says so."""
    from helpers_cli import run_cli

    dev = second_order_device(2, seed=3, delay_samples=1)
    model = dev.model
    for f_top in (450.0, 20.0):
        f = np.geomspace(0.5, f_top, 400)
        P = np.asarray(dev.sampled_P(TWO_PI * f))
        ZT = np.asarray(model.Z_T(1j * TWO_PI * f))
        s = np.full(P.shape, 1e-9)
        hio.save_frf(tmp_path / "frf.npz", as_frf(f, P @ ZT, ZT, s, s))
        hio.save_model(tmp_path / "model.npz", model)
        rc, out, err, _, _ = run_cli(["analyze", "--model", "model.npz", "--frf", "frf.npz",
                                      "--fs", "1000", "--gm-db", "6", "--pm-deg", "30"], tmp_path)  # fmt: skip
        assert rc == 0, err
        lines = out.strip().splitlines()
        assert lines[0].startswith("NOT ESTABLISHED"), lines
        assert "controller sampled at 1000 Hz" in lines[0], lines
        assert (f"the FRF covers 0.5–{f_top:g} Hz only" in lines[0]) == (f_top < 100), lines
        assert "few frequencies" not in out and f"400 frequencies, 0.5–{f_top:g} Hz" in out
