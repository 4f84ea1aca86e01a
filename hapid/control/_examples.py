"""Small synthetic impedance models for examples, tests and benchmarks of ``hapid.control``.

Not a device simulation (see ``hapid.device``): just plausible second-order Ẑ_H, Ẑ_T with
rod-space coupling, so that control code can be exercised without the other stages.
"""

from __future__ import annotations

import numpy as np

from ..impedance import ImpedanceModel, SecondOrder


def _spd(rng, n, lo, hi, Q):
    return Q @ np.diag(rng.uniform(lo, hi, n)) @ Q.T


def example_model(n: int = 5, seed: int = 0) -> ImpedanceModel:
    """A random but physically plausible ``n``-rod model (SI units, rod space).

    Hand: M_H eigenvalues 0.1–0.5 kg, B_H 2–20 N·s/m, K_H 200–1000 N/m, coupled by a random
    rotation; mechanism: diagonal 0.4–0.6 kg, 20–40 N·s/m, no stiffness. ``Ẑ_T = Ẑ_H + Ẑ_M``.
    All matrices symmetric positive definite, so both impedances have OLHP roots.
    """
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    hand = SecondOrder(
        M=_spd(rng, n, 0.1, 0.5, Q), B=_spd(rng, n, 2.0, 20.0, Q), K=_spd(rng, n, 200.0, 1000.0, Q)
    )
    mech = SecondOrder(
        M=np.diag(rng.uniform(0.4, 0.6, n)),
        B=np.diag(rng.uniform(20.0, 40.0, n)),
        K=np.zeros((n, n)),
    )
    hand = SecondOrder(*(np.asarray(x) for x in (hand.M, hand.B, hand.K)))
    return ImpedanceModel.from_hand_mechanism(hand, mech)
