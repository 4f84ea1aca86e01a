"""The only matplotlib import. Functions take results and return ``(fig, axes)``."""

from __future__ import annotations

import io as _io
from pathlib import Path

import matplotlib

matplotlib.use("Agg", force=False)
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D

from ._constants import COHERENCE_LOW  # noqa: E402
from .defaults import PPHAT_BAND_HZ  # noqa: E402


def _sv(A):
    return np.linalg.svd(np.asarray(A), compute_uv=False)


def singular_values(
    curves: dict,
    *,
    title: str = "",
    ylabel: str = "singular values (dB)",
    db: bool = True,
    ax=None,
    styles: dict | None = None,
):
    """Plot singular values of matrix frequency responses.

    curves: ``{label: (freq_hz (N,), A (N, n, n))}``; each gets one colour, all its
    singular values drawn (solid unless ``styles[label]`` gives a linestyle).
    """
    if ax is None:
        fig, ax = plt.subplots(figsize=(6.4, 4.2))
    else:
        fig = ax.figure
    styles = styles or {}
    for i, (label, (f, A)) in enumerate(curves.items()):
        sv = _sv(A)
        y = 20 * np.log10(sv) if db else sv
        color = f"C{i}"
        for k in range(sv.shape[1]):
            ax.semilogx(f, y[:, k], styles.get(label, "-"), color=color, lw=1.4,
                        label=label if k == 0 else None, marker="." if len(f) < 60 else None)  # fmt: skip
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return fig, ax


def frf_overview(frf, *, title_prefix: str = ""):
    """Three panels: σ(Z_H), σ(Z_T) and σ(P) of an empirical FRF (dB); when the FRF holds
    coherences (an H1 estimate), a second row shows γ² of every output channel of Z_H and Z_T
    with the low-coherence level dashed."""
    coh = {"Z_H": getattr(frf, "coherence_H", None), "Z_T": getattr(frf, "coherence_T", None)}
    rows = 2 if any(g is not None for g in coh.values()) else 1
    fig, axes = plt.subplots(rows, 3, figsize=(15, 4.2 + 2.6 * (rows - 1)), squeeze=False)
    f = np.asarray(frf.freq_hz)
    top = axes[0]
    singular_values({"Z_H": (f, frf.Z_H)}, ax=top[0], title=f"{title_prefix}σ(Z_H)",
                    ylabel="singular values (dB re 1 N/m)")  # fmt: skip
    singular_values({"Z_T": (f, frf.Z_T)}, ax=top[1], title=f"{title_prefix}σ(Z_T)",
                    ylabel="singular values (dB re 1 N/m)")  # fmt: skip
    singular_values({"P": (f, frf.P)}, ax=top[2], title=f"{title_prefix}σ(P = Z_H Z_T⁻¹)",
                    ylabel="singular values (dB)")  # fmt: skip
    if rows == 2:
        for ax, (name, g) in zip(axes[1, :2], coh.items(), strict=True):
            if g is None:
                ax.set_axis_off()
                continue
            _coherence_panel(ax, f, g, f"{title_prefix}coherence of the rows of {name} (H1)",
                             COHERENCE_LOW, "row")  # fmt: skip
        axes[1, 2].set_axis_off()
    fig.tight_layout()
    return fig, axes if rows == 2 else axes[0]


def _coherence_panel(ax, f, g, title: str, level: float, label: str) -> None:
    """γ² ``(N, n)`` against ``f`` (Hz) on ``ax``: one curve per channel (``label i``), the
    low-coherence ``level`` dashed, the axis 0–1.05."""
    g = np.asarray(g)
    for i in range(g.shape[1]):
        ax.semilogx(f, g[:, i], "-", lw=1.0, label=f"{label} {i}")
    ax.axhline(level, color="k", ls="--", lw=0.8)
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("coherence γ²")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)


ISO = 1 - 1 / np.sqrt(2)


def _sv_colors(n: int):
    """One colour per singular value / locus index (σ_1 largest … σ_n smallest)."""
    return [plt.get_cmap("viridis")(x) for x in np.linspace(0.0, 0.85, n)]


