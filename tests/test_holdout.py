"""The leave-one-frequency-out check of the params band (hapid.uncertainty.holdout_check,
``hapid predict``; issue 29): left-out = removed, a local feature the band cannot see is
found and named, a right model class is established, and the CLI prints the verdict."""

import dataclasses

import numpy as np
import pytest
from helpers_fit import random_truth, synthetic_frf

from hapid.cli import main
from hapid.fit import fit_nls
from hapid.impedance import plant
from hapid.io import save_samples
from hapid.uncertainty import (
    GPCorr,
    HoldoutStatus,
    White,
    band_calibration,
    holdout_check,
    make_log_posterior,
    posterior_laplace_samples,
    predictive_plants,
    recalibration,
)
from hapid.uncertainty._holdout import INFLATE

FREQ_HZ = np.array([1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0])
H10 = np.array(
    [np.log(0.05), np.log(0.02), np.log(0.4), np.log(0.8), 0.5, -0.3, 0.7, -0.4, 0.6, -0.5]
)  # fmt: skip  (fixed gp_corr hyperparameters: no mode search)


@pytest.fixture(scope="module")
def samples():
    """gp_corr Laplace samples of a strictly second-order 2-rod truth (model class right)."""
    frf = synthetic_frf(random_truth(2, seed=5), freq_hz=FREQ_HZ, rel_noise=1e-3, seed=6)
    nls = fit_nls(frf, weight="noise", f_max_hz=None).raise_if_failed()
    post = make_log_posterior(frf, nls.scale, f_max_hz=None, reference=nls,
                              model_error=GPCorr(hyper=tuple(H10)))  # fmt: skip
    return frf, nls, posterior_laplace_samples(post, 200, nls, key=0)


def _bumped(ps, k, rel):
    """``ps`` with the measured Z_H at fit frequency ``k`` changed by ``rel·‖Z_H‖`` (a local
    feature between the neighbours that the posterior's θ never saw)."""
    d = ps.predictive
    ZH = np.array(d["Z_H"])
    ZT = np.array(d["Z_T"])
    bump = rel * np.linalg.norm(ZH[k]) / ZH.shape[-1] * (1 + 1j)
    ZH[k] += bump  # the hand changes, the mechanism not: Z_T = Z_H + Z_M moves with it
    ZT[k] += bump
    return dataclasses.replace(ps, predictive={**d, "Z_H": ZH, "Z_T": ZT})


def test_left_out_frequency_equals_removed_frequency(samples):
    """The inflated variance of the left-out frequency gives the same predictive distribution
    at it as deleting it from the fit data: same draw mean (within 4 standard errors) and
    spread (within 10 %) of the model-error term, for one θ."""
    _, _, ps = samples
    one = dataclasses.replace(ps, samples=np.repeat(ps.samples[:1], 1500, axis=0),
                              log_prob=np.repeat(ps.log_prob[:1], 1500))  # fmt: skip
    d, k = one.predictive, 7  # 20 Hz
    big = INFLATE * (np.asarray(d["a_H"][k]) + np.asarray(d["a_M"][k])) ** 2
    vH, vT = np.array(d["var_H"]), np.array(d["var_T"])
    vH[k] += big
    vT[k] += big
    inflated = dataclasses.replace(one, predictive={**d, "var_H": vH, "var_T": vT})
    keep = np.arange(len(FREQ_HZ)) != k
    per_freq = ("omega", "Z_H", "Z_T", "var_H", "var_T", "a_H", "a_M")
    removed = dataclasses.replace(
        one, predictive={**d, **{key: np.asarray(d[key])[keep] for key in per_freq}}
    )
    om = np.asarray(d["omega"])[k : k + 1]
    a = predictive_plants(inflated, om, max_samples=None, seed=1).Z_H[:, 0]
    b = predictive_plants(removed, om, max_samples=None, seed=2).Z_H[:, 0]
    full = predictive_plants(one, om, max_samples=None, seed=3).Z_H[:, 0]
    se = np.std(a, axis=0) / np.sqrt(a.shape[0])
    assert np.all(np.abs(a.mean(0) - b.mean(0)) < 4 * np.sqrt(2) * se + 1e-12)
    ratio = np.std(a, axis=0) / np.std(b, axis=0)
    assert np.all(np.abs(ratio - 1) < 0.1), ratio
    # and it is not the full conditional (which sits on the measurement: noise-sized spread)
    assert np.all(np.std(full, axis=0) < 0.2 * np.std(a, axis=0))


