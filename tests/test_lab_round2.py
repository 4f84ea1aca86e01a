"""Lab data, round two: impact (hammer) records, coherence, signs and what ``hapid fit``
prints, and the bad inputs a new user meets (each one line, exit 2, nothing written).

The impact records are synthesized from a known two-mode structure (modes near 900 Hz and
2640 Hz, ζ 1e-3 and 3e-4, fs 25.6 kHz, five hits, noise on both channels) whose FRF is known in
closed form (``hapid.experiment._hammer``); every estimate is checked against that closed form
and against an independent one-segment-per-impact H1 written here with scipy."""

from __future__ import annotations

import io as _io

import numpy as np
import pytest
import scipy.signal as ss
from helpers_cli import assert_clean_error, run_cli, write_valid_files

from hapid import io as hio
from hapid.experiment import TimeSeries, estimate_impedance
from hapid.experiment._hammer import hammer_records, modal_impedance
from hapid.fit import correct_exponential, fit_impedance
from hapid.impedance_frf import as_impedance_frf

SPAN = 38_400  # samples per hit in hammer_records' default (1.5 s at 25.6 kHz)


def _db_err(a, b):
    return np.abs(20 * np.log10(np.abs(a) / np.abs(b)))


def scipy_h1_acc(force, acc, fs, starts, L):
    """Independent H1 of Z = (jω)² F/a: scipy csd/welch with a boxcar window, one segment of
    ``L`` samples per impact (starting at ``starts`` in the 1-D records)."""
    kw = dict(fs=fs, window="boxcar", nperseg=L, noverlap=0, detrend=False)
    Pfa = sum(ss.csd(force[s : s + L], acc[s : s + L], **kw)[1] for s in starts)
    Pff = sum(ss.welch(force[s : s + L], **kw)[1] for s in starts)
    f = np.fft.rfftfreq(L, 1 / fs)
    return f[1:], ((2j * np.pi * f) ** 2 / (Pfa / Pff))[1:]


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    d = tmp_path_factory.mktemp("lab2")
    hio.save_timeseries(d / "hits.npz", hammer_records(separate=True))
    hio.save_timeseries(d / "series.npz", hammer_records())
    return d


@pytest.fixture(scope="module")
def lab_z1(lab):
    """``lab`` with ``z1.npz``: the default ``hapid frf --h1`` of the five-hit record (written
    here, so the fit tests do not depend on which worker ran the frf test)."""
    rc, _, err, _, _ = run_cli(["frf", "series.npz", "--h1", "--response", "acceleration",
                                "--out", "z1.npz"], lab)  # fmt: skip
    assert rc == 0, err
    return lab


def test_default_h1_on_separate_hammer_records_is_one_segment_per_impact(lab):
    rc, out, err, _, _ = run_cli(["frf", "hits.npz", "--h1", "--response", "acceleration",
                                  "--nperseg", "2048", "--out", "z.npz"], lab)  # fmt: skip
    assert rc == 0, err
    assert "one segment per impact: 5 segments of 38400 samples" in out
    z = hio.load_impedance_frf(lab / "z.npz")
    ts = hammer_records(separate=True)
    f_ref, Z_ref = scipy_h1_acc(ts.force[:, :, 0].ravel(), ts.response[:, :, 0].ravel(),
                                ts.fs_hz, [e * SPAN for e in range(5)], SPAN)  # fmt: skip
    f = np.asarray(z.freq_hz)
    np.testing.assert_allclose(f, f_ref, rtol=1e-12)
    m = f >= 100
    Z = np.asarray(z.Z)[:, 0, 0]
    assert np.median(_db_err(Z[m], Z_ref[m])) < 1e-6  # the same estimator, written twice
    assert np.median(_db_err(Z[m], modal_impedance(f[m])[:, 0, 0])) < 1.0
    # coherence stored with the FRF, (N, n) in [0, 1]; low where the response is noise
    g = np.asarray(z.coherence)
    assert g.shape == (f.size, 1) and np.all((g >= 0) & (g <= 1))
    assert np.median(g[(f > 800) & (f < 3000)]) > 0.9


