"""An independent refined loop reference in numpy/scipy (no hapid numerics): the crossings of
σ̄(T − I) = σ̄(S) through 1 − 1/√2, the peaks of σ̄(T) and σ̄(S − T), each located on the grid
and then solved for on the exact loop ``L_at(ω)`` with scipy's ``brentq`` /
``minimize_scalar`` in log ω."""

import numpy as np
from scipy.optimize import brentq, minimize_scalar

TWO_PI = 2 * np.pi
THR = 1 - 1 / np.sqrt(2)


def _maps(L):
    n = L.shape[-1]
    S = np.linalg.inv(np.eye(n) + L)
    return S, np.eye(n) - S


def _sig(M):
    return np.linalg.svd(M, compute_uv=False)[..., 0]


def refined_numbers(L_at, omega) -> dict:
    """``iso_bandwidth_hz`` (first crossing), ``iso_bandwidth_literal_hz`` (last), ``t_peak_db``,
    ``t_peak_hz``, ``disk_margin`` of the loop ``L_at(omega (M,)) → (M, n, n)`` (numpy),
    located on ``omega`` (rad/s) and refined on ``L_at``. Assumes a stable loop."""
    omega = np.asarray(omega, dtype=float)
    lw = np.log(omega)

    def sig_S(x):
        return float(_sig(_maps(L_at(np.array([np.exp(x)])))[0])[0])

    def sig_T(x):
        return float(_sig(_maps(L_at(np.array([np.exp(x)])))[1])[0])

    def sig_SmT(x):
        S, T = _maps(L_at(np.array([np.exp(x)])))
        return float(_sig(S - T)[0])

    S, T = _maps(L_at(omega))
    s = _sig(S)
    out = {}
    above = np.nonzero(s >= THR)[0]
    if above.size == 0:
        out["iso_bandwidth_hz"] = np.inf
    elif above[0] == 0:
        out["iso_bandwidth_hz"] = 0.0
    else:
        k = above[0]
        x = brentq(lambda x: sig_S(x) - THR, lw[k - 1], lw[k], xtol=1e-14)
        out["iso_bandwidth_hz"] = np.exp(x) / TWO_PI
    below = np.nonzero(s < THR)[0]
    if below.size and below[-1] < len(s) - 1:
        j = below[-1]
        out["iso_bandwidth_literal_hz"] = (
            np.exp(brentq(lambda x: sig_S(x) - THR, lw[j], lw[j + 1], xtol=1e-14)) / TWO_PI
        )
    for name, grid, fn in (("t", _sig(T), sig_T), ("disk", _sig(S - T), sig_SmT)):
        k = int(np.argmax(grid))
        a, b = lw[max(k - 1, 0)], lw[min(k + 1, len(lw) - 1)]
        r = minimize_scalar(lambda x, f=fn: -f(x), bounds=(a, b), method="bounded",
                            options={"xatol": 1e-12})  # fmt: skip
        v, w = (-r.fun, np.exp(r.x)) if -r.fun > grid[k] else (grid[k], omega[k])
        if name == "t":
            out["t_peak_db"], out["t_peak_hz"] = 20 * np.log10(v), w / TWO_PI
        else:
            out["disk_margin"] = 2.0 / v
    return out
