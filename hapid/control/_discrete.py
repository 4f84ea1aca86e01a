# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""Discretization of the compensator and of the inverse-model controller.

**g(s): matched pole-zero** (paper section 5.2; Franklin, Powell & Workman, *Digital
Control of Dynamic Systems*): every pole and finite zero maps by ``z = e^{s t_s}``; zeros at
``s = ∞`` (one per low-pass pole) map to ``z = −1`` (``infinite_zeros="minus_one"``, the
default), all but one of them (``"all_but_one"``: a strictly proper g with one sample of
computation delay) or none (``"delay"``: python-control's ``sample_system(method="matched")``);
the gain of each section is set so that the DC gain matches. Done section by section (lag,
notch, low-pass), which equals matching the whole product. Requires no pole or zero at
``s = 0`` (DC gain finite and non-zero).

**Matrix part Ẑ_T Ẑ_H⁻¹: Tustin (bilinear)** of its state space
(:func:`._controller.impedance_ratio_state_space`, state ``[y; ẏ]``) by default. Tustin maps
the open left half plane onto the open unit disc, so the discrete controller is stable iff
the continuous one is (the CRHP verdict carries over), and it is exact at DC; its frequency
warping ``ω_c = (2/t_s) tan(ω t_s/2)`` matters little here because Ẑ_T Ẑ_H⁻¹ is flat
(→ M̂_T M̂_H⁻¹) above the hand resonances. ``method="zoh"`` (exact for a held input) is
available as well; it adds the half-sample phase lag of the hold to the dynamic part.

**Stated accuracy** (tested in ``tests/test_control_discrete.py`` with the paper's g and
random 3–5-rod second-order models at ``t_s`` = 1 ms; measured maxima over 12 models in
brackets), with ``e(ω) = ‖G_d(e^{jωt_s}) − G(jω)‖₂``, for every ω up to π/t_s:

* matrix part alone (Tustin): ``e ≤ 0.01 ‖G(jω)‖₂`` below fs/10 [0.5 %] and
  ``e ≤ 0.05 ‖G(jω)‖₂`` up to fs/2 [3.1 %, at fs/2, where the warping is largest];
* whole controller, g matched pole-zero (the paper's):
  ``e ≤ 0.25 ω t_s ‖G(jω)‖₂ + 0.01 max_ω ‖G‖₂`` [≤ 0.74 of that bound]. The matched g lags
  the continuous one by about 0.2 samples (−0.7° at 10 Hz, −7° at 100 Hz for 1 kHz):
  relative error ≈ 0.2 ω t_s, i.e. 1.2 % at 10 Hz and 14 % at 100 Hz, reaching 100 % at
  fs/2 where the zeros at z = −1 null the response (g has rolled off there: the absolute
  error stays ≤ 2 % of the peak gain [1.7 %]);
* whole controller, ``g_method="tustin"``: ``e ≤ 0.01 ‖G(jω)‖₂`` below 30 Hz [0.5 %] and
  ``e ≤ 0.02 max_ω ‖G‖₂`` up to fs/2 [0.95 %].
"""

from __future__ import annotations

from .. import _config  # noqa: F401  (float64)
from ..impedance import ImpedanceModel
from ..lti import StateSpace, block_diag, matched, series, tustin, zoh
from ._compensator import Compensator
from ._controller import impedance_ratio_state_space

DiscreteStateSpace = StateSpace
"""A discrete :class:`hapid.lti.StateSpace` (``ts`` set): ``x[k+1] = A x[k] + B u[k]``,
``y[k] = C x[k] + D u[k]``; ``step(x, u) -> (x_next, y)`` is the body of a ``lax.scan`` loop.
``D ≠ 0`` means the output responds in the same sample."""

DiscreteController = DiscreteStateSpace
"""The discrete inverse-model controller: input R_E (n), output R_A (n)."""


def discretize_compensator(
    g: Compensator, ts: float, infinite_zeros: str = "minus_one"
) -> DiscreteStateSpace:
    """Matched pole-zero discretization of ``g`` with matched DC gain (SISO, ``ts`` in s):
    :func:`hapid.lti.matched`. See the module docstring for ``infinite_zeros``."""
    return matched(g, ts, infinite_zeros)


def discretize_state_space(
    sys: StateSpace, ts: float, method: str = "tustin", prewarp: float | None = None
) -> DiscreteStateSpace:
    """Tustin (``prewarp`` in rad/s optional: exact at that frequency) or ZOH of ``sys``
    (:func:`hapid.lti.tustin`, :func:`hapid.lti.zoh`)."""
    if method == "tustin":
        return tustin(sys, ts, prewarp)
    if method == "zoh":
        return zoh(sys, ts)
    raise ValueError(f"method must be 'tustin' or 'zoh', got {method!r}")


def discretize_controller(
    model: ImpedanceModel,
    g: Compensator,
    ts: float,
    method: str = "tustin",
    infinite_zeros: str = "minus_one",
    prewarp: float | None = None,
    g_method: str = "matched",
) -> DiscreteStateSpace:
    """Discrete inverse-model controller ``G_d = [Ẑ_T Ẑ_H⁻¹]_d · g_d I`` (input R_E, output R_A).

    g by matched pole-zero (``g_method="matched"``, the paper's; ``infinite_zeros`` as in
    :func:`discretize_compensator`) or ``"tustin"`` (same ``prewarp``; ~10× more accurate
    below 30 Hz at 1 kHz), per channel; the matrix part by ``method`` (``"tustin"`` or
    ``"zoh"``); states ``[x_g (n·order(g)); y-part (2n)]``. ``ts`` in seconds. Run it with
    ``DiscreteStateSpace.step`` in a ``lax.scan``.
    """
    n = model.n
    if g_method == "matched":
        gd = discretize_compensator(g, ts, infinite_zeros)
    elif g_method == "tustin":
        gd = discretize_state_space(g.state_space(), ts, "tustin", prewarp)
    else:
        raise ValueError(f"g_method must be 'matched' or 'tustin', got {g_method!r}")
    md = discretize_state_space(impedance_ratio_state_space(model), ts, method, prewarp)
    return series(block_diag(gd, n), md)


def discretize_siso_controller(g, c: float, ts: float, n: int) -> DiscreteStateSpace:
    """The SISO baseline ``G = c·g(s)·I_n`` sampled at ``ts`` (matched pole-zero ``g``, as
    :func:`discretize_controller` uses): ``n`` decoupled copies, output scaled by ``c``."""
    gbig = block_diag(discretize_compensator(g, ts), n)
    return StateSpace(gbig.A, gbig.B, c * gbig.C, c * gbig.D, ts=gbig.ts)
