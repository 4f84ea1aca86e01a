"""A public impact-hammer measurement (tests/data/pyfrf-impact, MIT): five triggered hits at
51.2 kHz on a real structure, force in N and acceleration in m/s². The file has what lab files
have: record 0's force is clipped (three samples at the 2000 N range limit while the other hits
peak at 150–185 N) and record 2 holds a double hit 23 ms after the first.

Checked against an independent one-segment-per-impact H1 written here with scipy (boxcar
window, one whole record per segment) and an independent least squares of one mode."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sl
import scipy.signal as ss
from helpers_cli import run_cli

from hapid import io as hio

DATA = Path(__file__).parent / "data" / "pyfrf-impact" / "impact_series.npz"


def _db_err(a, b):
    return np.abs(20 * np.log10(np.abs(a) / np.abs(b)))


def scipy_h1(records):
    """Z = (jω)² F/a by H1 over whole records (one unwindowed segment each), scipy only."""
    d = np.load(DATA)
    F, A, fs = (
        d["force"][..., 0].astype(float),
        d["response"][..., 0].astype(float),
        float(d["fs_hz"]),
    )
    kw = dict(fs=fs, window="boxcar", nperseg=F.shape[1], noverlap=0, detrend=False)
    Pfa = sum(ss.csd(F[e], A[e], **kw)[1] for e in records)
    Pff = sum(ss.welch(F[e], **kw)[1] for e in records)
    f = np.fft.rfftfreq(F.shape[1], 1 / fs)
    return f[1:], ((2j * np.pi * f) ** 2 / (Pfa / Pff))[1:]


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    d = tmp_path_factory.mktemp("pyfrf")
    for name, sign in (("z.npz", "+"), ("zneg.npz", "-")):
        rc, out, err, _, _ = run_cli(["frf", str(DATA), "--h1", "--response", "acceleration",
                                      "--sign", sign, "--out", name], d)  # fmt: skip
        assert rc == 0, err
    return d, out


def test_default_h1_drops_the_clipped_hit_keeps_the_double_hit_and_equals_scipy(lab):
    d, out = lab
    F = np.abs(np.load(DATA)["force"][..., 0].astype(float))
    # record 0: the samples at its peak, counted here from the data
    assert (
        f"record 0 dropped: its force is clipped ({int(np.sum(F[0] == F[0].max()))} samples" in out
    )
    assert np.sum(F[0] == F[0].max()) >= 3 and np.sum(F[2] == F[2].max()) == 1
    # record 2: the note's delay and share must point at a second pulse in the force itself
    m = re.search(
        r"record 2 has a double hit \(([\d.]+) ms after the first, (\d+) % of its peak\)", out
    )
    assert m, out
    fs = float(np.load(DATA)["fs_hz"])
    first = int(np.argmax(F[2] > 0.1 * F[2].max()))
    second = first + int(round(float(m.group(1)) * 1e-3 * fs))
    pulse = F[2, second : second + int(2e-3 * fs)].max()
    assert pulse > 0.1 * F[2].max()  # a hit starts there …
    assert F[2, first + int(3e-3 * fs) : second - 2].max() < 0.1 * F[2].max()  # … and none before
    assert abs(pulse / F[2].max() - int(m.group(2)) / 100) < 0.01
    assert "4 segments of 51200 samples" in out
    z = hio.load_impedance_frf(d / "z.npz")
    f_ref, Z_ref = scipy_h1([1, 2, 3, 4])
    f, Z = np.asarray(z.freq_hz), np.asarray(z.Z)[:, 0, 0]
    np.testing.assert_allclose(f, f_ref, rtol=1e-12)
    m = f >= 100
    err = np.median(_db_err(Z[m], Z_ref[m]))
    assert err < 1.0  # the bar (100 Hz–Nyquist) …
    assert err < 1e-9  # … and the same estimator written twice
    # keeping the clipped record would have been far off: its force spectrum is the 2000 N spike
    _, Z_all = scipy_h1([0, 1, 2, 3, 4])
    assert np.median(_db_err(Z_all[m], Z_ref[m])) > 10
    g = np.asarray(z.coherence)[:, 0]
    assert np.median(g[(f > 100) & (f < 3000)]) > 0.9  # the hammer tip excites up to ~6 kHz


def _lstsq_mbk(f, Z):
    """Relative-weight least squares of m s² + b s + k to Z over (f, Z), scipy only."""
    s = 2j * np.pi * f
    w = 1 / np.abs(Z)
    A = w[:, None] * np.stack([s**2, s, np.ones_like(s)], -1)
    coef = sl.lstsq(np.vstack([A.real, A.imag]), np.concatenate([(w * Z).real, (w * Z).imag]))[0]
    return coef


def test_one_mode_fit_equals_least_squares_and_the_inverted_mode_names_sign_minus(lab):
    d, _ = lab
    z = hio.load_impedance_frf(d / "z.npz")
    f, Z = np.asarray(z.freq_hz), np.asarray(z.Z)[:, 0, 0]
    rc, out, err, _, _ = run_cli(["fit", "z.npz", "--method", "wls", "--f-min-hz", "850",
                                  "--f-max-hz", "900", "--out", "m1.npz"], d)  # fmt: skip
    assert rc == 0, err
    fit = hio.load_impedance_model(d / "m1.npz")
    band = (f >= 850) & (f <= 900)
    m, b, k = _lstsq_mbk(f[band], Z[band])
    got = [float(np.asarray(a).ravel()[0]) for a in (fit.M, fit.B, fit.K)]
    np.testing.assert_allclose(got, [m, b, k], rtol=1e-8)
    fn = np.sqrt(k / m) / (2 * np.pi)
    assert abs(fn - f[band][np.argmin(np.abs(Z[band]))]) < 3  # the |Z| minimum is the mode
    assert f"f_n = √(K/M)/2π = {fn:.2f} Hz" in out
    # 220–270 Hz: a mode of the opposite sign (a transfer FRF): WLS goes negative definite and
    # NLS collapses; both name --sign -, which gives a positive mode at the |Z| minimum
    for method in ("wls", "nls"):
        rc, out, err, _, _ = run_cli(["fit", "z.npz", "--method", method, "--f-min-hz", "220",
                                      "--f-max-hz", "270", "--out", f"m2{method}.npz"], d)  # fmt: skip
        assert rc == 0 and "try hapid frf --sign -" in out + err, out + err
    rc, out, err, _, _ = run_cli(["fit", "zneg.npz", "--method", "nls", "--f-min-hz", "220",
                                  "--f-max-hz", "270", "--out", "m2neg.npz"], d)  # fmt: skip
    assert rc == 0 and "--sign -" not in out + err, out + err
    neg = hio.load_impedance_model(d / "m2neg.npz")
    mass, stiff = float(np.asarray(neg.M).ravel()[0]), float(np.asarray(neg.K).ravel()[0])
    band = (f >= 220) & (f <= 270)
    assert (
        mass > 0
        and abs(np.sqrt(stiff / mass) / (2 * np.pi) - f[band][np.argmin(np.abs(Z[band]))]) < 3
    )