def test_check_establishes_a_right_model_and_names_a_local_feature(samples):
    _, _, ps = samples
    c = holdout_check(ps, max_samples=200, seed=0)
    assert np.allclose(c.freq_hz, FREQ_HZ[1:-1])  # interior frequencies only
    assert c.status is HoldoutStatus.ESTABLISHED and c.ok and c.not_established_hz == []
    assert np.all(c.covers(np.geomspace(1, 40, 50)))
    # a 5 % feature at 20 Hz: found there, and (the GP carries it to its neighbours'
    # predictions) around it; the low frequencies far from it stay established
    bad = holdout_check(_bumped(ps, 7, 0.05), max_samples=200, seed=0)
    assert bad.status is HoldoutStatus.NOT_ESTABLISHED and 20.0 in bad.missed_hz
    assert list(bad.covers([2.5, 17.5, 22.5])) == [True, False, False]
    lo, hi = bad.not_established_hz[-1]
    assert lo <= 15.0 and hi >= 25.0 and np.all(bad.held[bad.freq_hz < 5])
    assert f"NOT ESTABLISHED at {bad.not_established_hz[0][0]:g}" in bad.message()
    # the remedy: the gaps' geometric midpoints (17.3, 22.4 Hz) on the measured 1 Hz grid
    assert 17.0 in bad.suggested_hz and 22.0 in bad.suggested_hz and "17, 22" in bad.message()
    js = bad.summary()
    assert js["status"] == "not established" and [lo, hi] in js["not_established_hz"]


def test_recalibrated_band_holds_on_a_right_model_and_widens_at_a_local_feature(samples):
    """On the right model class the recalibrated band still holds the true P between the
    measured frequencies; a 5 % feature at 20 Hz adds variance around it, far more than on the
    unbumped samples."""
    _, _, ps = samples
    truth = random_truth(2, seed=5)
    f = np.geomspace(1.2, 38.0, 40)
    om = 2 * np.pi * f
    P_true = np.asarray(plant(truth.hand.at_omega(om), truth.total.at_omega(om)))
    raw = predictive_plants(ps, om, max_samples=200, seed=0).P
    rc = recalibration(holdout_check(ps, max_samples=200, seed=0), f)
    assert band_calibration(rc.apply(raw, seed=1), P_true).coverage >= 0.85
    bumped = recalibration(holdout_check(_bumped(ps, 7, 0.05), max_samples=200, seed=0), f)
    near = (f > 16) & (f < 24)
    assert np.all(bumped.add[near].sum(1) > 10 * rc.add[near].sum(1) + 1e-30)


def test_check_refuses_what_it_cannot_check(samples):
    frf, nls, ps = samples
    post = make_log_posterior(frf, nls.scale, f_max_hz=None, reference=nls, model_error=White())
    pw = posterior_laplace_samples(post, 20, nls, key=0)
    with pytest.raises(ValueError, match="'white' model error does not condition"):
        holdout_check(pw)
    with pytest.raises(ValueError, match="level must be in"):
        holdout_check(ps, level=1.0)


def test_predict_prints_the_verdict(samples, tmp_path, capsys):
    _, _, ps = samples
    s = save_samples(tmp_path / "s.npz", _bumped(ps, 7, 0.05))
    args = ["predict", "--samples", str(s), "--n-freq", "5", "--max-samples", "50"]
    assert main([*args, "--out", str(tmp_path / "d.npz")]) == 0
    cap = capsys.readouterr()
    lines = cap.out.splitlines()
    assert lines[1].startswith("check of the band as drawn: left out in turn, the measured P "
                               "at ") and " 20, " in lines[1]  # fmt: skip
    assert "Measuring more frequencies there (e.g. " in lines[1]
    assert lines[2].startswith("recalibrated on those left-out errors")
    assert "10 measured frequencies left out in turn" in cap.err  # progress: 12 fit frequencies
    assert "drawing up to 50 draws of P on 5 frequencies" in cap.err
    assert main([*args, "--no-recalibrate", "--out", str(tmp_path / "r.npz")]) == 0
    line = capsys.readouterr().out.splitlines()[1]
    assert line.startswith("check: band NOT ESTABLISHED at ") and " 20, " in line
    assert main([*args, "--no-check", "--out", str(tmp_path / "e.npz")]) == 0
    assert capsys.readouterr().out.splitlines()[1].startswith("check: not run (--no-check)")