def test_default_h1_splits_one_record_of_five_hits(lab):
    rc, out, err, _, _ = run_cli(["frf", "series.npz", "--h1", "--response", "acceleration",
                                  "--out", "z1s.npz", "--plot", "z1.png"], lab)  # fmt: skip
    assert rc == 0, err
    assert "split before each impact" in out and (lab / "z1.png").stat().st_size > 0
    z = hio.load_impedance_frf(lab / "z1s.npz")
    f = np.asarray(z.freq_hz)
    L = int(round(25_600 / (f[1] - f[0])))
    ts = hammer_records()
    # independent segments: from each known record boundary (5 % before its hit), L samples
    f_ref, Z_ref = scipy_h1_acc(ts.force[0, :, 0], ts.response[0, :, 0], ts.fs_hz,
                                [h * SPAN for h in range(5)], L)  # fmt: skip
    np.testing.assert_allclose(f, f_ref, rtol=1e-9)
    m = f >= 100
    Z = np.asarray(z.Z)[:, 0, 0]
    assert np.median(_db_err(Z[m], Z_ref[m])) < 0.2
    assert np.median(_db_err(Z[m], modal_impedance(f[m])[:, 0, 0])) < 1.0


def test_records_neither_impulsive_nor_stationary_are_refused_naming_the_options(tmp_path):
    rng = np.random.default_rng(1)
    T = 20_000
    F = np.zeros((1, T, 1))
    F[0, 5000:9000, 0] = rng.standard_normal(4000)  # a noise burst: 20 % of the record
    Y = np.cumsum(F, axis=1) * 1e-3 + 1e-6 * rng.standard_normal((1, T, 1))
    hio.save_timeseries(tmp_path / "burst.npz", TimeSeries(fs_hz=1000.0, force=F, response=Y))
    line = assert_clean_error(["frf", "burst.npz", "--out", "zb.npz"], tmp_path)
    assert "--estimate impact" in line and "--estimate welch" in line and "burst.npz" in line
    rc, _, err, _, _ = run_cli(["frf", "burst.npz", "--estimate", "welch", "--nperseg", "1024",
                                "--out", "zb.npz"], tmp_path)  # fmt: skip
    assert rc == 0, err


def test_undecayed_impacts_are_refused_and_the_exponential_window_is_corrected(tmp_path):
    mode = ((900.0, 1e-3, 0.5),)
    ts = hammer_records(modes=mode, hit_spacing_s=0.1, response_noise=1e-4, force_noise=1e-4,
                        separate=True)  # fmt: skip
    hio.save_timeseries(tmp_path / "short.npz", ts)
    line = assert_clean_error(["frf", "short.npz", "--response", "acceleration", "--out", "z.npz"],
                              tmp_path)  # fmt: skip
    assert "--exp-tau" in line and "--estimate impact" in line
    tau = 0.02
    est = estimate_impedance(ts, response="acceleration", exp_tau_s=tau)
    assert est.method == "impact" and est.frf.exp_tau_s == tau
    fit = fit_impedance(est.frf, method="wls", f_min_hz=800, f_max_hz=1000)
    wn = 2 * np.pi * 900.0
    zeta = lambda m: float(m.B[0, 0] / (2 * np.sqrt(m.K[0, 0] * m.M[0, 0])))  # noqa: E731
    # the windowed data are Z(jω + 1/τ): their ζ is raised by 1/(τ ω_n) = 8.8e-3 ≫ 1e-3
    windowed = as_impedance_frf(est.frf.freq_hz, est.frf.Z, est.frf.Z_std)  # exp_tau_s unset
    raw = fit_impedance(windowed, method="wls", f_min_hz=800, f_max_hz=1000)
    assert fit.exp_tau_s == tau and "exp_window" in dict(fit.quality.lines)
    M, B, K, *_ = correct_exponential(raw.model.M, raw.model.B, raw.model.K, tau)
    np.testing.assert_allclose(np.asarray(fit.model.B), B, rtol=1e-12)
    assert abs(zeta(fit.model) - 1e-3) < 1.5e-4
    assert abs(zeta(raw.model) - (1e-3 + 1 / (tau * wn))) < 1.5e-4