def sigma_T_minus_I(
    reports: dict, *, title: str = "", f_max_hz: float = 100.0, y_min: float = 1e-4
):
    """σ(T(jω) − I) per loop (the paper's Figs. 5 and 10), one panel per loop, on a log
    magnitude axis so the isotropic-bandwidth threshold 1 − 1/√2 (dashed) is not squashed
    against a large resonance; each σ_k labelled, the bandwidth marked (dotted)."""
    k = len(reports)
    fig, axes = plt.subplots(1, k, figsize=(5.6 * k, 4.4), squeeze=False, sharey=True)
    lows = []
    for ax, (label, rep) in zip(axes[0], reports.items(), strict=True):
        f = np.asarray(rep.freq_hz)
        m = (f >= 0.1) & (f <= f_max_hz)
        sv = np.asarray(rep.sv_T_minus_I)
        lows.append(np.min(sv[m]))
        n = sv.shape[1]
        for i, c in enumerate(_sv_colors(n)):
            name = "σ̄ (largest)" if i == 0 else ("σ̲ (smallest)" if i == n - 1 else f"σ_{i + 1}")
            ax.loglog(f[m], np.maximum(sv[m, i], y_min), lw=1.3, color=c, label=name)
        ax.axhline(ISO, color="k", ls="--", lw=1, label="threshold 1 − 1/√2 ≈ 0.293")
        bw = float(rep.iso_bandwidth_hz)
        stable = bool(rep.stable)
        if stable and np.isfinite(bw):
            ax.axvline(bw, color="C3", ls=":", lw=1.4, label=f"iso-bandwidth {bw:.2f} Hz")
        ax.set_title(label if stable else f"{label} — UNSTABLE (no bandwidth)", fontsize=9)
        ax.set_xlabel("frequency (Hz)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    axes[0][0].set_ylim(bottom=max(y_min, 0.3 * float(np.nanmin(lows))))
    axes[0][0].set_ylabel("σ_k(T(jω) − I)  (magnitude, log axis)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig, axes


def _sv_std(Z, Z_std):
    """First-order std of each singular value of ``Z`` ``(N, n, n)`` from independent,
    circular complex element noise of std ``Z_std`` (``E|δZ_ij|² = s_ij²``):
    ``δσ_k = Re(u_kᴴ δZ v_k)``, so ``var σ_k = ½ Σ_ij |u_ik|² |v_jk|² s_ij²``."""
    U, sv, Vh = np.linalg.svd(np.asarray(Z))
    w = np.abs(U) ** 2  # (N, i, k)
    v = np.abs(Vh) ** 2  # (N, k, j)
    var = 0.5 * np.einsum("nik,nkj,nij->nk", w, v, np.asarray(Z_std) ** 2)
    return sv, np.sqrt(var)


def impedance_fit(f, Z, f_model, models: dict, *, title: str = "", name: str = "Z", Z_std=None):
    """Singular values of a measured impedance (black, markers; ±1 std error bars from the
    FRF's element std ``Z_std``, first order) and of its models (dashed, dotted) in dB re
    1 N/m — the paper's Figs. 6 and 7."""
    fig, ax = plt.subplots(figsize=(7.0, 4.6))
    if Z_std is not None:
        sv, sd = _sv_std(Z, Z_std)
    else:
        sv, sd = _sv(Z), None
    note = ""
    if sd is not None and not np.any(sd > 0):  # e.g. Z_T from noiseless commands and encoders
        note, sd = " (its std is 0: no noise source enters this estimate)", None
    elif sd is not None:  # say how big the bars are: at low noise they hide behind the markers
        note = f" (±1 std bars, median {np.median(20 * np.log10(1 + sd / sv)):.2g} dB)"
    for k in range(sv.shape[1]):
        y = 20 * np.log10(sv[:, k])
        lab = f"measured {name}{note}" if k == 0 else None
        if sd is None:
            ax.semilogx(f, y, "-", marker=".", color="k", lw=1.2, label=lab)
        else:
            lo = 20 * np.log10(np.maximum(sv[:, k] - sd[:, k], 1e-3 * sv[:, k]))
            hi = 20 * np.log10(sv[:, k] + sd[:, k])
            ax.errorbar(f, y, yerr=[y - lo, hi - y], fmt="-", marker=".", color="k", lw=1.2,
                        elinewidth=1.0, capsize=2, label=lab)  # fmt: skip
            ax.set_xscale("log")
    for i, (label, Zm) in enumerate(models.items()):
        svm = _sv(Zm)
        for k in range(svm.shape[1]):
            ax.semilogx(f_model, 20 * np.log10(svm[:, k]), ("--", ":")[i % 2], color=f"C{i}",
                        lw=1.4, label=label if k == 0 else None)  # fmt: skip
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel(f"singular values of {name} (dB re 1 N/m)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig, ax


def impedance_h1(f, Z, coherence=None, *, title: str = "", unit: str = "N/m"):
    """An H1 impedance estimate: singular values of ``Z`` ``(N, n, n)`` in dB re 1 ``unit``
    and, below, the coherence γ² ``(N, n)`` of every response channel (``None``: not shown)."""
    rows = 1 if coherence is None else 2
    fig, axes = plt.subplots(rows, 1, figsize=(7.0, 2.6 + 2.0 * rows), sharex=True, squeeze=False)
    ax = axes[0, 0]
    sv = _sv(Z)
    for k in range(sv.shape[1]):
        ax.semilogx(f, 20 * np.log10(np.maximum(sv[:, k], 1e-300)), "-", color=f"C{k}", lw=1.0)
    ax.set_ylabel(f"σ(Z) (dB re 1 {unit})")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    if coherence is not None:
        cx = axes[1, 0]
        for i in range(np.shape(coherence)[1]):
            cx.semilogx(f, np.asarray(coherence)[:, i], "-", lw=1.0, label=f"response {i}")
        cx.set_ylim(0, 1.05)
        cx.set_ylabel("coherence γ²")
        cx.grid(True, which="both", alpha=0.3)
        cx.legend(fontsize=8)
    axes[-1, 0].set_xlabel("frequency (Hz)")
    fig.tight_layout()
    return fig, axes


def coherence(f, gamma2: dict, *, title: str = "", level: float = COHERENCE_LOW):
    """The coherence γ² of an H1 estimate: one panel per entry of ``gamma2``
    (``{label: (N, n)}``, one curve per response channel) against frequency ``f`` (Hz), the
    low-coherence ``level`` dashed."""
    fig, axes = plt.subplots(1, len(gamma2), figsize=(6.0 * len(gamma2), 3.4), squeeze=False)
    for ax, (name, g) in zip(axes[0], gamma2.items(), strict=True):
        _coherence_panel(ax, f, g, f"{title}{name}", level, "channel")
    fig.tight_layout()
    return fig, axes[0]


def pphat(
    f, curves: dict, *, title: str = "", band_db: float = 7.0, f_band_hz: float = PPHAT_BAND_HZ
):
    """Singular values of P·P̂⁻¹ (ideally 0 dB) with the paper's ±7 dB band to 30 Hz shaded
    — the paper's Fig. 8."""
    k = len(curves)
    fig, axes = plt.subplots(1, k, figsize=(6.2 * k, 4.2), squeeze=False, sharey=True)
    for ax, (label, A) in zip(axes[0], curves.items(), strict=True):
        sv = 20 * np.log10(_sv(A))
        ax.semilogx(f, sv, marker=".", lw=1.2)
        ax.fill_between([f.min(), f_band_hz], -band_db, band_db, color="0.85", zorder=0,
                        label=f"paper: ±{band_db:g} dB to {f_band_hz:g} Hz")  # fmt: skip
        ax.axhline(0, color="k", lw=0.8)
        m = f <= f_band_hz
        ax.set_title(
            f"{label}: {sv[m].min():+.1f} / {sv[m].max():+.1f} dB to {f_band_hz:g} Hz", fontsize=9
        )
        ax.set_xlabel("frequency (Hz)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    axes[0][0].set_ylabel("singular values of P·P̂⁻¹ (dB)")
    fig.suptitle(title)
    fig.tight_layout()
    return fig, axes


def predictive_band(f, P, *, measured=None, check=None, uncalibrated=(), raw=None,
                    level: float = 0.9, title: str = ""):  # fmt: skip
    """The ``level`` band of plant draws ``P (S, N, n, n)`` on ``f (N,)`` Hz (``hapid predict
    --plot``): left, each singular value's central band over the draws (shaded) and median
    (line), the measured ``P`` as dots (``measured = (f_m (K,) Hz, P_m (K, n, n))``); right,
    the leave-one-frequency-out check (``check``, a
    :class:`~hapid.uncertainty.HoldoutCheck`): at each left-out measured frequency the
    measured ``P``'s distance from the band's centre over the band's radius, above 1 =
    outside. The intervals the check leaves not established are shaded red in both, the
    intervals ``uncalibrated`` (``[(lo, hi)]`` Hz: where the measured record says the band is
    not calibrated) hatched grey. With ``raw`` (draws ``(S', N, n, n)`` before
    :func:`~hapid.uncertainty.recalibration`) its band's edges are drawn as thin dashed lines
    and the check's intervals are not shaded (the recalibrated band carries those errors)."""
    f = np.asarray(f)
    lo_q, hi_q = (1 - level) / 2, 1 - (1 - level) / 2
    lo, med, hi = _sv_db(P, (lo_q, 0.5, hi_q))
    k = 2 if check is not None else 1
    fig, axes = plt.subplots(1, k, figsize=(6.4 * k, 4.4), squeeze=False)
    ax = axes[0][0]
    S, n = np.shape(P)[0], np.shape(P)[-1]
    for i, c in enumerate(_sv_colors(n)):
        ax.fill_between(f, lo[:, i], hi[:, i], color=c, alpha=0.3, lw=0)
        ax.semilogx(f, med[:, i], color=c, lw=1.0, label=f"σ_{i + 1}(P)" if n <= 6 else None)
    if raw is not None:
        for edge in _sv_db(raw, (lo_q, hi_q)):
            for i, c in enumerate(_sv_colors(n)):
                ax.semilogx(f, edge[:, i], color=c, lw=0.6, ls="--")
        ax.plot([], [], color="0.4", lw=0.6, ls="--", label="band as drawn")
    if measured is not None:
        fm, Pm = (np.asarray(x) for x in measured)
        keep = (fm >= f.min()) & (fm <= f.max())
        svm = 20 * np.log10(np.linalg.svd(Pm[keep], compute_uv=False))
        ax.semilogx(fm[keep], svm, "k.", ms=4)
        ax.plot([], [], "k.", label="measured P")
    ax.set_ylabel(f"singular values of P (dB), {100 * level:.0f} % band")
    ax.set_title(f"{S} draws of P", fontsize=9)
    if check is not None:
        bx = axes[0][1]
        ratio = np.asarray(check.error) / np.maximum(np.asarray(check.radius), 1e-300)
        held = np.asarray(check.held)
        bx.semilogx(check.freq_hz[held], ratio[held], "o", color="C0", ms=5, label="inside")
        bx.semilogx(check.freq_hz[~held], ratio[~held], "x", color="C3", ms=7, mew=2,
                    label="outside")  # fmt: skip
        bx.axhline(1.0, color="k", lw=0.9, ls="--", label="band edge")
        bx.set_yscale("log")
        bx.set_xlim(ax.get_xlim())
        bx.set_ylabel("left-out measured P: error ÷ band radius")
        bx.set_title(
            f"check of the band as drawn: {check.status}"
            + ("; the errors it recalibrates on" if raw is not None else ""),
            fontsize=9,
        )
    for a in axes[0]:
        shaded = check.not_established_hz if check is not None and raw is None else []
        for i, (a_hz, b_hz) in enumerate(shaded):
            a.axvspan(a_hz, b_hz, color="C3", alpha=0.12, lw=0,
                      label="not established" if i == 0 else None)  # fmt: skip
        for i, (a_hz, b_hz) in enumerate(uncalibrated):
            a.axvspan(a_hz, b_hz, facecolor="none", edgecolor="0.65", hatch="//", lw=0,
                      label="not calibrated (measured record)" if i == 0 else None)  # fmt: skip
        a.set_xlabel("frequency (Hz)")
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig, axes


def _sv_db(P, qs):
    """The quantiles ``qs`` over the draws of the singular values of ``P (S, N, n, n)``, in
    dB: one ``(N, n)`` array per level."""
    sv = np.linalg.svd(np.asarray(P), compute_uv=False)  # (S, N, n)
    return [20 * np.log10(np.quantile(sv, q, axis=0)) for q in qs]


def loci(reports: dict, *, title: str = "", f_range=(0.1, 500.0)):
    """Characteristic loci (eigenvalues λ_i of P G, tracked over frequency): Nyquist plane
    (top; solid ω > 0, dotted its mirror image ω < 0) and Bode magnitude and phase (bottom) per
    loop — the paper's Fig. 9. The phase is unwrapped only strictly below the Nyquist
    frequency (the grid's last point), where the discrete loci turn real and their angle jumps."""
    k = len(reports)
    fig, axes = plt.subplots(3, k, figsize=(6.2 * k, 11), squeeze=False,
                             gridspec_kw={"height_ratios": [2.2, 1, 1]})  # fmt: skip
    for j, (label, rep) in enumerate(reports.items()):
        f = np.asarray(rep.freq_hz)
        m = (f >= f_range[0]) & (f <= f_range[1])
        lam = np.asarray(rep.loci)[m]
        n = lam.shape[1]
        colors = [f"C{i}" for i in range(n)]
        ax = axes[0][j]
        for i in range(n):
            ax.plot(lam[:, i].real, lam[:, i].imag, lw=1.1, color=colors[i], label=f"λ_{i + 1}")
            ax.plot(lam[:, i].real, -lam[:, i].imag, lw=0.6, ls=":", color=colors[i])
        th = np.linspace(0, 2 * np.pi, 200)
        ax.plot(np.cos(th), np.sin(th), color="0.6", lw=0.8, label="unit circle")
        ax.plot([-1], [0], "r+", ms=12, mew=2, label="−1")
        mirror = Line2D([], [], color="0.3", ls=":", lw=0.8, label="dotted: mirror, ω < 0")
        ax.set_xlim(-3, 2)
        ax.set_ylim(-2.5, 2.5)
        ax.set_aspect("equal")
        ax.grid(True, alpha=0.3)
        gm, pm = float(rep.gm_db), float(rep.pm_deg)
        ax.set_title(f"{label}\n{'stable' if bool(rep.stable) else 'UNSTABLE'}, GM {gm:.1f} dB, "
                     f"PM {pm:.1f}°", fontsize=9)  # fmt: skip
        ax.set_xlabel("Re λ_i(PG)")
        ax.set_ylabel("Im λ_i(PG)")
        handles, _ = ax.get_legend_handles_labels()
        ax.legend(handles=handles + [mirror], fontsize=7, loc="lower left", ncol=2)
        for i in range(n):
            axes[1][j].semilogx(f[m], 20 * np.log10(np.abs(lam[:, i])), lw=1.1, color=colors[i],
                                label=f"λ_{i + 1}")  # fmt: skip
        axes[1][j].axhline(0, color="k", lw=0.8)
        axes[1][j].set_ylim(-60, 50)
        axes[1][j].set_ylabel("|λ_i(PG)| (dB)")
        axes[1][j].grid(True, which="both", alpha=0.3)
        axes[1][j].legend(fontsize=7, ncol=n, loc="lower left")
        below = f[m] < (1 - 1e-6) * f.max()  # strictly below Nyquist (the grid's last point)
        ph = np.degrees(np.unwrap(np.angle(lam[below]), axis=0))
        for i in range(n):
            axes[2][j].semilogx(f[m][below], ph[:, i], lw=1.1, color=colors[i])
        axes[2][j].axhline(-180, color="k", lw=0.8)
        axes[2][j].set_ylabel("phase λ_i(PG) (deg, below Nyquist)")
        axes[2][j].set_xlabel("frequency (Hz)")
        axes[2][j].grid(True, which="both", alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig, axes


def sweep(keys, rows, metrics):
    """Sweep results against the first varied option; one line per combination of the others."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    x = rows[:, 0]
    others = rows[:, 1:]
    combos = np.unique(others, axis=0) if others.shape[1] else np.zeros((1, 0))
    for j, c in enumerate(combos):
        m = np.all(others == c, axis=1) if others.shape[1] else np.ones(len(x), bool)
        o = np.argsort(x[m])
        lab = ", ".join(f"{k}={v:g}" for k, v in zip(keys[1:], c, strict=True)) or None
        axes[0].plot(
            x[m][o],
            metrics["iso_bandwidth_hz"][m][o],
            marker="o",
            ms=3,
            color=f"C{j % 10}",
            label=lab,
        )
        axes[1].plot(x[m][o], metrics["pphat_max_db"][m][o], marker="o", ms=3, color=f"C{j % 10}")
        axes[1].plot(
            x[m][o], metrics["pphat_min_db"][m][o], marker="o", ms=3, ls="--", color=f"C{j % 10}"
        )
        axes[2].plot(x[m][o], metrics["disk_margin"][m][o], marker="o", ms=3, color=f"C{j % 10}")
    axes[0].set_ylabel("isotropic bandwidth (Hz; missing = unstable)")
    axes[1].set_ylabel("P·P̂⁻¹ band to 30 Hz (dB): max solid, min dashed")
    axes[2].set_ylabel("disk margin α (σ̄(S − T))")
    for ax in axes:
        ax.set_xlabel(keys[0])
        ax.grid(True, alpha=0.3)
    if len(combos) <= 12 and others.shape[1]:
        axes[0].legend(fontsize=7)
    fig.tight_layout()
    return fig, axes


def robust_histograms(reports: dict, *, title: str = ""):
    """Histograms of the robust check's draws per controller/model (``reports``: ``{label:
    hapid.uncertainty.RobustReport}``): |GM| (dB), |PM| (deg) and the isotropic bandwidth
    (Hz) of the stable draws, the requirements dashed; each label with its P(stable)."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.0))
    panels = (("gm_db", "|GM| (dB)", "gm_req_db"), ("pm_deg", "|PM| (deg)", "pm_req_deg"),
              ("iso_bandwidth_hz", "isotropic bandwidth (Hz)", None))  # fmt: skip
    for ax, (name, xlabel, req) in zip(axes, panels, strict=True):
        for i, (label, rep) in enumerate(reports.items()):
            ok = np.asarray(rep.stable, bool)
            v = np.abs(np.asarray(getattr(rep, name), float))[ok]
            v = v[np.isfinite(v)]
            if v.size:
                ax.hist(v, bins=40, histtype="step", lw=1.4, color=f"C{i}",
                        label=f"{label}: P(stable) {rep.p_stable:.3f}, n = {rep.n}")  # fmt: skip
            if req is not None and i == 0:
                ax.axvline(float(getattr(rep, req)), color="k", ls="--", lw=1,
                           label=f"required ≥ {float(getattr(rep, req)):g}")  # fmt: skip
        ax.set_xlabel(xlabel + " of the stable draws")
        ax.set_ylabel("draws")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig, axes


def to_bytes(fig, fmt: str = "png", dpi: int = 110) -> bytes:
    """The figure as ``fmt`` (``"png"``, ``"pdf"``) bytes; the figure stays open."""
    buf = _io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=dpi, bbox_inches="tight")
    return buf.getvalue()


def close(fig) -> None:
    """Close a figure (free its memory)."""
    plt.close(fig)


def save(fig, path) -> None:
    """Save and close a figure (creates the folder)."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130, bbox_inches="tight")
    plt.close(fig)
