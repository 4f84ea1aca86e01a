"""Synthetic strictly second-order truths and FRFs for the fit tests (no hapid.device)."""

from __future__ import annotations

import numpy as np

from hapid.frf import as_frf
from hapid.impedance import ImpedanceModel, SecondOrder

PAPER_FREQ_HZ = np.concatenate([np.arange(1.0, 11.0), np.arange(15.0, 101.0, 5.0)])  # 28


def random_spd(rng, n, lo, hi, max_cond=5.0):
    """Symmetric PD matrix with eigenvalues log-uniform in [lo, hi] within ``max_cond``."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    top = np.exp(rng.uniform(np.log(lo * max_cond), np.log(hi)))
    lam = np.exp(rng.uniform(np.log(top / max_cond), np.log(top), size=n))
    return (Q * lam) @ Q.T


def random_truth(n, seed=0) -> ImpedanceModel:
    """Hand and mechanism with SPD M (0.1–1 kg), B (1–50 N·s/m), K (10²–10⁴ N/m)."""
    rng = np.random.default_rng(seed)
    hand = SecondOrder(
        random_spd(rng, n, 0.1, 1.0), random_spd(rng, n, 1.0, 50.0), random_spd(rng, n, 1e2, 1e4)
    )
    mech = SecondOrder(
        random_spd(rng, n, 0.1, 1.0), random_spd(rng, n, 1.0, 50.0), random_spd(rng, n, 1e2, 1e4)
    )
    return ImpedanceModel.from_hand_mechanism(hand, mech)


def synthetic_frf(truth: ImpedanceModel, freq_hz=PAPER_FREQ_HZ, rel_noise=1e-4, seed=1):
    """FRF of ``truth`` plus complex Gaussian noise, std ``rel_noise·‖Z(jω)‖_F/n`` per element.

    The std stored in the FRF is the std of the complex element (real and imaginary parts
    together), as ``hapid.frf`` defines it.
    """
    rng = np.random.default_rng(seed)
    w = 2 * np.pi * np.asarray(freq_hz)
    out = []
    for Z in (np.asarray(truth.hand.at_omega(w)), np.asarray(truth.total.at_omega(w))):
        n = Z.shape[-1]
        std = rel_noise * np.linalg.norm(Z, axis=(-2, -1))[:, None, None] / n
        std = np.broadcast_to(std, Z.shape).copy()
        noise = (rng.standard_normal(Z.shape) + 1j * rng.standard_normal(Z.shape)) / np.sqrt(2)
        out.append((Z + std * noise, std))
    (Z_H, s_H), (Z_T, s_T) = out
    return as_frf(freq_hz, Z_H, Z_T, s_H, s_T)


def batch_frfs(truth: ImpedanceModel, n_batch, freq_hz=PAPER_FREQ_HZ, rel_noise=1e-4, seed=100):
    """A batched FRF (leading axis ``n_batch``) of independent noise realizations."""
    frfs = [synthetic_frf(truth, freq_hz, rel_noise, seed + k) for k in range(n_batch)]
    stack = lambda name: np.stack([np.asarray(getattr(f, name)) for f in frfs])  # noqa: E731
    return as_frf(
        np.stack([np.asarray(freq_hz)] * n_batch),
        stack("Z_H"),
        stack("Z_T"),
        stack("Z_H_std"),
        stack("Z_T_std"),
    )


def wls_reference(freq_hz, Z, omega_c=7 * 2 * np.pi):
    """Paper section 4.2 by explicit loops over (i, j): ``(Re φ̃φ̃ᴴ)⁻¹ Re(φ̃ Z̃)``, φ̃ = Aᴴ."""
    w = 2 * np.pi * np.asarray(freq_hz)
    s = 1j * w
    h = 1.0 / (s + omega_c) ** 2
    phiH = h[:, None] * np.stack([s**2, s, np.ones_like(s)], axis=1)  # (N, 3) = φ̃ᴴ
    phi = phiH.conj().T  # (3, N)
    n = Z.shape[-1]
    out = np.zeros((3, n, n))
    for i in range(n):
        for j in range(n):
            Zt = h * Z[:, i, j]
            out[:, i, j] = np.linalg.solve(np.real(phi @ phiH), np.real(phi @ Zt))
    return out