def test_sign_checks_name_sign_minus_on_data_of_the_opposite_convention(lab_z1):
    lab = lab_z1
    rc, _, err, _, _ = run_cli(["frf", "series.npz", "--response", "acceleration", "--sign", "-",
                                "--out", "zneg.npz"], lab)  # fmt: skip
    assert rc == 0, err
    for method in ("wls", "nls"):
        rc, out, err, _, _ = run_cli(["fit", "zneg.npz", "--method", method, "--f-min-hz", "2600",
                                      "--f-max-hz", "2680", "--out", f"m_{method}.npz"], lab)  # fmt: skip
        assert rc == 0, err
        warns = [ln for ln in out.splitlines() if ln.startswith("warning:")]
        assert any("negative definite" in w and "--sign -" in w for w in warns), out
        assert any("negative damping" in w for w in warns), out
        if method == "nls":
            assert any("collapsed toward 0" in w and "--sign -" in w for w in warns), out
    rc, out, err, _, _ = run_cli(["fit", "z1.npz", "--method", "wls", "--f-min-hz", "2600",
                                  "--f-max-hz", "2680", "--out", "m_pos.npz"], lab)  # fmt: skip
    assert rc == 0 and "--sign -" not in out, out


def test_fit_prints_the_matrices_with_std_as_stored(lab_z1):
    lab = lab_z1
    rc, out, err, _, _ = run_cli(["fit", "z1.npz", "--method", "nls", "--f-min-hz", "860",
                                  "--f-max-hz", "940", "--out", "m1.npz"], lab)  # fmt: skip
    assert rc == 0, err
    d = np.load(lab / "m1.npz")
    line = next(ln for ln in out.splitlines() if ln.startswith("M [kg]:"))
    val, sd = line.split(":", 1)[1].split("±")
    assert float(val) == pytest.approx(float(d["M"][0, 0]), rel=1e-3)
    assert float(sd) == pytest.approx(float(d["M_std"][0, 0]), rel=0.05)
    assert "f_n = " in out and "ζ = " in out
    # the modal figures recover the 900 Hz mode (its neighbour adds a little stiffness)
    fn = float(out.split("f_n = √(K/M)/2π = ")[1].split(" Hz")[0])
    assert abs(fn - 900.0) < 2.0


def test_matrices_report_summarizes_large_n():
    from hapid._cli_lab import matrices_report
    from hapid.impedance import SecondOrder

    A = np.diag([1.0, 2.0, 3.0, 4.0])
    lines = matrices_report(SecondOrder(A, A, A), None, {"M": "kg", "B": "N·s/m", "K": "N/m"})
    assert lines[0].startswith("M [kg]: eigenvalues 1, 2, 3, 4; diagonal")
    assert len(lines) == 4  # M, B, K, and the "no std" line


def test_noise_weights_scale_the_std_by_the_reduced_chi2_when_the_std_are_understated():
    f = np.linspace(5.0, 50.0, 60)
    s = 2j * np.pi * f
    Z0 = (0.2 * s**2 + 3.0 * s + 400.0)[:, None, None]
    sigma = 2.0
    rng = np.random.default_rng(3)
    noise = (
        sigma / np.sqrt(2) * (rng.standard_normal(Z0.shape) + 1j * rng.standard_normal(Z0.shape))
    )
    honest = fit_impedance(as_impedance_frf(f, Z0 + noise, np.full(Z0.shape, sigma)),
                           method="nls", weight="noise")  # fmt: skip
    under = fit_impedance(as_impedance_frf(f, Z0 + noise, np.full(Z0.shape, sigma / 10)),
                          method="nls", weight="noise")  # fmt: skip
    assert 0.5 < honest.reduced_chi2 < 2 and honest.sigma2 == 1.0
    assert under.reduced_chi2 == pytest.approx(100 * honest.reduced_chi2, rel=1e-6)
    # the scaled std are the honest ones (the same fit, weights ×10, variance scale ×100)
    np.testing.assert_allclose(np.asarray(under.model_std.M), np.asarray(honest.model_std.M)
                               * np.sqrt(honest.reduced_chi2), rtol=1e-4)  # fmt: skip
    assert any("reduced χ²" in w and "scaled" in w for w in under.quality.warnings)


def test_one_segment_gives_no_std_and_a_band_edge_keeps_its_bin(tmp_path):
    rng = np.random.default_rng(4)
    F = rng.standard_normal((1, 4096, 1))
    hio.save_timeseries(tmp_path / "one.npz", TimeSeries(fs_hz=1000.0, force=F, response=2e-3 * F))
    rc, out, err, _, _ = run_cli(["frf", "one.npz", "--estimate", "welch", "--window", "boxcar",
                                  "--nperseg", "4096", "--f-max-hz", "900", "--out", "z.npz"],
                                 tmp_path)  # fmt: skip
    assert rc == 0, err
    assert "no std" in out and "above the Nyquist frequency" in out
    assert hio.load_impedance_frf(tmp_path / "z.npz").Z_std is None
    z = as_impedance_frf(np.array([900.0, 920.0000000000001, 940.0]), np.ones((3, 1, 1)))
    assert np.asarray(z.band(920.0, 1000.0).freq_hz).size == 2


