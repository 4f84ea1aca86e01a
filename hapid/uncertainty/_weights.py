# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Sizes of the model-error term per frequency and element: the data's RMS element sizes
continued by the reference model outside the fit band (:func:`gp_amplitudes`), and the
per-element weights of ``GPCorr(scale="element")``."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401  (float64)
from ..fit._pd import Scale, theta_to_model


def gp_amplitudes(
    omega, omega_fit, a_fit, ref_theta, scale: Scale
) -> tuple[np.ndarray, np.ndarray]:
    """``(a_H, a_M)`` (N,) N/m on any ``omega`` (rad/s): the data's RMS element sizes
    ``a_fit = (a_H, a_M)`` on the fit band ``omega_fit``, log-log interpolated inside it;
    outside, the reference model's sizes scaled to meet the data at the nearest band end."""
    omega = np.asarray(omega, dtype=np.float64)
    om_f = np.asarray(omega_fit, dtype=np.float64)
    ref_new = reference_amplitudes(ref_theta, scale, omega)
    ref_fit = reference_amplitudes(ref_theta, scale, om_f[[0, -1]])
    out = []
    for a, rn, rf in zip(a_fit, ref_new, ref_fit, strict=True):
        a = np.maximum(np.asarray(a, dtype=np.float64), 1e-300)
        rn, rf = np.maximum(np.asarray(rn), 1e-300), np.maximum(np.asarray(rf), 1e-300)
        v = np.exp(np.interp(np.log(omega), np.log(om_f), np.log(a)))
        v = np.where(omega < om_f[0], rn * a[0] / rf[0], v)
        out.append(np.where(omega > om_f[-1], rn * a[-1] / rf[1], v))
    return out[0], out[1]


def reference_amplitudes(ref_theta, scale: Scale, omega) -> tuple[np.ndarray, np.ndarray]:
    """``(a_H, a_M)`` (N,) in N/m: RMS element sizes ``‖Z(jω)‖_F / n`` of the reference
    model's hand and mechanism impedances on ``omega`` (rad/s) — the GP amplitude scale."""
    m = theta_to_model(jnp.asarray(ref_theta), scale)
    s = 1j * jnp.asarray(omega, dtype=jnp.float64)
    n = m.n
    aH = jnp.linalg.norm(m.hand(s), axis=(-2, -1)) / n
    aM = jnp.linalg.norm(m.mechanism(s), axis=(-2, -1)) / n
    return aH, aM


ELEMENT_FLOOR = 0.01  # element sizes floored at this × √(e_ii e_jj) (a model zero stays > 0)


def element_weights(ref_theta, scale: Scale, omega) -> tuple[np.ndarray, np.ndarray]:
    """Per-element weights ``(w_H, w_M)``, each ``(E, N)`` (``E = n²`` row-major, unitless),
    of the gp_corr model-error amplitude with ``GPCorr(scale="element")``, on ``omega`` (N,)
    rad/s: ``w_ij(ω) = e_ij(ω) / RMS_kl e_kl(ω)`` with ``e_ij = |K_ij| + ω |B_ij| + ω² |M_ij|``
    the size of element ``(i, j)`` of the reference model's hand (``w_H``) or mechanism
    (``w_M``) impedance — the sum of its three terms' magnitudes, so it has no dip where they
    cancel (a resonance) and is smooth in ω — floored at :data:`ELEMENT_FLOOR` ``× √(e_ii
    e_jj)`` so that an element the model leaves at zero keeps a (small) error. The model
    error is then *relative per element*: ``τ`` is the relative size of the misfit in every
    element, large and small. The RMS weight over the elements is 1, so the total error size
    ``τ a(ω)`` is that of ``GPCorr(scale="shared")``. Fixed by the fit: no hyperparameter."""
    m = theta_to_model(jnp.asarray(ref_theta), scale)
    om = np.asarray(omega, dtype=np.float64)
    out = []
    for part in (m.hand, m.mechanism):
        e = sum(
            np.abs(np.asarray(A))[None] * om[:, None, None] ** k
            for k, A in enumerate((part.K, part.B, part.M))
        )  # fmt: skip  (N, n, n)
        d = np.diagonal(e, axis1=-2, axis2=-1)
        e = np.maximum(e, ELEMENT_FLOOR * np.sqrt(d[:, :, None] * d[:, None, :]))
        e = np.maximum(e, 1e-300)
        w = e / np.sqrt(np.mean(e**2, axis=(1, 2)))[:, None, None]
        out.append(w.reshape(om.shape[0], -1).T)
    return out[0], out[1]
