"""The only matplotlib import. Functions take results and return ``(fig, axes)``."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg", force=False)
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

TWO_PI = 2 * np.pi


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
    """Three panels: σ(Z_H), σ(Z_T) and σ(P) of an empirical FRF (dB)."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    f = np.asarray(frf.freq_hz)
    singular_values({"Z_H": (f, frf.Z_H)}, ax=axes[0], title=f"{title_prefix}σ(Z_H)",
                    ylabel="singular values (dB re 1 N/m)")  # fmt: skip
    singular_values({"Z_T": (f, frf.Z_T)}, ax=axes[1], title=f"{title_prefix}σ(Z_T)",
                    ylabel="singular values (dB re 1 N/m)")  # fmt: skip
    singular_values({"P": (f, frf.P)}, ax=axes[2], title=f"{title_prefix}σ(P = Z_H Z_T⁻¹)",
                    ylabel="singular values (dB)")  # fmt: skip
    fig.tight_layout()
    return fig, axes


def save(fig, path) -> None:
    """Save and close a figure (creates the folder)."""
    from pathlib import Path

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130, bbox_inches="tight")
    plt.close(fig)
