"""Synthesize runs on a simulated device: exact periodic steady state or time-domain scan.

Both use the same sampled-data model: the commanded forces go through a ``delay_samples``
buffer and a zero-order hold into the continuous device, whose outputs ``[L; R_I]`` are
sampled. ``periodic_run`` evaluates that model's frequency response at the excited bins (exact,
fast, linear); ``time_domain_run`` integrates it with ``jax.lax.scan`` and can add smoothed
Coulomb friction. With the nonlinear effects off the two agree to rounding after transients.
Measurement effects (sensor noise, encoder noise and quantization) are applied identically
afterwards.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import _config  # noqa: F401
from ..device import Device
from ._protocol import Protocol, Run


def _command(device: Device, protocol: Protocol):
    U = protocol.pattern_matrix(device.n)  # (E, n)
    ms = protocol.excitation()
    r = np.asarray(ms.period())  # (Tp,)
    return U, ms, r


def periodic_run(device: Device, protocol: Protocol | None = None, *, hold: str = "zoh",
                 noise_seed: int | None = None) -> Run:  # fmt: skip
    """Exact periodic steady state, computed per excited bin in the frequency domain.

    hold: ``"zoh"`` (sampled hardware: zero-order hold, matches ``time_domain_run``) or
    ``"bandlimited"`` (an ideal band-limited actuator: the continuous response, so the FRF
    equals ``device.impedances`` exactly).
    """
    protocol = Protocol() if protocol is None else protocol
    if device.fs_hz != protocol.fs_hz:
        raise ValueError(
            f"device samples at {device.fs_hz} Hz but the protocol at {protocol.fs_hz} Hz"
        )
    U, ms, _ = _command(device, protocol)
    Tp, n = protocol.period_samples, device.n
    bins = ms.bins
    omega = 2 * np.pi * np.asarray(ms.freq_hz)
    if hold == "zoh":
        z = jnp.exp(1j * omega / device.fs_hz)
        H = device.discrete().freqresp(z) * (z ** (-device.delay_samples))[:, None, None]
    elif hold == "bandlimited":
        s = 1j * omega
        H = (
            device.state_space().freqresp(s)
            * jnp.exp(-s * device.delay_samples / device.fs_hz)[:, None, None]
        )
    else:
        raise ValueError(f"hold must be 'zoh' or 'bandlimited', got {hold!r}")
    c = np.asarray(ms.amplitude) * np.exp(1j * np.asarray(ms.phase))  # (K,)
    Y = np.einsum("kyu,eu,k->eky", np.asarray(H), U, c)  # (E, K, 2n) complex amplitudes
    spec = np.zeros((U.shape[0], Tp // 2 + 1, 2 * n), dtype=complex)
    spec[:, bins, :] = Y * Tp / 2
    y = np.fft.irfft(spec, n=Tp, axis=1)  # (E, Tp, 2n)
    y = np.tile(y, (1, protocol.n_periods, 1))
    r = np.asarray(ms.period())
    R_A = np.tile(U[:, None, :] * r[None, :, None], (1, protocol.n_periods, 1))
    return _measure(y, R_A, n, protocol, noise_seed)


def time_domain_run(device: Device, protocol: Protocol | None = None, *, friction: bool = False,
                    initial: str = "periodic", substeps: int | None = None, noise_seed: int | None = None) -> Run:  # fmt: skip
    """Time-domain simulation (``jax.lax.scan``): delay buffer, zero-order hold, optional
    smoothed Coulomb friction on the motors, then the same measurement model.

    initial: ``"periodic"`` starts from the linear model's exact periodic steady state (so only
    the nonlinear effects need ``transient_periods`` to settle) or ``"zero"`` (rest).
    substeps: integration steps per sample (default 1 without friction, 10 with: the
    friction force is explicit within each sub-step).
    """
    protocol = Protocol() if protocol is None else protocol
    if device.fs_hz != protocol.fs_hz:
        raise ValueError(
            f"device samples at {device.fs_hz} Hz but the protocol at {protocol.fs_hz} Hz"
        )
    if initial not in ("periodic", "zero"):
        raise ValueError(f"initial must be 'periodic' or 'zero', got {initial!r}")
    m = substeps if substeps is not None else (10 if friction else 1)
    U, _, r = _command(device, protocol)
    Tp, n, d = protocol.period_samples, device.n, device.delay_samples
    total = (protocol.transient_periods + protocol.n_periods) * Tp
    cmd = U[:, None, :] * np.tile(r, total // Tp)[None, :, None]  # (E, total, n)
    applied = np.roll(cmd, d, axis=1)  # periodic command: the delay wraps around
    if initial == "zero" and d > 0:
        applied[:, :d] = 0.0
    ss_sub = device.discrete(substeps=m, friction=friction)
    ss_lin = device.discrete(substeps=1)
    y = _simulate(
        device, ss_sub, ss_lin, jnp.asarray(applied), m, friction, initial == "periodic", Tp
    )
    keep = slice(protocol.transient_periods * Tp, None)
    return _measure(np.asarray(y)[:, keep], cmd[:, keep], n, protocol, noise_seed)


class Response(NamedTuple):
    """A device's noise-free response (:func:`time_domain_response`), each ``(E, T, n)``:
    ``L`` the rod displacements (m) and ``R_I`` the interaction forces at the hand (N)."""

    L: np.ndarray
    R_I: np.ndarray


def time_domain_response(device: Device, R_A, *, friction: bool = False,
                         substeps: int | None = None) -> Response:  # fmt: skip
    """Noise-free :class:`Response` ``(L, R_I)`` (each ``(E, T, n)``) of a device at rest to arbitrary
    commanded forces ``R_A`` ``(E, T, n)`` (N): for chirps, noise excitation or closed-loop
    studies. Delay, zero-order hold and optional friction as in ``time_domain_run``."""
    R_A = np.asarray(R_A, dtype=float)
    if R_A.ndim != 3 or R_A.shape[-1] != device.n:
        raise ValueError(f"R_A must be (E, T, n) with n = {device.n}, got shape {R_A.shape}")
    if not np.all(np.isfinite(R_A)):
        raise ValueError("R_A contains NaN or inf")
    m = substeps if substeps is not None else (10 if friction else 1)
    d = device.delay_samples
    applied = np.zeros_like(R_A)
    applied[:, d:] = R_A[:, : R_A.shape[1] - d]
    y = _simulate(device, device.discrete(substeps=m, friction=friction), device.discrete(),
                  jnp.asarray(applied), m, friction, False, 1)  # fmt: skip
    y = np.asarray(y)
    return Response(y[..., : device.n], y[..., device.n :])


def _simulate(device, ss_sub, ss_lin, applied, m, friction, periodic_init, Tp):
    return _simulate_jit(device, ss_sub, ss_lin, applied, m, friction, periodic_init, Tp)


@functools.partial(jax.jit, static_argnums=(4, 5, 6, 7))
def _simulate_jit(device, ss_sub, ss_lin, applied, m, friction, periodic_init, Tp):
    n = device.n
    A, B, C, D = ss_sub.A, ss_sub.B, ss_sub.C, ss_sub.D
    nx = A.shape[0]

    def step(x, u):
        y = C @ x + D[:, :n] @ u

        def sub(x, _):
            uu = jnp.concatenate([u, device.coulomb_force(x)]) if friction else u
            return A @ x + B @ uu, None

        x, _ = jax.lax.scan(sub, x, None, length=m)
        return x, y

    def one(u_seq):
        if periodic_init:
            # linear periodic steady state: x0 = (I − Ad^Tp)⁻¹ · (state after one period from rest)
            Al, Bl = ss_lin.A, ss_lin.B[:, :n]
            xT, _ = jax.lax.scan(lambda x, u: (Al @ x + Bl @ u, None), jnp.zeros(nx), u_seq[:Tp])
            x0 = jnp.linalg.solve(jnp.eye(nx) - jnp.linalg.matrix_power(Al, Tp), xT)
        else:
            x0 = jnp.zeros(nx)
        _, ys = jax.lax.scan(step, x0, u_seq)
        return ys

    return jax.vmap(one)(applied)


def _measure(y, R_A, n, protocol: Protocol, noise_seed) -> Run:
    rng = np.random.default_rng(protocol.seed + 1 if noise_seed is None else noise_seed)
    L = np.array(y[..., :n])
    R_I = np.array(y[..., n:])
    if protocol.force_noise > 0:
        R_I = R_I + protocol.force_noise * rng.standard_normal(R_I.shape)
    if protocol.position_noise > 0:
        L = L + protocol.position_noise * rng.standard_normal(L.shape)
    if protocol.encoder_resolution > 0:
        L = protocol.encoder_resolution * np.round(L / protocol.encoder_resolution)
    return Run(
        fs_hz=float(protocol.fs_hz),
        period_samples=int(protocol.period_samples),
        freq_hz=np.asarray(protocol.freq_hz, dtype=float),
        R_A=np.ascontiguousarray(R_A, dtype=float),
        R_I=R_I,
        L=L,
    )
