"""Figure helpers of hapid.plot: the singular-value error bars against Monte Carlo, the loci
phase kept below Nyquist, and the σ(T − I) panels' log axis and legends."""

from __future__ import annotations

import types

import numpy as np

from hapid import plot


def test_singular_value_std_matches_monte_carlo():
    rng = np.random.default_rng(1)
    N, n = 3, 4
    Z = rng.normal(size=(N, n, n)) + 1j * rng.normal(size=(N, n, n)) + 3 * np.eye(n)
    s = 0.01 * (1 + rng.random(size=(N, n, n)))  # element std: E|δZ_ij|² = s_ij²
    sv, sd = plot._sv_std(Z, s)
    draws = 8000
    noise = (
        s
        * (rng.normal(size=(draws, N, n, n)) + 1j * rng.normal(size=(draws, N, n, n)))
        / np.sqrt(2)
    )
    mc = np.linalg.svd(Z + noise, compute_uv=False).std(axis=0)
    np.testing.assert_allclose(sv, np.linalg.svd(Z, compute_uv=False))
    np.testing.assert_allclose(sd, mc, rtol=0.05)


def _fake_report(n=3, N=200, fs=1000.0):
    f = np.append(np.geomspace(0.1, 0.49999 * fs, N - 1), 0.5 * fs)
    w = 2 * np.pi * f
    # loci of a loop with a 1-sample delay: the phase passes −180° well before Nyquist
    lam = np.stack(
        [(20 / (1j * w / (2 * np.pi * (k + 1)) + 1)) * np.exp(-1j * w / fs) for k in range(n)], -1
    )
    lam[-1] = lam[-1].real  # the discrete loci are real at Nyquist
    return types.SimpleNamespace(freq_hz=f, loci=lam, gm_db=6.0, pm_deg=40.0, stable=True,
                                 sv_T_minus_I=np.abs(lam) / (1 + np.abs(lam)), iso_bandwidth_hz=3.0)  # fmt: skip


def test_loci_phase_is_drawn_strictly_below_nyquist_and_legends_name_each_locus():
    rep = _fake_report()
    fig, axes = plot.loci({"a": rep})
    phase_lines = axes[2][0].get_lines()
    f_max = max(float(np.max(ln.get_xdata())) for ln in phase_lines)
    assert f_max < 500.0
    labels = [t.get_text() for t in axes[0][0].get_legend().get_texts()]
    assert {"λ_1", "λ_2", "λ_3"} <= set(labels) and any("dotted" in t for t in labels)
    plot.plt.close(fig)


def test_sigma_panels_are_log_scaled_with_a_legend_per_singular_value():
    rep = _fake_report()
    fig, axes = plot.sigma_T_minus_I({"a": rep, "b": rep}, title="t")
    ax = axes[0][0]
    assert ax.get_yscale() == "log"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert sum(lab.startswith("σ") for lab in labels) == 3 and any("threshold" in t for t in labels)
    plot.plt.close(fig)
