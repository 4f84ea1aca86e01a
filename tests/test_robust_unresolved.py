"""A robust check whose failure rests on loops the frequency grid does not resolve is
"not established", never "failed" or "passed"; a denser grid resolves it."""

import numpy as np

from hapid.uncertainty import RobustReport, robust_check
from hapid.verdict import Verdict


def _report(stable, resolved, gm=9.0, pm=45.0):
    S = len(stable)
    nan = np.full(S, np.nan)
    return RobustReport(stable=np.asarray(stable, bool), n_closed_loop_rhp=np.zeros(S),
                        gm_db=np.full(S, gm), pm_deg=np.full(S, pm), disk_margin=nan,
                        disk_gm_db=nan, disk_pm_deg=nan, iso_bandwidth_hz=np.full(S, 5.0),
                        t_peak_db=nan, computed=("gm_db", "pm_deg", "iso_bandwidth_hz"),
                        nyquist_resolved=None if resolved is None else np.asarray(resolved, bool))  # fmt: skip


def test_failure_through_unresolved_plants_only_is_not_established():
    S = 20
    stable = np.ones(S, bool)
    stable[:3] = False  # P(stable) 0.85 < 0.95
    unres = np.zeros(S, bool)
    unres[:3] = True  # … and all three are loops the grid did not resolve
    ck = _report(stable, ~unres).check
    assert ck.verdict is Verdict.NOT_ESTABLISHED
    assert "3 of 20 plants" in ck.reason and "--n-freq" in ck.remedy
    # the same plants, resolved and unstable: failed
    assert _report(stable, np.ones(S, bool)).check.verdict is Verdict.FAILED
    assert _report(stable, None).check.verdict is Verdict.FAILED  # not recorded: as before
    # unresolved plants that could not change the outcome: still failed
    stable2 = stable.copy()
    stable2[3:6] = False  # three more, resolved and unstable: fails even if the first pass
    assert _report(stable2, ~unres).check.verdict is Verdict.FAILED
    # a margin failure on resolved plants stays failed whatever the unresolved ones do
    assert _report(stable, ~unres, pm=20.0).check.verdict is Verdict.FAILED
    # and a passing report is untouched by the field
    assert _report(np.ones(S, bool), np.ones(S, bool)).check.verdict is Verdict.PASSED


def _resonant_plants(omega, zetas, k=0.2):
    """2×2 diagonal plants k ω₀²/(s² + 2ζω₀s + ω₀²) at 10 Hz: with G = I the closed loop is
    stable for every ζ > 0 (characteristic polynomial s² + 2ζω₀s + (1 + k)ω₀²), but a lightly
    damped mode swings the phase of 1 + L by nearly 180° within ≈ 2ζω₀ rad/s."""
    w0 = 2 * np.pi * 10.0
    s = 1j * omega
    P = []
    for z in zetas:
        p = k * w0**2 / (s**2 + 2 * z * w0 * s + w0**2)
        P.append(np.einsum("w,ij->wij", p, np.eye(2)))
    return np.stack(P)


def test_a_coarse_grid_leaves_a_sharp_mode_unresolved_and_a_dense_one_resolves_it():
    zetas = [0.3] * 17 + [3e-3] * 3  # three sharp modes among twenty plants
    # one grid size (one compiled program): evenly log-spaced, or the same count of points
    # crowded around the 10 Hz modes
    N = 600
    coarse = 2 * np.pi * np.geomspace(0.1, 100.0, N)
    dense = 2 * np.pi * np.concatenate([np.geomspace(0.1, 8.9, N // 4), np.geomspace(9.0, 11.0, N // 2),
                                        np.geomspace(11.1, 100.0, N // 4)])  # fmt: skip
    req = dict(gm_db=0.0, pm_deg=0.0)
    rc = robust_check(_resonant_plants(coarse, zetas), np.broadcast_to(np.eye(2), (N, 2, 2)),
                      coarse, **req)  # fmt: skip
    assert not rc.nyquist_resolved[-3:].any() and rc.nyquist_resolved[:17].all()
    assert rc.check.verdict is Verdict.NOT_ESTABLISHED
    rd = robust_check(_resonant_plants(dense, zetas), np.broadcast_to(np.eye(2), (N, 2, 2)),
                      dense, **req)  # fmt: skip
    assert rd.nyquist_resolved.all() and rd.stable.all()  # the closed form: all stable
    assert rd.check.verdict is Verdict.PASSED
