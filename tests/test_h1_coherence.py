"""Coherence of the haptic pair's H1 estimate (``estimate_frf_h1`` → ``FRF.coherence_H/_T``):
equal to an independent scipy computation, ~1 for noise-free linear data, low exactly where
output noise was added, kept by ``select``/``band`` and the FRF files, and named by ``hapid frf
--h1`` in a warning."""

from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.signal as ss
from helpers import second_order_device
from helpers_cli import run_cli

from hapid import io as hio
from hapid.experiment import Run, estimate_frf_h1, time_domain_response
from hapid.frf import as_frf

FS = 1000.0
T = 2**13
NPERSEG = 256
NOISE_BAND = (100.0, 200.0)  # Hz: band-limited noise added to the hand forces R_I
CLEAN = (250.0, 400.0)  # Hz: well away from the noise band and from Nyquist


@pytest.fixture(scope="module")
def records():
    """A 2-rod device driven by white noise (3 experiments); ``R_I_noisy`` adds band-limited
    noise of the signal's own RMS to the hand forces in ``NOISE_BAND``."""
    dev = second_order_device(2, seed=1)
    rng = np.random.default_rng(0)
    R_A = rng.normal(size=(3, T, 2))
    L, R_I = time_domain_response(dev, R_A)
    sos = ss.butter(4, NOISE_BAND, btype="bandpass", fs=FS, output="sos")
    noise = ss.sosfiltfilt(sos, rng.normal(size=R_I.shape), axis=1)
    return R_A, R_I, L, R_I + noise * (np.std(R_I) / np.std(noise))


