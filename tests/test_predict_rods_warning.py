"""``hapid predict`` says in the run where its band was measured not calibrated: a warning for
a model of 6 or more rods (the params band measured too narrow at 16–40 Hz and too wide below
on 6-rod hexapods), none for 3–5 rods (measured calibrated) or for loop draws."""

import numpy as np
import pytest

from hapid import SecondOrder
from hapid._cli_predict import RODS_UNCALIBRATED, rods_warning
from hapid.cli import main
from hapid.fit import Scale, model_to_theta
from hapid.impedance import ImpedanceModel
from hapid.io import save_samples
from hapid.samples import PosteriorSamples
from hapid.uncertainty import param_names


def _spd(rng, n, scale):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + np.eye(n))


def _samples(tmp_path, n, S=6):
    """``S`` draws of an ``n``-rod second-order model near one point (no model error)."""
    rng = np.random.default_rng(n)
    hand = SecondOrder(_spd(rng, n, 0.3), _spd(rng, n, 10.0), _spd(rng, n, 500.0))
    total = SecondOrder(_spd(rng, n, 1.0) + hand.M, _spd(rng, n, 40.0) + hand.B,
                        _spd(rng, n, 200.0) + hand.K)  # fmt: skip
    scale = Scale(np.asarray(2 * np.pi * 8.0), np.asarray(500.0))
    th = np.asarray(model_to_theta(ImpedanceModel(hand=hand, total=total), scale))
    th = np.abs(th + 1e-4 * rng.standard_normal((S, th.size)))
    ps = PosteriorSamples(samples=th, log_prob=np.zeros(S), scale=scale, n=n,
                          names=tuple(param_names(n)))  # fmt: skip
    return save_samples(tmp_path / f"s{n}.npz", ps)


@pytest.mark.parametrize("n", [3, 5, 6, 7])
def test_predict_warns_on_models_of_six_or_more_rods(n, tmp_path, capsys):
    s = _samples(tmp_path, n)
    out = tmp_path / "d.npz"
    assert main(["predict", "--samples", str(s), "--n-freq", "5", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    with np.load(out) as z:
        assert z["P"].shape[1:] == (5, n, n) and np.all(np.isfinite(z["P"]))
    warned = [ln for ln in text.splitlines() if ln.startswith("WARNING")]
    if n < RODS_UNCALIBRATED:
        assert not warned
    else:
        assert len(warned) == 1 and f"{n} rods" in warned[0]
        assert "too narrow at 16–40 Hz" in warned[0] and "too wide below 16 Hz" in warned[0]
        assert ("no device with more than 6 rods" in warned[0]) == (n > 6)


def test_rods_warning_only_for_parameter_draws():
    assert rods_warning("loop_gp", 6) is None
    assert rods_warning("params", RODS_UNCALIBRATED - 1) is None
    assert rods_warning("params", RODS_UNCALIBRATED).startswith("WARNING")
    # the recalibrated band was measured calibrated on 3-6 rods: no warning there, a note
    # beyond (no larger device was measured)
    assert rods_warning("params", RODS_UNCALIBRATED, recalibrated=True) is None
    note = rods_warning("params", RODS_UNCALIBRATED + 1, recalibrated=True)
    assert note.startswith("note: this model has 7 rods") and "3–6 rods only" in note


def test_parameter_only_draws_do_not_claim_the_model_error_calibration(tmp_path, capsys):
    """``--no-model-error`` draws are not the calibrated band: predict says so instead of
    printing the gp_corr calibration note or the 6-rod warning about that band."""
    s = _samples(tmp_path, 6)
    out = tmp_path / "d.npz"
    argv = ["predict", "--samples", str(s), "--n-freq", "5", "--out", str(out)]
    assert main([*argv, "--no-model-error"]) == 0
    text = capsys.readouterr().out
    assert "parameter uncertainty only" in text and "was not measured against the true P" in text
    assert "gp_corr model error) was measured" not in text and "WARNING" not in text
