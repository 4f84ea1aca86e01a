"""A jittable, vmappable shortcut from device to FRF for sweeps and Monte Carlo studies.

For a periodic run with white Gaussian measurement noise, the period-averaged DFT at each
excited bin is the exact steady-state amplitude plus complex Gaussian noise of total variance
``4 σ² / (T_p P)`` (``T_p`` samples per period, ``P`` periods), independent across bins,
experiments and channels. ``simulate_frf`` draws those averaged spectra directly and solves
``Z = −𝓡 𝓛⁺`` — the same estimator as ``periodic_run`` + ``estimate_frf`` and the same
distribution (without quantization, which is not Gaussian), but in one pure JAX function
whose inputs (device parameters, noise levels, keys) can be batched with ``vmap``. The std
it reports is the first-order formula of ``estimate_frf`` with the *known* noise variance.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .. import _config  # noqa: F401
from .._linalg import svdvals
from ..device import Device
from ..frf import FRF
from ._protocol import Protocol


def simulate_frf(device: Device, protocol: Protocol, key, *, force_noise=None,
                 position_noise=None, n_periods=None) -> FRF:  # fmt: skip
    """FRF of a simulated periodic experiment (zero-order hold), in pure JAX.

    ``force_noise``, ``position_noise`` (std per sample) and ``n_periods`` override the
    protocol's values and may be traced (batched) scalars.
    """
    sf = protocol.force_noise if force_noise is None else force_noise
    sl = protocol.position_noise if position_noise is None else position_noise
    P = protocol.n_periods if n_periods is None else n_periods
    U = jnp.asarray(protocol.pattern_matrix(device.n))  # (E, n)
    ms = protocol.excitation()
    omega = 2 * jnp.pi * jnp.asarray(ms.freq_hz)
    z = jnp.exp(1j * omega / device.fs_hz)
    H = device.discrete().freqresp(z) * (z ** (-device.delay_samples))[:, None, None]
    c = ms.amplitude * jnp.exp(1j * ms.phase)  # (K,)
    n, E, K = device.n, U.shape[0], omega.shape[0]
    cmd = c[:, None, None] * U.T[None]  # (K, n, E) commanded amplitudes
    Y = H @ cmd  # (K, 2n, E)
    var = 4.0 / (protocol.period_samples * P)
    k1, k2 = jax.random.split(key)

    def cnoise(k, shape, std):
        re, im = jax.random.normal(k, (2,) + shape)
        return std * jnp.sqrt(var / 2) * (re + 1j * im)

    Lm = Y[:, :n] + cnoise(k1, (K, n, E), sl)
    RI = Y[:, n:] + cnoise(k2, (K, n, E), sf)
    # 𝓛⁺ = (𝓛ᴴ𝓛)⁻¹𝓛ᴴ (E ≥ n): an LU solve, not an SVD — see hapid._linalg
    Lh = jnp.swapaxes(jnp.conj(Lm), -1, -2)
    Lp = jnp.linalg.solve(Lh @ Lm, Lh)  # (K, E, n)
    Z_H = -RI @ Lp
    Z_T = -cmd @ Lp
    w = jnp.abs(Lp) ** 2  # (K, E, n)
    # var(ε_ie) = var_R + Σ_m |Z_im|² var_L for each experiment e (same for all e)
    vH = var * (sf**2 + sl**2 * jnp.sum(jnp.abs(Z_H) ** 2, axis=-1))  # (K, n)
    vT = var * (sl**2 * jnp.sum(jnp.abs(Z_T) ** 2, axis=-1))
    std_H = jnp.sqrt(vH[:, :, None] * jnp.sum(w, axis=1)[:, None, :])
    std_T = jnp.sqrt(vT[:, :, None] * jnp.sum(w, axis=1)[:, None, :])
    sv = svdvals(Lm)
    return FRF(omega=omega, Z_H=Z_H, Z_T=Z_T, Z_H_std=std_H, Z_T_std=std_T,
               cond_L=sv[:, 0] / sv[:, -1])  # fmt: skip
