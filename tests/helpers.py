"""Shared test helpers: random strictly second-order devices with known truth."""

import numpy as np

import hapid
from hapid.device import SecondOrderDevice


def random_spd(rng, n, scale, cond=10.0):
    """Random symmetric positive-definite matrix with eigenvalues in [scale/cond, scale]."""
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    ev = scale * np.geomspace(1.0 / cond, 1.0, n)
    return Q @ np.diag(ev) @ Q.T


def second_order_device(n, seed=0, delay_samples=0):
    rng = np.random.default_rng(seed)
    hand = hapid.SecondOrder(
        random_spd(rng, n, 0.3), random_spd(rng, n, 10.0), random_spd(rng, n, 800.0)
    )
    mech = hapid.SecondOrder(
        random_spd(rng, n, 0.6), random_spd(rng, n, 40.0), random_spd(rng, n, 200.0)
    )
    return SecondOrderDevice(hand=hand, mechanism=mech, delay_samples=delay_samples)


def rel_err(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))