def test_suggestions_sit_on_the_measured_grid():
    from hapid.uncertainty._holdout import HoldoutCheck, _grid_step

    assert _grid_step([0.5, 1.25, 3.0]) == 0.25 and _grid_step([1.0, 2.0, 15.0]) == 1.0
    assert _grid_step([1.0, np.pi]) == 0.0  # no grid coarser than 1 mHz
    f = np.array([0.5, 0.75, 1.0, 2.0, 3.0])  # a 0.25 Hz grid; 2 Hz missed
    split = np.ones((3, 2))  # the direction split: not read by the verdict
    c = HoldoutCheck(f[1:-1], np.array([1.0, 1.0, 1.0]), np.array([0.5, 0.5, 2.0]), f, 0.9,
                     split, split)  # fmt: skip
    assert c.not_established_hz == [(1.0, 3.0)]
    # geometric midpoints 1.414 and 2.449 rounded to the 0.25 Hz grid
    assert c.suggested_hz == [1.5, 2.5]
    assert list(c.covers([1.0, 1.5, 2.9, 3.0])) == [True, False, False, True]
    g = np.array([19.0, 20.0, 21.0, 22.0])  # 21 Hz missed, its neighbours adjacent on 1 Hz
    c = HoldoutCheck(g[1:-1], np.array([1.0, 1.0]), np.array([0.5, 2.0]), g, 0.9, split[:2],
                     split[:2])  # fmt: skip
    assert c.suggested_hz == [] and "on a finer frequency grid" in c.message()


def test_predict_stores_where_the_band_is_established_and_draws_it(samples, tmp_path, capsys):
    """The draws file's ``established (N,)`` of the band as drawn (``--no-recalibrate``) is
    the check's own verdict on the grid (False in the interval around the 5 % feature at 20
    Hz, True far from it), ``--plot`` writes the figure, and a bad figure name fails before
    anything is written."""
    _, _, ps = samples
    bumped = _bumped(ps, 7, 0.05)
    s = save_samples(tmp_path / "s.npz", bumped)
    out, fig = tmp_path / "d.npz", tmp_path / "band.png"
    args = ["predict", "--samples", str(s), "--n-freq", "40", "--max-samples", "50",
            "--no-recalibrate"]  # fmt: skip
    assert main([*args, "--out", str(out), "--plot", str(fig)]) == 0
    assert "figure → " in capsys.readouterr().out
    with np.load(out) as z:
        f, est = z["freq_hz"], z["established"]
    assert est.dtype == bool and est.shape == f.shape
    check = holdout_check(bumped, max_samples=50, seed=0)
    assert np.array_equal(est, check.covers(f))
    assert not est[(f > 16) & (f < 24)].any() and est[f < 5].all()
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # beyond the measured frequencies (40 Hz) nothing was judged: not established
    assert main([*args, "--f-max-hz", "60", "--out", str(out)]) == 0
    with np.load(out) as z:
        f, est = z["freq_hz"], z["established"]
    assert not est[f > 40.0 + 1e-9].any() and est[f < 5].all()
    bad_out = tmp_path / "e.npz"
    assert main([*args, "--out", str(bad_out), "--plot", str(tmp_path / "band.txt")]) == 2
    assert "--plot" in capsys.readouterr().err and not bad_out.exists()


def test_predict_says_why_the_check_did_not_run_on_two_frequencies(samples, tmp_path, capsys):
    """Fit data of two frequencies leave nothing to leave out: predict writes its draws and
    says why there is no check, instead of failing."""
    _, _, ps = samples
    d = ps.predictive
    keep = slice(3, 5)
    per_freq = ("omega", "Z_H", "Z_T", "var_H", "var_T", "a_H", "a_M")
    two = dataclasses.replace(ps, predictive={**d, **{k: np.asarray(d[k])[keep] for k in per_freq}})
    s = save_samples(tmp_path / "s.npz", two)
    out = tmp_path / "d.npz"
    assert main(["predict", "--samples", str(s), "--n-freq", "4", "--max-samples", "20",
                 "--out", str(out)]) == 0  # fmt: skip
    text = capsys.readouterr().out
    assert "check: not run (needs at least 3 measured frequencies, got 2)" in text
    with np.load(out) as z:
        assert "established" not in z.files and z["P"].shape == (20, 4, 2, 2)


