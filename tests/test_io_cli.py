"""File contracts, readers/writers and the command line."""

import subprocess
import sys

import numpy as np
import pytest

import hapid
from hapid import io
from hapid.cli import main
from hapid.device import tripod3
from hapid.experiment import Protocol, estimate_frf, periodic_run


@pytest.fixture(scope="module")
def run():
    return periodic_run(tripod3(), Protocol(n_periods=2))


@pytest.mark.parametrize("ext", ["npz", "csv", "mat"])
def test_run_and_frf_round_trip(tmp_path, run, ext):
    io.save_run(tmp_path / f"r.{ext}", run)
    r2 = io.load_run(tmp_path / f"r.{ext}")
    for k in ("R_A", "R_I", "L"):
        np.testing.assert_array_equal(getattr(r2, k), getattr(run, k))
    assert r2.fs_hz == run.fs_hz and r2.period_samples == run.period_samples
    frf = estimate_frf(run)
    io.save_frf(tmp_path / f"f.{ext}", frf)
    f2 = io.load_frf(tmp_path / f"f.{ext}")
    np.testing.assert_array_equal(np.asarray(f2.Z_T), np.asarray(frf.Z_T))
    np.testing.assert_array_equal(np.asarray(f2.Z_H_std), np.asarray(frf.Z_H_std))


def test_model_round_trip(tmp_path):
    m = tripod3().rigid_model()
    io.save_model(tmp_path / "m.npz", m, method="wls", cost=1.5)
    m2 = io.load_model(tmp_path / "m.npz")
    np.testing.assert_array_equal(np.asarray(m2.total.M), np.asarray(m.total.M))
    assert str(io.load_model_metadata(tmp_path / "m.npz")["method"]) == "wls"


def test_bad_files_are_clear_errors(tmp_path):
    np.savez(tmp_path / "x.npz", Z_H=np.ones((3, 2, 2)), freq_hz=np.arange(1.0, 4.0))
    with pytest.raises(io.FileFormatError, match="missing arrays.*Z_T"):
        io.load_frf(tmp_path / "x.npz")
    np.savez(
        tmp_path / "y.npz",
        freq_hz=np.array([1.0, 1.0, 2.0]),
        Z_H=np.ones((3, 2, 2)),
        Z_T=np.ones((3, 2, 2)),
    )
    with pytest.raises(io.FileFormatError, match="strictly increasing"):
        io.load_frf(tmp_path / "y.npz")
    with pytest.raises(io.FileFormatError, match="unknown file type"):
        io.load_frf(tmp_path / "y.txt")
    bad = hapid.ImpedanceModel(hapid.SecondOrder(np.eye(2) * np.nan, np.eye(2), np.eye(2)),
                               hapid.SecondOrder(np.eye(2), np.eye(2), np.eye(2)))  # fmt: skip
    with pytest.raises(ValueError, match="NaN"):
        io.save_model(tmp_path / "bad.npz", bad)
    assert not (tmp_path / "bad.npz").exists()


def test_cli_simulate_then_frf_write_contract_files(tmp_path, capsys):
    assert (
        main(
            [
                "simulate",
                "--device",
                "tripod3",
                "--periods",
                "2",
                "--out",
                str(tmp_path / "run.npz"),
            ]
        )
        == 0
    )
    with np.load(tmp_path / "run.npz") as z:
        assert z["fs_hz"].dtype == np.float64 and z["fs_hz"].shape == ()
        assert z["period_samples"].dtype == np.int64
        assert z["R_A"].shape == (3, 2000, 3) and z["L"].dtype == np.float64
        assert np.allclose(z["freq_hz"] * z["period_samples"] / z["fs_hz"] % 1, 0)
    assert main(["frf", str(tmp_path / "run.npz"), "--out", str(tmp_path / "frf.npz")]) == 0
    with np.load(tmp_path / "frf.npz") as z:
        assert z["Z_H"].dtype == np.complex128 and z["Z_H"].shape == (28, 3, 3)
        assert z["Z_T_std"].dtype == np.float64 and np.all(np.diff(z["freq_hz"]) > 0)


def test_cli_errors_are_one_line_and_write_nothing(tmp_path, capsys):
    out = tmp_path / "run.npz"
    assert main(["simulate", "--freqs", "1,2.5", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hapid: error: --freqs") and err.count("\n") == 1
    assert "frequencies off the FFT grid" in err
    assert not out.exists()
    # a run with NaN: frf refuses and writes no FRF file
    r = periodic_run(tripod3(), Protocol(n_periods=2))
    np.savez(tmp_path / "nan.npz", fs_hz=1000.0, period_samples=1000, freq_hz=r.freq_hz,
             R_A=r.R_A, R_I=np.where(r.R_I > 0.2, np.nan, r.R_I), L=r.L)  # fmt: skip
    assert main(["frf", str(tmp_path / "nan.npz"), "--out", str(tmp_path / "f.npz")]) == 2
    assert "R_I contains NaN" in capsys.readouterr().err
    assert not (tmp_path / "f.npz").exists()


def test_console_script_help():
    res = subprocess.run(
        [sys.executable, "-m", "hapid.cli", "--help"], capture_output=True, text=True
    )
    assert res.returncode == 0 and "simulate" in res.stdout and "example" in res.stdout