def scipy_multiple_coherence(x, y, freq_hz):
    """γ²_i = (S_yx S_xx⁻¹ S_xy)_ii / S_yy,ii from scipy.signal.csd (Hann, 50 % overlap, no
    detrend), cross-spectra averaged over experiments; ``x, y`` ``(E, T, n)``."""
    n = x.shape[-1]

    def G(a, b):  # G[f, i, j] = E[A_i B_j*] = csd(b_j, a_i) (scipy: conj(first) · second)
        out = 0
        for e in range(a.shape[0]):
            cols = []
            for i in range(n):
                row = []
                for j in range(n):
                    f, s = ss.csd(b[e, :, j], a[e, :, i], fs=FS, window="hann",
                                  nperseg=NPERSEG, noverlap=NPERSEG // 2, detrend=False)  # fmt: skip
                    row.append(s)
                cols.append(row)
            out = out + np.moveaxis(np.asarray(cols), -1, 0)
        return f, out

    f, Sxx = G(x, x)
    _, Syx = G(y, x)
    _, Syy = G(y, y)
    k = np.argmin(np.abs(f[None, :] - np.asarray(freq_hz)[:, None]), axis=1)
    assert np.allclose(f[k], freq_hz, rtol=1e-12)
    Sxx, Syx, Syy = Sxx[k], Syx[k], Syy[k]
    num = np.einsum("fij,fji->fi", Syx @ np.linalg.inv(Sxx), Syx.conj().transpose(0, 2, 1))
    return num.real / np.einsum("fii->fi", Syy).real


def test_coherence_equals_scipy_cross_spectra(records):
    R_A, R_I, L, R_I_noisy = records
    frf = estimate_frf_h1(FS, R_A, R_I_noisy, L, nperseg=NPERSEG, f_band_hz=(1.0, 490.0))
    f = np.asarray(frf.freq_hz)
    ref_H = scipy_multiple_coherence(L, R_I_noisy, f)
    ref_T = scipy_multiple_coherence(L, R_A, f)
    assert np.shape(frf.coherence_H) == np.shape(frf.coherence_T) == (f.size, 2)
    np.testing.assert_allclose(frf.coherence_H, ref_H, rtol=0, atol=1e-10)
    np.testing.assert_allclose(frf.coherence_T, ref_T, rtol=0, atol=1e-10)


def test_single_channel_coherence_equals_scipy_coherence():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(1, 4096, 1))
    b, a = ss.butter(2, 0.2)
    y = ss.lfilter(b, a, x, axis=1) + 0.3 * rng.normal(size=x.shape)
    frf = estimate_frf_h1(FS, y, y, x, nperseg=NPERSEG)
    f_ref, c_ref = ss.coherence(x[0, :, 0], y[0, :, 0], fs=FS, window="hann", nperseg=NPERSEG,
                                noverlap=NPERSEG // 2, detrend=False)  # fmt: skip
    k = np.argmin(np.abs(f_ref[None, :] - np.asarray(frf.freq_hz)[:, None]), axis=1)
    np.testing.assert_allclose(np.asarray(frf.coherence_H)[:, 0], c_ref[k], atol=1e-10)
    assert float(np.max(frf.coherence_H)) < 0.99  # the noise shows everywhere


def test_coherence_is_one_without_noise_and_drops_in_the_noisy_band(records):
    R_A, R_I, L, R_I_noisy = records
    clean = estimate_frf_h1(FS, R_A, R_I, L, nperseg=NPERSEG)
    noisy = estimate_frf_h1(FS, R_A, R_I_noisy, L, nperseg=NPERSEG)
    f = np.asarray(clean.freq_hz)
    away = (f >= CLEAN[0]) & (f <= CLEAN[1])
    inside = (f >= 120.0) & (f <= 180.0)
    for g in (clean.coherence_H, clean.coherence_T, noisy.coherence_T):
        assert np.min(np.asarray(g)[away]) > 0.99
    gH = np.asarray(noisy.coherence_H)
    assert np.max(gH[inside]) < 0.5
    assert np.min(gH[away]) > 0.99
    assert np.min(np.asarray(clean.coherence_H)[inside]) > 0.99
    # the noise is on R_I only: Z_T's coherence (R_A on L) does not change at all
    np.testing.assert_array_equal(noisy.coherence_T, clean.coherence_T)


def test_no_coherence_from_too_few_segments_or_with_the_command_as_reference(records):
    R_A, R_I, L, _ = records
    # 2 experiments × 1 segment for n = 2 rods: γ² ≡ 1, so none is stored
    one = estimate_frf_h1(FS, R_A[:2, :NPERSEG], R_I[:2, :NPERSEG], L[:2, :NPERSEG],
                          nperseg=NPERSEG)  # fmt: skip
    assert one.coherence_H is None and one.coherence_T is None
    iv = estimate_frf_h1(FS, R_A, R_I, L, nperseg=NPERSEG, reference="R_A")
    assert iv.coherence_H is None and iv.coherence_T is None


@pytest.mark.parametrize("ext", ["npz", "mat", "csv"])
def test_coherence_survives_select_band_and_files(records, tmp_path, ext):
    R_A, _, L, R_I_noisy = records
    frf = estimate_frf_h1(FS, R_A, R_I_noisy, L, nperseg=NPERSEG)
    f = np.asarray(frf.freq_hz)
    sub = frf.band(100.0, 300.0)
    m = (f >= 100.0) & (f <= 300.0)
    np.testing.assert_array_equal(sub.coherence_H, np.asarray(frf.coherence_H)[m])
    np.testing.assert_array_equal(sub.coherence_T, np.asarray(frf.coherence_T)[m])
    back = hio.load_frf(hio.save_frf(tmp_path / f"frf.{ext}", frf))
    np.testing.assert_allclose(back.coherence_H, frf.coherence_H, rtol=1e-15, atol=0)
    np.testing.assert_allclose(back.coherence_T, frf.coherence_T, rtol=1e-15, atol=0)
    one = frf.select(np.arange(f.size) == 7)  # N = 1 round trip (shape (1, n))
    back1 = hio.load_frf(hio.save_frf(tmp_path / f"one.{ext}", one))
    np.testing.assert_allclose(back1.coherence_H, one.coherence_H, rtol=1e-15, atol=0)


def test_frf_rejects_bad_coherence(records):
    R_A, R_I, L, _ = records
    frf = estimate_frf_h1(FS, R_A, R_I, L, nperseg=NPERSEG, f_band_hz=(10.0, 20.0))
    args = (frf.freq_hz, frf.Z_H, frf.Z_T)
    N = np.shape(frf.Z_H)[0]
    with pytest.raises(ValueError, match=r"coherence_H has shape"):
        as_frf(*args, coherence_H=np.ones((N, 3)))
    with pytest.raises(ValueError, match=r"coherence_T must lie in \[0, 1\]"):
        as_frf(*args, coherence_T=np.full((N, 2), 1.5))


def test_cli_h1_warns_naming_the_noisy_band_and_plots(records, tmp_path):
    R_A, _, L, R_I_noisy = records
    hio.save_run(tmp_path / "run.npz", Run(fs_hz=FS, period_samples=T,
                                           freq_hz=np.array([8 * FS / T]), R_A=R_A,
                                           R_I=R_I_noisy, L=L))  # fmt: skip
    rc, out, err, warns, new = run_cli(
        ["frf", "run.npz", "--h1", "--nperseg", NPERSEG, "--f-min-hz", 50, "--f-max-hz", 400,
         "--out", "frf.npz", "--plot", "frf.png"], tmp_path)  # fmt: skip
    assert rc == 0, err
    assert {"frf.npz", "frf.png"} <= new
    msgs = [str(w.message) for w in warns if "low coherence" in str(w.message)]
    assert len(msgs) == 1 and msgs[0].startswith("Z_H:"), msgs  # only Z_H has noise
    lo, hi = (float(x) for x in re.search(r"widest bands ([\d.]+)–([\d.]+) Hz", msgs[0]).groups())
    assert 60.0 <= lo <= 120.0 and 180.0 <= hi <= 240.0, msgs[0]
    assert "coherence γ² of Z_H" in out and "coherence γ² of Z_T" in out
    saved = hio.load_frf(tmp_path / "frf.npz")
    assert saved.coherence_H is not None and saved.coherence_T is not None
