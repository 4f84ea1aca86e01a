"""Lab data (issue 15): a single measured impedance, non-periodic records, fit quality.

References: numpy formulas for the quality figures, a known M, B, K (noise-free recovery and
recovery inside the Laplace uncertainty), a frequency-domain-exact simulation for the H1
route, and a real measured 2 × 2 dataset (tests/data/mimo-frf, BSD-2, see its LICENSE).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from hapid import io
from hapid.cli import main
from hapid.fit import fit_quality
from hapid.impedance import SecondOrder
from hapid.impedance_frf import as_impedance_frf

DATA = Path(__file__).parent / "data" / "mimo-frf"


def _spd(rng, n, lo, hi):
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (Q * np.geomspace(lo, hi, n)) @ Q.T


def _truth(n=2, seed=0) -> SecondOrder:
    rng = np.random.default_rng(seed)
    return SecondOrder(_spd(rng, n, 0.5, 2.0), _spd(rng, n, 5.0, 20.0), _spd(rng, n, 2e3, 8e3))


def _rel(a, b):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(np.asarray(b)))


# ---- fit quality ------------------------------------------------------------------------------
def test_quality_figures_match_numpy_and_warn():
    rng = np.random.default_rng(1)
    N, n = 40, 3
    w = 2 * np.pi * np.linspace(1, 40, N)
    Z = rng.standard_normal((N, n, n)) + 1j * rng.standard_normal((N, n, n))
    Z = Z + np.swapaxes(Z, -1, -2)  # symmetric data
    good = Z * (1 + 0.01 * rng.standard_normal((N, 1, 1)))
    bad = Z * 0.3  # 70 % error everywhere: −3.1 dB
    q = fit_quality(w, {"Z": Z}, {"Z": good})
    ref = 20 * np.log10(np.linalg.norm(good - Z, axis=(1, 2)) / np.linalg.norm(Z, axis=(1, 2)))
    np.testing.assert_allclose(q.rel_err_db[0], ref, rtol=1e-12)
    assert q.median_db[0] == pytest.approx(np.median(ref)) and q.max_db[0] == pytest.approx(
        ref.max()
    )
    assert q.ok and q.asymmetry[0] < 1e-12 and np.isnan(q.inside_fraction[0])
    qb = fit_quality(w, {"Z": Z}, {"Z": bad}, before=q)
    assert qb.median_db[0] == pytest.approx(20 * np.log10(0.7))
    text = " | ".join(qb.warnings)
    assert "does not describe Z" in text and "positizing made the fit of Z worse" in text
    A = rng.standard_normal((N, n, n))
    skew = Z + (A - np.swapaxes(A, -1, -2))
    qa = fit_quality(w, {"Z": skew}, {"Z": skew})
    St = np.swapaxes(skew, -1, -2)
    a_ref = np.linalg.norm(skew - St, axis=(1, 2)) / np.linalg.norm(skew + St, axis=(1, 2))
    assert qa.asymmetry[0] == pytest.approx(np.median(a_ref)) and qa.asymmetry[0] > 0.2
    assert any("far from symmetric" in m for m in qa.warnings)
    arr = q.with_line("cramer_rao", "Cramér–Rao: x").to_arrays()
    assert str(arr["quality_line_cramer_rao"]) == "Cramér–Rao: x"


def test_inside_fraction_is_the_confidence_level_for_the_true_model():
    rng = np.random.default_rng(2)
    N, n = 800, 2
    w = 2 * np.pi * np.geomspace(1, 100, N)
    Z = np.asarray(_truth(n).at_omega(w))
    std = 0.05 * np.abs(Z) + 1.0
    noisy = Z + std * (rng.standard_normal(Z.shape) + 1j * rng.standard_normal(Z.shape)) / np.sqrt(
        2
    )
    q = fit_quality(w, {"Z": noisy}, {"Z": Z}, {"Z": std}, level=0.9)
    assert abs(q.inside_fraction[0] - 0.9) < 4 * np.sqrt(0.9 * 0.1 / N)
    q_off = fit_quality(w, {"Z": noisy}, {"Z": 1.2 * Z}, {"Z": std}, level=0.9)
    assert q_off.inside_fraction[0] < 0.1


# ---- single impedance: known M, B, K ----------------------------------------------------------
def test_cli_fit_recovers_known_MBK_noise_free(tmp_path, capsys):
    truth = _truth(2, seed=3)
    f = np.geomspace(0.5, 60, 50)
    io.save_impedance_frf(tmp_path / "z.npz", as_impedance_frf(f, truth.at_omega(2 * np.pi * f)))
    for method in ("wls", "nls"):
        out = tmp_path / f"{method}.npz"
        assert main(["fit", str(tmp_path / "z.npz"), "--method", method, "--out", str(out)]) == 0
        m = io.load_impedance_model(out)
        for a, b in ((m.M, truth.M), (m.B, truth.B), (m.K, truth.K)):
            assert _rel(a, b) < 1e-6
        meta = io.load_model_metadata(out)
        assert float(meta["quality_median_db"][0]) < -120
        np.testing.assert_allclose(meta["quality_freq_hz"], f)
    text = capsys.readouterr().out
    assert (
        "single impedance Z (N/m)" in text and "kg" in text and "band: 0.5–60 Hz, 50 of 50" in text
    )


def test_cli_fit_with_noise_is_inside_the_laplace_uncertainty(tmp_path):
    truth = _truth(2, seed=4)
    f = np.geomspace(0.5, 60, 120)
    Z = np.asarray(truth.at_omega(2 * np.pi * f))
    rng = np.random.default_rng(5)
    std = 0.02 * np.linalg.norm(Z, axis=(1, 2))[:, None, None] * np.ones(Z.shape)
    noisy = Z + std * (rng.standard_normal(Z.shape) + 1j * rng.standard_normal(Z.shape)) / np.sqrt(
        2
    )
    io.save_impedance_frf(tmp_path / "z.npz", as_impedance_frf(f, noisy, std))
    out = tmp_path / "m.npz"
    args = [
        "fit",
        str(tmp_path / "z.npz"),
        "--method",
        "nls",
        "--weight",
        "noise",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    m, meta = io.load_impedance_model(out), io.load_model_metadata(out)
    z = []
    for k, t in zip("MBK", (truth.M, truth.B, truth.K), strict=True):
        sd = meta[f"{k}_std"]
        assert np.all(sd > 0) and np.all(sd < 0.05 * np.abs(np.asarray(t)).max())
        z.append(((np.asarray(getattr(m, k)) - np.asarray(t)) / sd)[np.triu_indices(2)])
    z = np.concatenate(z)
    assert np.all(np.abs(z) < 4.5), z  # each entry within 4.5 σ
    assert 0.05 < np.sqrt(np.mean(z**2)) < 2.5  # and σ is not wildly over- or under-stated
    assert 0.8 < float(meta["quality_inside_fraction"][0]) <= 1.0


# ---- H1 from records --------------------------------------------------------------------------
def _records(truth, fs, T, E, noise, seed, kind="acceleration"):
    """Forces (white, independent per channel) and the exact periodic response in the
    frequency domain (the record is one period), plus response noise."""
    rng = np.random.default_rng(seed)
    n = truth.n
    F = rng.standard_normal((E, T, n))
    w = 2 * np.pi * np.fft.rfftfreq(T, 1 / fs)
    Zw = np.array(truth.at_omega(w))
    Zw[0] = np.asarray(truth.K)
    X = np.einsum("kij,ekj->eki", np.linalg.inv(Zw), np.fft.rfft(F, axis=1))
    k = {"displacement": 0, "velocity": 1, "acceleration": 2}[kind]
    Y = np.fft.irfft(X * (1j * w)[None, :, None] ** k, n=T, axis=1)
    return F, Y + noise * np.std(Y) * rng.standard_normal(Y.shape)


def test_cli_frf_h1_acceleration_records_give_the_impedance_within_its_std(tmp_path, capsys):
    truth = _truth(2, seed=6)
    F, Y = _records(truth, fs=200.0, T=2**14, E=2, noise=0.02, seed=7)
    np.savez(tmp_path / "ts.npz", fs_hz=200.0, force=F, response=Y)
    z_path = tmp_path / "z.npz"
    args = ["frf", str(tmp_path / "ts.npz"), "--h1", "--nperseg", "512", "--response",
            "acceleration", "--f-min-hz", "2", "--f-max-hz", "60", "--out", str(z_path)]  # fmt: skip
    assert main(args) == 0
    z = io.load_impedance_frf(z_path)
    f = np.asarray(z.freq_hz)
    assert f.min() >= 2 and f.max() <= 60 and z.unit == "N/m"
    Zt = np.asarray(truth.at_omega(z.omega))
    err = np.abs(np.asarray(z.Z) - Zt)
    assert (
        np.median(
            np.linalg.norm(np.asarray(z.Z) - Zt, axis=(1, 2)) / np.linalg.norm(Zt, axis=(1, 2))
        )
        < 0.03
    )
    ratio = err / np.asarray(z.Z_std)
    assert np.mean(ratio < 3) > 0.9 and 0.2 < np.median(ratio) < 2.0
    assert "Z = (jω)²·F/a" in capsys.readouterr().out


# ---- bad input: one line, exit 2, no file -----------------------------------------------------
def _bad_cases(tmp_path):
    f = np.linspace(1, 10, 8)
    Z = np.ones((8, 2, 2)) * (1 + 1j)
    np.savez(tmp_path / "nnN.npz", freq_hz=f, Z=np.moveaxis(Z, 0, -1))
    np.savez(
        tmp_path / "nnN_pair.npz", freq_hz=f, Z_H=np.moveaxis(Z, 0, -1), Z_T=np.moveaxis(Z, 0, -1)
    )
    (tmp_path / "wrong.csv").write_text("a,b,c\n1,2,3\n")
    np.savez(
        tmp_path / "ts_T.npz", fs_hz=100.0, force=np.ones((2, 500)), response=np.ones((2, 500))
    )
    np.savez(tmp_path / "ts_keys.npz", fs_hz=100.0, u=np.ones((500, 2)), y=np.ones((500, 2)))
    np.savez(tmp_path / "ts_nofs.npz", force=np.ones((500, 2)), response=np.ones((500, 2)))
    io.save_impedance_frf(tmp_path / "z.npz", as_impedance_frf(f, Z + np.eye(2)))
    return {
        "(n, n, N) layout": (["fit", "nnN.npz"], "looks like (n, n, N)"),
        "(n, n, N) pair": (["fit", "nnN_pair.npz"], "looks like (n, n, N)"),
        "csv layout": (["frf", "wrong.csv", "--h1"], "expected a time-series CSV"),
        "csv fit layout": (["fit", "wrong.csv"], "CSV header freq_hz,Z_re_0_0"),
        "(n, T) records": (["frf", "ts_T.npz"], "looks like (n, T)"),
        "missing keys": (["frf", "ts_keys.npz", "--force-key", "force"], "--force-key"),
        "no fs": (["frf", "ts_nofs.npz"], "--fs-hz"),
        "empty band": (["fit", "z.npz", "--f-min-hz", "20"], "only 0 of the file's 8"),
        "weight": (["fit", "z.npz", "--weight", "paper"], "a single impedance takes relative or noise"),
        "nperseg": (["frf", "ts_keys.npz", "--force-key", "u", "--response-key", "y", "--nperseg", "4096"], "longer than the records"),
    }  # fmt: skip


def test_each_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name, (argv, needle) in _bad_cases(tmp_path).items():
        out = tmp_path / f"out_{name.replace(' ', '_').replace(',', '')}.npz"
        assert main([*argv, "--out", str(out)]) == 2, name
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("hapid: error:"), (name, err)
        assert needle in err[0], (name, err[0])
        assert not out.exists(), name


def _write_v73(path, arrays: dict):
    """A MAT-file as MATLAB -v7.3 writes it: HDF5 with a 512-byte text userblock, arrays
    column-major (reversed axes), complex as a real/imag compound."""
    h5py = pytest.importorskip("h5py")
    with h5py.File(path, "w", userblock_size=512) as h:
        for k, v in arrays.items():
            v = np.asarray(v)
            if np.iscomplexobj(v):
                c = np.empty(v.shape, dtype=[("real", "f8"), ("imag", "f8")])
                c["real"], c["imag"] = v.real, v.imag
                v = c
            h.create_dataset(k, data=v.T).attrs["MATLAB_class"] = np.bytes_("double")
    with open(path, "r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(116, b" "))


def test_matlab_v73_is_read_through_h5py_or_named_as_the_hdf5_extra(tmp_path, capsys, monkeypatch):
    f = np.linspace(1, 20, 12)
    truth = _truth(2, seed=8)
    Z = np.asarray(truth.at_omega(2 * np.pi * f))
    _write_v73(tmp_path / "z73.mat", {"freq_hz": f[None, :], "Z": Z})
    z = io.load_impedance_frf(tmp_path / "z73.mat")
    np.testing.assert_allclose(np.asarray(z.Z), Z, rtol=1e-15)
    monkeypatch.setitem(sys.modules, "h5py", None)  # as if the optional extra were missing
    out = tmp_path / "m.npz"
    assert main(["fit", str(tmp_path / "z73.mat"), "--method", "wls", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hapid[hdf5]" in err[0] and not out.exists()


def test_timeseries_csv_round_trip_matches_npz(tmp_path):
    truth = _truth(2, seed=9)
    F, Y = _records(truth, fs=100.0, T=1024, E=2, noise=0.0, seed=1, kind="displacement")
    rows = ["# fs_hz=100.0", "experiment,force_0,force_1,response_0,response_1"]
    rows += [",".join([str(e)] + [repr(float(v)) for v in (*F[e, t], *Y[e, t])])
             for e in range(2) for t in range(1024)]  # fmt: skip
    (tmp_path / "ts.csv").write_text("\n".join(rows) + "\n")
    ts = io.load_timeseries(tmp_path / "ts.csv")
    assert ts.fs_hz == 100.0 and ts.force.shape == (2, 1024, 2)
    np.testing.assert_array_equal(ts.response, Y)


# ---- a real measured dataset ------------------------------------------------------------------
def test_real_mimo_excerpt_frf_fit_report_end_to_end(tmp_path, capsys):
    """tests/data/mimo-frf: a real 2 × 2 chirp test (accelerometer outputs) — frf → fit →
    report for WLS, WLS + positize and NLS; the structure has several modes in 8–50 Hz, so a
    single M, B, K does not describe it and every fit must say so."""
    z_path = tmp_path / "z.npz"
    args = ["frf", str(DATA / "mimo_excerpt.npz"), "--h1", "--nperseg", "128", "--response",
            "acceleration", "--f-min-hz", "8", "--f-max-hz", "50", "--out", str(z_path)]  # fmt: skip
    assert main(args) == 0
    z = io.load_impedance_frf(z_path)
    assert z.n == 2 and z.unit == "V/(V·s²)" and np.all(np.asarray(z.Z_std) > 0)
    medians = {}
    for method in (["wls"], ["wls", "--positize"], ["nls"]):
        out = tmp_path / f"{'_'.join(method)}.npz"
        assert main(["fit", str(z_path), "--method", *method, "--out", str(out)]) == 0
        meta = io.load_model_metadata(out)
        medians["+".join(method)] = float(meta["quality_median_db"][0])
        assert any("does not describe Z" in str(w) for w in meta["quality_warnings"])
        np.testing.assert_allclose(meta["quality_freq_hz"], np.asarray(z.freq_hz))
    text = capsys.readouterr().out
    assert text.count("data-fit relative error of Z: median") == 3
    assert text.count("band: 8.78906–49.8047 Hz, 43 of 43 frequencies") == 3
    assert all(-6 < v < 3 for v in medians.values()), medians


def test_cli_frf_then_fit_recovers_known_MBK_noise_free_from_periodic_records(tmp_path):
    """The whole CLI route on records: periodic multisine forces (period = nperseg, every bin
    excited, independent channels), the exact displacement, boxcar segments → Z exact →
    NLS M, B, K to 1e-6."""
    truth = _truth(2, seed=10)
    rng = np.random.default_rng(11)
    fs, Tp, reps, n = 256.0, 256, 6, 2
    Fk = np.exp(2j * np.pi * rng.random((2, Tp // 2 + 1, n)))  # (E, bins, n), unit amplitude
    Fk[:, 0] = 0.0
    w = 2 * np.pi * np.fft.rfftfreq(Tp, 1 / fs)
    Zw = np.array(truth.at_omega(w))
    Zw[0] = np.eye(n)
    Xk = np.einsum("kij,ekj->eki", np.linalg.inv(Zw), Fk)
    F = np.tile(np.fft.irfft(Fk, n=Tp, axis=1), (1, reps, 1))
    X = np.tile(np.fft.irfft(Xk, n=Tp, axis=1), (1, reps, 1))
    np.savez(tmp_path / "ts.npz", fs_hz=fs, force=F, response=X)
    z, m = tmp_path / "z.npz", tmp_path / "m.npz"
    assert main(["frf", str(tmp_path / "ts.npz"), "--nperseg", str(Tp), "--window", "boxcar",
                 "--f-max-hz", "100", "--out", str(z)]) == 0  # fmt: skip
    assert main(["fit", str(z), "--method", "nls", "--out", str(m)]) == 0
    model = io.load_impedance_model(m)
    for a, b in ((model.M, truth.M), (model.B, truth.B), (model.K, truth.K)):
        assert _rel(a, b) < 1e-6
