# ruff: noqa: F722  (jaxtyping shape strings in annotations)
"""The scalar compensator ``g(s)`` of the paper (section 5.2), with configurable terms.

    g(s) = k · Π_j (s + z_j)/(s + p_j)                                  lag (or lead) pairs
             · Π_i (s² + 2ζ_num,i ω_i s + ω_i²)/(s² + 2ζ_den,i ω_i s + ω_i²)     notches
             · Π_l a_l/(s + a_l)                                         unit-DC low-pass poles

All parameters are rad/s (frequencies) or dimensionless (``k``, damping ratios). Every term
is an array, so any number of lag pairs, notches and low-pass poles is allowed (zero too).
The module is a pytree of its parameters: evaluation and the state-space realization are
pure ``jnp`` and can be differentiated with respect to every parameter (gradient tuning).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from .. import _config  # noqa: F401  (float64)
from .._constants import TWO_PI
from ..lti import StateSpace, series


def _vec(x) -> Array:
    return jnp.atleast_1d(jnp.asarray(x, dtype=jnp.float64))


FIELDS = (
    "k",
    "lag_zeros",
    "lag_poles",
    "notch_omega",
    "notch_zeta_num",
    "notch_zeta_den",
    "lowpass",
)
"""The fields of :class:`Compensator`, in the order design files and the tuner use."""
POSITIVE_FIELDS = ("k", "lag_zeros", "lag_poles", "notch_omega", "notch_zeta_den", "lowpass")
"""Fields that must be > 0 (the others ≥ 0)."""


class Compensator(eqx.Module):
    """Scalar compensator ``g(s)`` (see the module docstring for the formula).

    Fields (shapes): ``k ()``; ``lag_zeros (q,)`` and ``lag_poles (q,)`` rad/s;
    ``notch_omega (m,)`` rad/s with ``notch_zeta_num (m,)`` (ζ₁, the depth-setting numerator
    damping) and ``notch_zeta_den (m,)`` (ζ₂); ``lowpass (r,)`` rad/s. Construct the paper's
    values with :meth:`paper`.
    """

    k: Float[Array, ""]
    lag_zeros: Float[Array, " q"]
    lag_poles: Float[Array, " q"]
    notch_omega: Float[Array, " m"]
    notch_zeta_num: Float[Array, " m"]
    notch_zeta_den: Float[Array, " m"]
    lowpass: Float[Array, " r"]

    def __init__(
        self,
        k=1.0,
        lag_zeros=(),
        lag_poles=(),
        notch_omega=(),
        notch_zeta_num=(),
        notch_zeta_den=(),
        lowpass=(),
    ):
        self.k = jnp.asarray(k, dtype=jnp.float64)
        self.lag_zeros = _vec(lag_zeros)
        self.lag_poles = _vec(lag_poles)
        w = _vec(notch_omega)
        self.notch_omega = w
        self.notch_zeta_num = jnp.broadcast_to(_vec(notch_zeta_num), w.shape) if w.size else w
        self.notch_zeta_den = jnp.broadcast_to(_vec(notch_zeta_den), w.shape) if w.size else w
        self.lowpass = _vec(lowpass)

    def __check_init__(self):
        if np.shape(self.k) != ():
            raise ValueError(f"Compensator: k must be a scalar, got shape {np.shape(self.k)}")
        if np.shape(self.lag_zeros) != np.shape(self.lag_poles):
            raise ValueError(
                "Compensator: lag_zeros and lag_poles must have the same length, got "
                f"{np.shape(self.lag_zeros)} and {np.shape(self.lag_poles)}"
            )
        m = np.shape(self.notch_omega)
        if np.shape(self.notch_zeta_num) != m or np.shape(self.notch_zeta_den) != m:
            raise ValueError("Compensator: notch damping ratios must match notch_omega")

    @classmethod
    def paper(cls, **overrides) -> Compensator:
        """The paper's g(s): k = 0.85, p₁ = 1.2π, z₁ = 30·2π, notches at 17, 55, 100 Hz
        (ζ₁ = 0.2, ζ₂ = 0.5), low-pass poles at 100·2π and 200·2π rad/s."""
        params = dict(
            k=0.85,
            lag_zeros=[30.0 * TWO_PI],
            lag_poles=[1.2 * np.pi],
            notch_omega=[17.0 * TWO_PI, 55.0 * TWO_PI, 100.0 * TWO_PI],
            notch_zeta_num=0.2,
            notch_zeta_den=0.5,
            lowpass=[100.0 * TWO_PI, 200.0 * TWO_PI],
        )
        params.update(overrides)
        return cls(**params)

    # --- evaluation -------------------------------------------------------------------

    def __call__(self, s: Complex[Array, " N"]) -> Complex[Array, " N"]:
        """``g(s)`` at complex ``s`` (rad/s), shape of ``s``."""
        return _response(self, jnp.asarray(s, dtype=jnp.complex128))

    def at_omega(self, omega: Float[Array, " N"]) -> Complex[Array, " N"]:
        """Frequency response ``g(jω)`` with ω in rad/s."""
        return self(1j * jnp.asarray(omega))

    @property
    def order(self) -> int:
        """Number of states of the realization (``q + 2m + r``)."""
        return int(self.lag_zeros.size + 2 * self.notch_omega.size + self.lowpass.size)

    @property
    def relative_degree(self) -> int:
        """Poles minus finite zeros (the number of low-pass poles)."""
        return int(self.lowpass.size)

    # --- rational forms (numpy, at the edge: cross-checks and reporting) ---------------

    def zpk(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Zeros, poles (rad/s, complex numpy) and the gain ``K`` of ``K Π(s−z)/Π(s−p)``."""
        zeros, poles = [-np.asarray(self.lag_zeros)], [-np.asarray(self.lag_poles)]
        for w, zn, zd in zip(
            np.asarray(self.notch_omega),
            np.asarray(self.notch_zeta_num),
            np.asarray(self.notch_zeta_den),
            strict=True,
        ):
            zeros.append(np.roots([1.0, 2 * zn * w, w * w]))
            poles.append(np.roots([1.0, 2 * zd * w, w * w]))
        lp = np.asarray(self.lowpass)
        poles.append(-lp)
        gain = float(self.k) * float(np.prod(lp))
        z = np.concatenate([np.asarray(x, dtype=complex) for x in zeros])
        p = np.concatenate([np.asarray(x, dtype=complex) for x in poles])
        return z, p, gain

    def tf_coefficients(self) -> tuple[np.ndarray, np.ndarray]:
        """Numerator and denominator coefficients in descending powers of ``s`` (numpy).

        Built by multiplying the real factors, so they are real up to rounding. High-order
        polynomials in ``s`` are badly scaled (coefficients span ~10²⁰ for the paper's g);
        prefer :meth:`state_space` for computation.
        """
        num, den = np.array([1.0]), np.array([1.0])
        for zj, pj in zip(np.asarray(self.lag_zeros), np.asarray(self.lag_poles), strict=True):
            num, den = np.polymul(num, [1.0, zj]), np.polymul(den, [1.0, pj])
        for w, zn, zd in zip(
            np.asarray(self.notch_omega),
            np.asarray(self.notch_zeta_num),
            np.asarray(self.notch_zeta_den),
            strict=True,
        ):
            num = np.polymul(num, [1.0, 2 * zn * w, w * w])
            den = np.polymul(den, [1.0, 2 * zd * w, w * w])
        for a in np.asarray(self.lowpass):
            num, den = num * a, np.polymul(den, [1.0, a])
        return float(self.k) * num, den

    def state_space(self) -> StateSpace:
        """A balanced-ish cascade realization (1 input, 1 output, :attr:`order` states).

        Sections, in order: lag pairs ``1 + (z−p)/(s+p)``; notches with the scaled companion
        form ``A = [[0, ω], [−ω, −2ζ₂ω]]``, ``B = [0, 1]ᵀ``, ``C = [0, 2(ζ₁−ζ₂)ω]``, ``D = 1``
        (states of comparable size at every ω); low-pass poles ``A = −a``, ``B = C = √a``.
        The gain k multiplies the output. Pure ``jnp``: differentiable in the parameters.
        """
        sys = StateSpace(
            jnp.zeros((0, 0)), jnp.zeros((0, 1)), jnp.zeros((1, 0)), self.k * jnp.ones((1, 1))
        )
        for j in range(self.lag_zeros.size):
            z, p = self.lag_zeros[j], self.lag_poles[j]
            sec = StateSpace(
                -p.reshape(1, 1), jnp.ones((1, 1)), (z - p).reshape(1, 1), jnp.ones((1, 1))
            )
            sys = series(sys, sec)
        for i in range(self.notch_omega.size):
            w, zn, zd = self.notch_omega[i], self.notch_zeta_num[i], self.notch_zeta_den[i]
            A = jnp.array([[0.0, 1.0], [-1.0, -2.0 * zd]]) * w
            B = jnp.array([[0.0], [1.0]])
            C = jnp.stack([jnp.zeros(()), 2.0 * (zn - zd) * w]).reshape(1, 2)
            sys = series(sys, StateSpace(A, B, C, jnp.ones((1, 1))))
        for l_ in range(self.lowpass.size):
            a = self.lowpass[l_]
            r = jnp.sqrt(a).reshape(1, 1)
            sys = series(sys, StateSpace(-a.reshape(1, 1), r, r, jnp.zeros((1, 1))))
        return sys


@jax.jit
def _response(g: Compensator, s):
    """``g(s)`` at complex ``s`` (one compiled program per shape of ``s`` and of g's terms)."""
    s = s[..., None]
    lag = jnp.prod((s + g.lag_zeros) / (s + g.lag_poles), axis=-1)
    w = g.notch_omega
    notch = jnp.prod(
        (s**2 + 2 * g.notch_zeta_num * w * s + w**2) / (s**2 + 2 * g.notch_zeta_den * w * s + w**2),
        axis=-1,
    )
    lp = jnp.prod(g.lowpass / (s + g.lowpass), axis=-1)
    return g.k * lag * notch * lp