def test_coherence_round_trips_through_csv(tmp_path):
    f = np.array([1.0, 2.0, 3.0])
    z = as_impedance_frf(f, np.ones((3, 2, 2)), coherence=np.full((3, 2), 0.5), exp_tau_s=0.1)
    hio.save_impedance_frf(tmp_path / "z.csv", z)
    back = hio.load_impedance_frf(tmp_path / "z.csv")
    np.testing.assert_array_equal(np.asarray(back.coherence), np.asarray(z.coherence))
    assert back.exp_tau_s == 0.1


# ---- bad input: one line, exit 2, nothing written ---------------------------------------------
@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("round2")
    return d, write_valid_files(d)


@pytest.mark.parametrize("argv, needle", [
    (["predict", "--samples", "samples.npz", "--n-freq", "100000000", "--out", "o.npz"], "--n-freq must be an integer in [2, 100000]"),
    (["fit", "frf.npz", "--method", "wls", "--out", "frf.npz"], "does not overwrite its own input"),
    (["analyze", "--model", "model.npz", "--device", "cu5", "--rod-compliance", "1e300"], "--rod-compliance must be in"),
    (["robust", "--samples", "samples.npz", "--model", "model.npz", "--device", "cu5"], "is for n = 3 rods but --device cu5 has n = 5"),
    (["fit", "frf.npz", "--method", "foo", "--out", "m.npz"], "invalid choice: 'foo'"),
    (["simulate", "--device", "cu5", "--delay", "2.5", "--out", "r.npz"], "invalid int value"),
    (["simulate", "--device", "cu5", "--move", "0.01", "0", "--out", "r.npz"], "expected 3 arguments"),
    (["nosuch"], "invalid choice: 'nosuch'"),
])  # fmt: skip
def test_bad_choices_and_ranges_are_one_line(files, argv, needle):
    assert_clean_error(argv, files[0], needle)


def test_bad_files_are_named_in_one_line(files, tmp_path):
    d = files[0]
    run = dict(np.load(d / "run.npz"))
    run["L"] = np.zeros_like(run["L"])
    np.savez(tmp_path / "zero_L.npz", **run)
    assert_clean_error(
        ["frf", "zero_L.npz", "--out", "f.npz"], tmp_path, "zero_L.npz: the position record L"
    )
    F = np.zeros((1, 2000, 1))
    Y = np.random.default_rng(0).standard_normal((1, 2000, 1))
    hio.save_timeseries(tmp_path / "zero_F.npz", TimeSeries(fs_hz=1000.0, force=F, response=Y))
    assert_clean_error(
        ["frf", "zero_F.npz", "--out", "z.npz"],
        tmp_path,
        "zero_F.npz: the force of record 0 is zero",
    )
    (tmp_path / "empty.csv").write_text("")
    assert_clean_error(
        ["fit", "empty.csv", "--out", "m.npz"], tmp_path, "empty.csv: the file is empty"
    )
    # an impedance FRF where the haptic pair is expected: the CLI command, not a library call
    z = as_impedance_frf(np.array([1.0, 2.0, 3.0]), np.ones((3, 3, 3)))
    hio.save_impedance_frf(tmp_path / "z.npz", z)
    line = assert_clean_error(
        ["analyze", "--model", str(d / "model.npz"), "--frf", "z.npz"], tmp_path
    )
    assert "hapid fit" in line and "use load_" not in line


def test_csv_never_holds_negative_zero(tmp_path):
    hio.save_csv(tmp_path / "t.csv", ["a", "b", "c", "d"], [[-0.0, "-0", "-0.000", "-1"]])
    assert (tmp_path / "t.csv").read_text().splitlines()[1] == "0.0,0,0.000,-1"


def test_gloo_connection_lines_stay_off_stdout(capsys):
    from hapid._distributed import _relay_stdout

    _relay_stdout(_io.BytesIO(b"[Gloo] Rank 0 is connected to 1 peer ranks.\nresult 1\n"))
    assert capsys.readouterr().out == "result 1\n"
