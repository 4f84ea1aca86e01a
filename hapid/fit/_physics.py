"""Physics checks of a single-impedance fit ``Z ≈ M s² + B s + K`` (a passive structure has
symmetric positive (semi)definite M, B, K and dissipates energy), and what a user reads off it.

- :func:`data_passivity`: the share of frequencies where the measured ``Z`` dissipates energy
  with the sign it was given: ``(Z − Zᴴ)/(2j)`` has a positive trace (a passive ``Z = F/x``
  has ``Im Z ≥ 0``: the power ``ω Im(Z)|x|²/2`` flows into the structure).
- :func:`physics_warnings`: warnings for a fitted model: negative-definite M or K (the data's
  sign is the opposite convention: ``hapid frf --sign -``), negative damping (an eigenvalue of
  B below zero: the model generates energy), and a PSD fit that collapsed toward zero.
- :func:`chi2_note`: the reduced χ² of a noise-weighted fit and what it means for the std.
- :func:`correct_exponential`: M, B, K of the structure from a fit to records multiplied by
  an exponential window ``e^{−t/τ}`` (the data are ``Z(s + 1/τ)``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: a PSD fit whose median ‖Ẑ‖_F is below this fraction of the data's has collapsed
COLLAPSE_RATIO = 0.1
#: reduced χ² above this: the noise std under-states the misfit; the parameter std are scaled
CHI2_SCALE_ABOVE = 2.0
#: the text naming the fix for data of the opposite sign convention
SIGN_HINT = "the data's sign is likely the opposite of a passive impedance: try hapid frf --sign -"


def _sym_eig(A) -> np.ndarray:
    A = np.asarray(A, dtype=np.float64)
    return np.linalg.eigvalsh(0.5 * (A + A.T))


def data_passivity(Z) -> float:
    """Share of frequencies (``Z`` ``(N, n, n)``) where ``tr((Z − Zᴴ)/(2j)) > 0``."""
    Z = np.asarray(Z)
    herm_im = (Z - np.conj(np.swapaxes(Z, -1, -2))) / 2j
    return float(np.mean(np.trace(herm_im, axis1=-2, axis2=-1).real > 0))


def physics_warnings(model, Z, omega, what: str = "") -> tuple[str, ...]:
    """Warnings (one line each) for ``model`` (``M, B, K``) fitted to ``Z`` ``(N, n, n)`` at
    ``omega`` (rad/s), each prefixed by ``what`` (e.g. ``"the unconstrained WLS fit: "``).
    Empty when M, B, K are positive semidefinite and the fit did not collapse."""
    out = []
    eig = {k: _sym_eig(getattr(model, k)) for k in "MBK"}
    neg_def = [k for k in "MK" if np.all(eig[k] < 0)]
    passive = data_passivity(Z)
    if neg_def:
        out.append(
            f"{' and '.join(neg_def)} {'is' if len(neg_def) == 1 else 'are'} negative definite "
            f"(a passive structure has them positive): {SIGN_HINT}"
        )
    else:
        indef = [k for k in "MK" if np.any(eig[k] < 0)]
        if indef:
            out.append(
                f"{' and '.join(indef)} {'has' if len(indef) == 1 else 'have'} a negative "
                "eigenvalue: no passive second-order structure (a mode inside the band, or "
                "response and force at different points)"
            )
    if np.any(eig["B"] < 0):
        hint = f"; {SIGN_HINT}" if passive < 0.5 else ""
        out.append(
            f"negative damping: B has eigenvalue(s) {', '.join(f'{x:.3g}' for x in eig['B'] if x < 0)} "
            f"< 0 (the model generates energy){hint}"
        )
    s = 1j * np.asarray(omega)[:, None, None]
    Zh = np.asarray(model.M) * s**2 + np.asarray(model.B) * s + np.asarray(model.K)
    fro = lambda A: np.sqrt(np.sum(np.abs(A) ** 2, axis=(-2, -1)))  # noqa: E731
    ratio = float(np.median(fro(Zh)) / max(float(np.median(fro(np.asarray(Z)))), 1e-300))
    if ratio < COLLAPSE_RATIO:
        why = (
            f"the data dissipate energy at only {100 * passive:.0f} % of the frequencies, so "
            f"{SIGN_HINT}"
            if passive < 0.5
            else "no positive M, B, K describes the data in this band (a mode inside it, or a "
            "narrower band needed)"
        )
        out.append(
            f"the positive-semidefinite fit collapsed toward 0 (median ‖Ẑ‖/‖Z‖ = {ratio:.2g}): "
            f"{why}"
        )
    return tuple(what + w for w in out)


def chi2_note(chi2_red: float) -> str:
    """What a reduced χ² of a noise-weighted fit means (empty when near 1)."""
    if not np.isfinite(chi2_red) or 0.5 <= chi2_red <= CHI2_SCALE_ABOVE:
        return ""
    if chi2_red > CHI2_SCALE_ABOVE:
        return (
            f"reduced χ² {chi2_red:.3g}: the misfit is √{chi2_red:.3g} = {np.sqrt(chi2_red):.3g}× "
            "what the FRF's std explain (model error or optimistic std); the std of M, B, K "
            "are scaled by it"
        )
    return (
        f"reduced χ² {chi2_red:.3g}: the misfit is smaller than the FRF's std predict (the std "
        "are pessimistic, e.g. overlapping segments); the std of M, B, K are not scaled down"
    )


class CorrectedMBK(NamedTuple):
    """M, B, K of the structure under an exponential window (:func:`correct_exponential`),
    each ``(n, n)`` float64 in the fit's units (kg, N·s/m, N/m for ``Z`` in N/m); ``M_std``,
    ``B_std``, ``K_std`` their standard deviations (same shapes and units), ``None`` when none
    were given. Unpacks as ``M, B, K, M_std, B_std, K_std``."""

    M: np.ndarray
    B: np.ndarray
    K: np.ndarray
    M_std: np.ndarray | None
    B_std: np.ndarray | None
    K_std: np.ndarray | None


def correct_exponential(M, B, K, tau_s: float, M_std=None, B_std=None, K_std=None) -> CorrectedMBK:
    """Undo the exponential window on a fitted ``M s² + B s + K`` of ``Z(s + a)``, ``a = 1/τ``:
    ``B = B_w − 2aM``, ``K = K_w − aB − a²M`` (exact). Returns :class:`CorrectedMBK`; the std
    are propagated ignoring correlations between M, B, K (``None`` stays ``None``)."""
    a = 1.0 / float(tau_s)
    M, Bw, Kw = (np.asarray(x, dtype=np.float64) for x in (M, B, K))
    B_t = Bw - 2 * a * M
    K_t = Kw - a * B_t - a * a * M
    if M_std is None:
        return CorrectedMBK(M, B_t, K_t, None, None, None)
    ms, bs, ks = (np.asarray(x, dtype=np.float64) for x in (M_std, B_std, K_std))
    bs_t = np.sqrt(bs**2 + (2 * a * ms) ** 2)
    ks_t = np.sqrt(ks**2 + (a * bs_t) ** 2 + (a * a * ms) ** 2)
    return CorrectedMBK(M, B_t, K_t, ms, bs_t, ks_t)


__all__ = [
    "physics_warnings",
    "data_passivity",
    "chi2_note",
    "correct_exponential",
    "CorrectedMBK",
    "SIGN_HINT",
]