def test_established_on_an_uncalibrated_model_size_follows_the_record(samples, tmp_path,
                                                                       monkeypatch, capsys):  # fmt: skip
    """Where the measured record says the band of a model this size is not calibrated (here
    the record's rod count lowered to this 2-rod model), the file's ``established`` is False
    at and above ``UNCALIBRATED_FROM_HZ`` whatever the check says, the check's own verdict
    below it; the warning says so and the figure hatches that range."""
    from hapid import _cli_predict

    _, _, ps = samples
    s = save_samples(tmp_path / "s.npz", ps)  # unbumped: the check establishes everything
    args = [
        "predict",
        "--samples",
        str(s),
        "--n-freq",
        "40",
        "--max-samples",
        "50",
        "--no-recalibrate",
    ]  # fmt: skip  (the record is of the band as drawn)
    monkeypatch.setattr(_cli_predict, "RODS_UNCALIBRATED", 2)
    out = tmp_path / "d.npz"
    assert main([*args, "--out", str(out), "--plot", str(tmp_path / "b.png")]) == 0
    lines = capsys.readouterr().out.splitlines()
    warned = [ln for ln in lines if ln.startswith("WARNING")]
    assert len(warned) == 1 and "'established' is False at and above 16 Hz" in warned[0]
    assert lines[1].startswith("check: band established") and "16 Hz regardless" in lines[1]
    with np.load(out) as z:
        f, est = z["freq_hz"], z["established"]
    check = holdout_check(ps, max_samples=50, seed=0)
    assert check.covers(f)[f >= _cli_predict.UNCALIBRATED_FROM_HZ].all()  # the check: yes
    assert not est[f >= _cli_predict.UNCALIBRATED_FROM_HZ].any()  # the record: no
    low = f < _cli_predict.UNCALIBRATED_FROM_HZ
    assert low.any() and np.array_equal(est[low], check.covers(f)[low])
    monkeypatch.setattr(_cli_predict, "RODS_UNCALIBRATED", 3)  # 2 rods: calibrated again
    assert main([*args, "--out", str(out)]) == 0
    with np.load(out) as z:
        assert np.array_equal(z["established"], check.covers(z["freq_hz"]))
    assert list(_cli_predict.record_established("loop_gp", 9, [1.0, 30.0])) == [True, True]
    assert list(_cli_predict.record_established("params", 9, [1.0, 30.0], True)) == [True, True]


def test_predict_writes_the_recalibrated_band(samples, tmp_path, monkeypatch, capsys):
    """By default predict's P is :func:`recalibration` of the check applied to the band as
    drawn (``--no-recalibrate``), wider where the check found a local feature; its
    ``established`` is the measured range (the record of the band as drawn does not apply:
    no 6-rod warning even with the record's rod count lowered to this model)."""
    from hapid import _cli_predict
    from hapid.uncertainty import plant_draws

    _, _, ps = samples
    bumped = _bumped(ps, 7, 0.05)
    s = save_samples(tmp_path / "s.npz", bumped)
    args = [
        "predict",
        "--samples",
        str(s),
        "--n-freq",
        "30",
        "--max-samples",
        "80",
        "--f-max-hz",
        "60",
    ]  # fmt: skip  (beyond the measured 40 Hz: not established)
    monkeypatch.setattr(_cli_predict, "RODS_UNCALIBRATED", 2)
    assert main([*args, "--out", str(tmp_path / "r.npz"), "--no-recalibrate"]) == 0
    assert main([*args, "--out", str(tmp_path / "c.npz"), "--plot", str(tmp_path / "b.png")]) == 0
    assert (tmp_path / "b.png").read_bytes()[:4] == b"\x89PNG"
    text = capsys.readouterr().out
    assert "recalibrated on those left-out errors" in text and "recalibrated) on 30" in text
    assert sum(ln.startswith("WARNING") for ln in text.splitlines()) == 1  # as drawn only
    with np.load(tmp_path / "r.npz") as r, np.load(tmp_path / "c.npz") as c:
        f, raw, P, est = r["freq_hz"], r["P"], c["P"], c["established"]
        assert np.array_equal(c["Z_H"], r["Z_H"])  # the model's draws, unchanged
    ref = plant_draws(bumped, 2 * np.pi * f, draws="params", max_samples=80, seed=0).P
    assert np.array_equal(raw, ref)
    check = holdout_check(bumped, max_samples=80, seed=0)
    assert np.allclose(P, recalibration(check, f).apply(raw, seed=0))
    assert np.array_equal(est, check.within(f)) and est[f <= 40].all() and not est[f > 40].any()
    near = (f > 16) & (f < 24)
    r_raw = np.quantile(np.linalg.norm(raw - np.median(raw, 0), axis=(-2, -1)), 0.9, axis=0)
    r_new = np.quantile(np.linalg.norm(P - np.median(P, 0), axis=(-2, -1)), 0.9, axis=0)
    assert np.all(r_new[near] > 1.5 * r_raw[near])


def test_predict_refuses_non_finite_draws(samples, tmp_path, monkeypatch, capsys):
    """A draw of P that is not finite (a singular Z_T) is refused with a clear error and no
    file, instead of a band whose median is NaN."""
    import hapid.uncertainty as U

    _, _, ps = samples
    s = save_samples(tmp_path / "s.npz", ps)
    real = U.plant_draws

    def with_nan(*args, **kw):
        d = real(*args, **kw)
        P = d.P.copy()
        P[3, 2] = np.nan
        return dataclasses.replace(d, P=P)

    monkeypatch.setattr(U, "plant_draws", with_nan)
    out = tmp_path / "d.npz"
    assert main(["predict", "--samples", str(s), "--n-freq", "5", "--max-samples", "20",
                 "--out", str(out)]) == 2  # fmt: skip
    assert "1 of 20 draws (P, Z_H, Z_T) are not finite" in capsys.readouterr().err
    assert not out.exists()
