"""Shared test helpers: random strictly second-order devices with known truth."""

import numpy as np

import hapid
from hapid.device import SecondOrderDevice


def random_spd(rng, n, scale, cond=10.0):
    """Random symmetric positive-definite matrix with eigenvalues in [scale/cond, scale]."""
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    ev = scale * np.geomspace(1.0 / cond, 1.0, n)
    return Q @ np.diag(ev) @ Q.T


def random_hand_mechanism(n, seed=0):
    """``(hand, mechanism)``: random SPD second-order impedances (hand ~0.3 kg, 10 Ns/m,
    800 N/m; mechanism ~0.6 kg, 40 Ns/m, 200 N/m; condition 10), from ``seed``."""
    rng = np.random.default_rng(seed)
    hand = hapid.SecondOrder(
        random_spd(rng, n, 0.3), random_spd(rng, n, 10.0), random_spd(rng, n, 800.0)
    )
    mech = hapid.SecondOrder(
        random_spd(rng, n, 0.6), random_spd(rng, n, 40.0), random_spd(rng, n, 200.0)
    )
    return hand, mech


def random_model(n, seed=0):
    """The :class:`hapid.ImpedanceModel` (hand, hand + mechanism) of :func:`random_hand_mechanism`."""
    hand, mech = random_hand_mechanism(n, seed)
    total = hapid.SecondOrder(hand.M + mech.M, hand.B + mech.B, hand.K + mech.K)
    return hapid.ImpedanceModel(hand, total)


def second_order_device(n, seed=0, delay_samples=0):
    hand, mech = random_hand_mechanism(n, seed)
    return SecondOrderDevice(hand=hand, mechanism=mech, delay_samples=delay_samples)


def rel_err(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))
