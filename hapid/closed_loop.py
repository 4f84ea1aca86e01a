"""The sampled force loop: discretized controller + simulated device, in one state space.

Loop (paper Fig. 4, sampled at ``fs``): error ``e[k] = R_D[k] − R_I[k]``, controller
``R_A,cmd = G_d e``, actuator ``R_A,applied[k] = R_A,cmd[k − d]`` (``d`` = the device's
delay in samples), zero-order hold into the device, sensor reading ``R_I[k]``. Because the
command is delayed by at least one sample (or the device has no feedthrough), the loop is
well posed. ``closed_loop_matrix`` gives the closed-loop transition matrix, whose spectral
radius decides stability independently of the Nyquist analysis; ``simulate_loop`` runs the
loop with ``lax.scan`` (optionally with Coulomb friction and sensor noise).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from . import _config  # noqa: F401
from .device import Device
from .lti import StateSpace, feedback


class ClosedLoop(eqx.Module):
    """Closed-loop sampled system. State ``[x_dev, u_buffer (d·n), x_ctrl]``; input ``R_D``
    (``n``); outputs ``[L; R_I]`` (``2n``)."""

    A: Float[Array, "nx nx"]
    B: Float[Array, "nx n"]
    C: Float[Array, "2n nx"]
    n: int = eqx.field(static=True)

    def spectral_radius(self) -> Array:
        return jnp.max(jnp.abs(jnp.linalg.eigvals(self.A)))

    def is_stable(self, margin: float = 0.0) -> Array:
        """Stable iff every closed-loop eigenvalue lies inside the unit circle."""
        return self.spectral_radius() < 1.0 - margin


def closed_loop(device: Device, controller) -> ClosedLoop:
    """Assemble the loop of ``device`` with a discrete controller (``A, B, C, D`` fields,
    input ``e`` (n), output ``R_A`` (n), same sampling period)."""
    n, d = device.n, device.delay_samples
    dev = device.discrete()
    Ad, Bd, Cd, Dd = dev.A, dev.B[:, :n], dev.C, dev.D[:, :n]
    Ac, Bc, Cc, Dc = controller.A, controller.B, controller.C, controller.D
    nx, nc = Ad.shape[0], Ac.shape[0]
    CR, DR = Cd[n:], Dd[n:]
    if d == 0:  # R_I[k] depends on u[k] through D: solve the algebraic loop (hapid.lti.feedback)
        plant = StateSpace(Ad, Bd, CR, DR, ts=dev.ts)
        cl = feedback(plant, StateSpace(Ac, Bc, Cc, Dc, ts=dev.ts))
        Ku = cl.C[CR.shape[0] :]  # u = Ku [x; x_c] + (…) r
        C = jnp.concatenate([Cd, jnp.zeros((2 * n, nc))], axis=1) + Dd @ Ku
        return ClosedLoop(cl.A, cl.B, C, n)
    nb = d * n
    # buffer b = [u_cmd[k−d], …, u_cmd[k−1]]; applied u[k] = b[0:n]
    S = jnp.zeros((nb, nb)).at[: nb - n, n:].set(jnp.eye(nb - n)) if d > 1 else jnp.zeros((nb, nb))
    E_last = jnp.zeros((nb, n)).at[nb - n :].set(jnp.eye(n))
    sel = jnp.zeros((n, nb)).at[:, :n].set(jnp.eye(n))
    # R_I[k] = CR x + DR sel b  (no dependence on u_cmd[k])
    Ry_x, Ry_b = CR, DR @ sel
    # u_cmd[k] = Cc xc + Dc (r − R_I)
    A = jnp.block([
        [Ad, Bd @ sel, jnp.zeros((nx, nc))],
        [-E_last @ Dc @ Ry_x, S - E_last @ Dc @ Ry_b, E_last @ Cc],
        [-Bc @ Ry_x, -Bc @ Ry_b, Ac],
    ])  # fmt: skip
    B = jnp.concatenate([jnp.zeros((nx, n)), E_last @ Dc, Bc], axis=0)
    C = jnp.concatenate([Cd, Dd @ sel, jnp.zeros((2 * n, nc))], axis=1)
    return ClosedLoop(A, B, C, n)


def simulate_loop(device: Device, controller, R_D, *, friction: bool = False,
                  force_noise: float = 0.0, seed: int = 0, substeps: int | None = None):  # fmt: skip
    """Run the sampled loop from rest for desired forces ``R_D`` (``(T, n)``, N).

    Returns ``dict(R_I, R_A, L)`` of ``(T, n)`` arrays (sensed force with noise if any,
    commanded actuator force, encoder lengths). Friction and noise make it nonlinear/noisy;
    without them it equals the ``ClosedLoop`` state-space response.
    """
    R_D = jnp.asarray(R_D, dtype=jnp.float64)
    n, d = device.n, device.delay_samples
    if R_D.ndim != 2 or R_D.shape[1] != n:
        raise ValueError(f"R_D must be (T, n) with n = {n}, got shape {R_D.shape}")
    if not bool(jnp.all(jnp.isfinite(R_D))):
        raise ValueError("R_D contains NaN or inf")
    if d < 1:
        raise ValueError("simulate_loop needs a device with at least one sample of actuator "
                         "delay (use closed_loop(...) for the state-space loop without delay)")  # fmt: skip
    m = substeps if substeps is not None else (10 if friction else 1)
    dev = device.discrete(substeps=m, friction=friction)
    noise = force_noise * jax.random.normal(jax.random.PRNGKey(seed), R_D.shape)
    return _simulate(device, dev, controller, R_D, noise, m, friction, d)


@functools.partial(jax.jit, static_argnums=(5, 6, 7))
def _simulate(device, dev, ctrl, R_D, noise, m, friction, d):
    n = device.n
    nx = dev.A.shape[0]

    def step(carry, inp):
        x, buf, xc = carry
        r, w = inp
        u = buf[0]
        y = dev.C @ x + dev.D[:, :n] @ u
        R_I = y[n:] + w
        e = r - R_I
        u_cmd = ctrl.C @ xc + ctrl.D @ e
        xc = ctrl.A @ xc + ctrl.B @ e

        def sub(x, _):
            uu = jnp.concatenate([u, device.coulomb_force(x)]) if friction else u
            return dev.A @ x + dev.B @ uu, None

        x, _ = jax.lax.scan(sub, x, None, length=m)
        buf = jnp.concatenate([buf[1:], u_cmd[None]], axis=0)
        return (x, buf, xc), (R_I, u_cmd, y[:n])

    init = (jnp.zeros(nx), jnp.zeros((d, n)), jnp.zeros(ctrl.A.shape[0]))
    _, (R_I, R_A, L) = jax.lax.scan(step, init, (R_D, noise))
    return {"R_I": R_I, "R_A": R_A, "L": L}


def tracking_error(R_D, R_I, skip: int = 0) -> np.ndarray:
    """RMS force-tracking error per rod direction (N), after ``skip`` samples."""
    e = np.asarray(R_I)[skip:] - np.asarray(R_D)[skip:]
    return np.sqrt(np.mean(e**2, axis=0))
