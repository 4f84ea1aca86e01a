"""The figures of a design report, drawn by :mod:`hapid.plot` from the stages' results.

:func:`figures` returns ``{name: Figure}``: each figure's title, caption and PNG/PDF bytes;
the report writes them to the output folder and embeds the PNGs in the HTML page.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .. import pipeline, plot
from .._constants import TWO_PI
from .._grids import continuous_grid
from ..fit import pphat
from ..impedance_frf import ImpedanceFRF
from ..uncertainty import loop_gp_mean, measured_data, measured_loop_gp

LABELS = {"wls": "WLS + positize", "nls": "NLS (PD)", "ml": "ML"}


@dataclasses.dataclass(frozen=True)
class Figure:
    """One report figure: ``name`` (file stem), ``title``, ``caption``, ``png``/``pdf`` bytes."""

    name: str
    title: str
    caption: str
    png: bytes
    pdf: bytes


def _fig(name, title, caption, fig) -> Figure:
    out = Figure(name, title, caption, plot.to_bytes(fig, "png"), plot.to_bytes(fig, "pdf"))
    plot.close(fig)
    return out


def _models(fits: dict) -> dict:
    return {m: r["model"] for m, r in fits.items() if "error" not in r}


def coherences(frf) -> dict:
    """``{label: γ² (N, n)}`` an H1 FRF holds (``Z`` of a lab impedance, ``Z_H``/``Z_T`` of a
    MIMO H1 estimate); empty for a periodic run's FRF, which has the element std instead."""
    if isinstance(frf, ImpedanceFRF):
        return {} if frf.coherence is None else {"Z": np.asarray(frf.coherence)}
    out = {"Z_H": getattr(frf, "coherence_H", None), "Z_T": getattr(frf, "coherence_T", None)}
    return {k: np.asarray(v) for k, v in out.items() if v is not None}


def _coherence_figure(frf) -> list[Figure]:
    coh = coherences(frf)
    if not coh:
        return []
    fig, _ = plot.coherence(np.asarray(frf.freq_hz), coh, title="coherence γ² of ")
    return [_fig("coherence", "Coherence of the H1 estimate", "Multiple coherence γ² of every "
                 "response channel; below the dashed level noise, leakage or nonlinearity "
                 "spoil the estimate there.", fig)]  # fmt: skip


def _frf_figures(frf, fits: dict) -> list[Figure]:
    f = np.asarray(frf.freq_hz)
    f_dense = np.geomspace(f.min(), f.max(), 400)
    w = TWO_PI * f_dense
    models = _models(fits)
    if isinstance(frf, ImpedanceFRF):
        curves = {LABELS[m]: np.asarray(mod.at_omega(w)) for m, mod in models.items()}
        fig, _ = plot.impedance_fit(f, np.asarray(frf.Z), f_dense, curves, name="Z",
                                    Z_std=frf.Z_std, title=f"measured Z ({frf.unit}) and its fits")  # fmt: skip
        return [_fig("frf_Z", "FRF with ±1 std bars and the fits", "Singular values of the "
                     "measured impedance Z (black, ±1 std) and of each fitted M s² + B s + K.", fig)]  # fmt: skip
    out = []
    for name in ("Z_H", "Z_T"):
        curves = {LABELS[m]: np.asarray(getattr(mod, name)(1j * w)) for m, mod in models.items()}
        std = getattr(frf, f"{name}_std", None)
        fig, _ = plot.impedance_fit(f, np.asarray(getattr(frf, name)), f_dense, curves,
                                    name=name, Z_std=std, title=f"measured {name} and its fits")  # fmt: skip
        out.append(_fig(f"frf_{name}", f"FRF {name} with ±1 std bars and the fits",
                        f"Singular values of the measured {name} (black, ±1 std) and of each "
                        "fitted model.", fig))  # fmt: skip
    if models:
        om = np.asarray(frf.omega)
        curves = {LABELS[m]: np.asarray(pphat(frf.P, mod, om)) for m, mod in models.items()}
        fig, _ = plot.pphat(f, curves, title="σ(P P̂⁻¹): measured plant over each model")
        out.append(_fig("pphat", "σ(P P̂⁻¹)", "Singular values of the measured plant times the "
                        "inverse of each model's plant (0 dB: a perfect model); the paper's "
                        "±7 dB to 30 Hz shaded.", fig))  # fmt: skip
    return out


def loops(frf, nls_model, g_paper, g_tuned) -> dict:
    """``{label: LoopMetrics}`` of the inverse-model controller of the NLS model with the
    paper g and the tuned g (when there is one), continuous time, closed on the measured plant
    interpolated by the loop GP (``Q̄ P̂``, :func:`hapid.uncertainty.loop_gp_mean`) on the
    robust check's dense grid: the measured FRF's few frequencies cannot resolve a Nyquist
    count."""
    gp = measured_loop_gp(measured_data(frf), nls_model)
    omega = continuous_grid()
    P = loop_gp_mean(gp, omega) @ np.asarray(nls_model.P(1j * omega))
    plant = pipeline.Plant(jnp.asarray(omega), jnp.asarray(P), jnp.asarray(0), None)
    out = {}
    for label, g in (("paper g", g_paper), ("tuned g", g_tuned)):
        if g is not None:
            ctrl = pipeline.controller(nls_model, g, ts=None)
            out[label] = pipeline.loop(ctrl, plant, pipeline.SPEC_FIGURES)
    return out


def _loop_figures(reps: dict) -> list[Figure]:
    if not reps:
        return []
    f_top = 200.0
    fig, _ = plot.loci(
        reps, title="characteristic loci of P G (P: the measured plant, GP-interpolated)"
    )
    a = _fig("loci", "Characteristic loci", "Eigenvalues of P G, P the measured plant "
             "interpolated by the loop GP (Q̄ P̂), G = g Ẑ_T Ẑ_H⁻¹ of the NLS model, continuous "
             "time (Nyquist plane, magnitude, phase).", fig)  # fmt: skip
    fig, _ = plot.sigma_T_minus_I(reps, title="σ(T − I) on the measured plant (GP-interpolated)",
                                  f_max_hz=f_top)  # fmt: skip
    b = _fig("sigma_T_minus_I", "σ̄(T − I) with the isotropic bandwidth", "Singular values of "
             "T − I with P the measured plant interpolated by the loop GP; the isotropic "
             "bandwidth is where σ̄ first reaches 1 − 1/√2 (dashed).", fig)  # fmt: skip
    return [a, b]


def _robust_figure(robust: dict) -> list[Figure]:
    reps = {f"paper g, {LABELS[m]}": r["report"] for m, r in robust.items()}
    if not reps:
        return []
    fig, _ = plot.robust_histograms(reps, title="robust check of the paper g: loop draws "
                                    "conditioned on the measured FRF")  # fmt: skip
    return [_fig("robust", "Robust check histograms", "Margins and isotropic bandwidth of the "
                 "stable loop draws Q P̂ (Q = P P̂⁻¹ conditioned on the measured FRF), one "
                 "curve per model; requirements dashed.", fig)]  # fmt: skip


def figures(frf, fits: dict, robust: dict | None, reps: dict) -> list[Figure]:
    """Every figure the stages' results allow: the FRF with its std bars and fits, σ(P P̂⁻¹),
    the characteristic loci and σ(T − I) of ``reps`` (:func:`loops`), the robust histograms."""
    return (
        _frf_figures(frf, fits)
        + _coherence_figure(frf)
        + _loop_figures(reps)
        + _robust_figure(robust or {})
    )
