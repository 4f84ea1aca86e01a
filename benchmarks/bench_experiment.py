"""Simulate → FRF for the paper's protocol (28 frequencies, 5 experiments, 1 kHz, 4 periods):
hapid against a plain numpy/scipy implementation of the same steps, side by side.

    python benchmarks/bench_experiment.py [--quick] [--out out/bench]

Rows: hapid's exact periodic synthesis (frequency domain) and its lax.scan time-domain
simulation, against numpy/scipy doing what a user would write — ZOH discretization with
scipy.linalg.expm, a per-sample state-space loop (scipy.signal.dlsim) — and the FRF step
(hapid's vectorized estimate vs a per-frequency numpy loop with np.linalg.solve).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.signal

sys.path.insert(0, str(Path(__file__).parent))
from _common import Section, fs, standalone, table, timeit  # noqa: E402

import hapid  # noqa: E402,F401
from hapid.device import cu5  # noqa: E402
from hapid.experiment import Protocol, estimate_frf, periodic_run, time_domain_run  # noqa: E402


def numpy_simulate(dev, prot):
    ss = dev.state_space()
    A, B, C, D = (np.asarray(x) for x in (ss.A, ss.B, ss.C, ss.D))
    ts = 1.0 / prot.fs_hz
    nx, nu = B.shape
    M = scipy.linalg.expm(np.block([[A, B], [np.zeros((nu, nx + nu))]]) * ts)
    Ad, Bd = M[:nx, :nx], M[:nx, nx:]
    U = prot.pattern_matrix(dev.n)
    r = np.asarray(prot.excitation().period())
    total = (prot.transient_periods + prot.n_periods) * prot.period_samples
    out = []
    for e in range(U.shape[0]):
        cmd = np.tile(r, total // prot.period_samples)[:, None] * U[e][None, :]
        applied = np.roll(cmd, dev.delay_samples, axis=0)
        _, y, _ = scipy.signal.dlsim((Ad, Bd, C, D, ts), applied)
        out.append((cmd, y))
    return out


def numpy_frf(sim, prot, n):
    Tp, P = prot.period_samples, prot.n_periods
    bins = np.round(np.asarray(prot.freq_hz) * Tp / prot.fs_hz).astype(int)
    keep = slice(prot.transient_periods * Tp, None)
    Z_H = np.zeros((len(bins), n, n), complex)
    Z_T = np.zeros_like(Z_H)
    for k, b in enumerate(bins):
        Lm = np.zeros((n, len(sim)), complex)
        RI = np.zeros_like(Lm)
        RA = np.zeros_like(Lm)
        for e, (cmd, y) in enumerate(sim):
            avg = lambda x: x[keep].reshape(P, Tp, -1).mean(0)  # noqa: E731
            ph = np.exp(-2j * np.pi * b * np.arange(Tp) / Tp) * 2 / Tp
            Lm[:, e] = ph @ avg(y[:, :n])
            RI[:, e] = ph @ avg(y[:, n:])
            RA[:, e] = ph @ avg(cmd)
        Z_H[k] = -RI @ np.linalg.inv(Lm)
        Z_T[k] = -RA @ np.linalg.inv(Lm)
    return Z_H, Z_T


def run(quick: bool = False, out: str = "out/bench", periods: int = 4) -> Section:
    sec = Section("Simulate → FRF: frequency domain, time domain (lax.scan), numpy/scipy")
    dev = cu5()
    prot = Protocol(n_periods=periods).noiseless()
    ref = estimate_frf(periodic_run(dev, prot))
    Zs = dev.sampled_impedances(ref.omega)

    def err(Z_H):
        return float(
            np.max(np.abs(np.asarray(Z_H) - np.asarray(Zs[0]))) / np.max(np.abs(np.asarray(Zs[0])))
        )

    r = 1 if quick else 3
    sim = numpy_simulate(dev, prot)
    estimate_frf(time_domain_run(dev, prot))  # warm-up (compile of the scan)
    rows = []
    t_per = timeit(lambda: estimate_frf(periodic_run(dev, prot)), repeat=r + 2)
    t_td = timeit(lambda: estimate_frf(time_domain_run(dev, prot)), repeat=r)
    t_np_sim = timeit(lambda: numpy_simulate(dev, prot), repeat=r)
    t_np_frf = timeit(lambda: numpy_frf(sim, prot, dev.n), repeat=r)
    run_td = time_domain_run(dev, prot)
    t_frf = timeit(lambda: estimate_frf(run_td), repeat=r + 2)
    e_np = err(numpy_frf(sim, prot, dev.n)[0])
    rows.append({"pipeline": "hapid periodic steady state + FRF", "time": fs(t_per),
                 "numpy ÷ hapid": f"{(t_np_sim + t_np_frf) / t_per:.1f}×", "rel. error Z_H": f"{err(ref.Z_H):.1e}"})  # fmt: skip
    rows.append({"pipeline": "hapid time domain (lax.scan) + FRF", "time": fs(t_td),
                 "numpy ÷ hapid": f"{(t_np_sim + t_np_frf) / t_td:.1f}×",
                 "rel. error Z_H": f"{err(estimate_frf(run_td).Z_H):.1e}"})  # fmt: skip
    rows.append({"pipeline": "numpy/scipy dlsim + per-frequency FRF", "time": fs(t_np_sim + t_np_frf),
                 "numpy ÷ hapid": "1.0×", "rel. error Z_H": f"{e_np:.1e}"})  # fmt: skip
    rows.append({"pipeline": "FRF step only: hapid", "time": fs(t_frf),
                 "numpy ÷ hapid": f"{t_np_frf / t_frf:.1f}×", "rel. error Z_H": "—"})  # fmt: skip
    rows.append({"pipeline": "FRF step only: numpy loop", "time": fs(t_np_frf),
                 "numpy ÷ hapid": "1.0×", "rel. error Z_H": "—"})  # fmt: skip
    sec.add(f"cu5, paper protocol, {periods} periods (+1 transient), noiseless.\n\n" + table(rows) + "\n\n"
            "numpy/scipy starts from rest as a user would: its error is the undecayed transient (cu5's "
            "slowest pole ≈ −0.24 rad/s); hapid starts from the exact periodic steady state "
            "(the time-domain run from the same state). Best of several runs after a warm-up.")  # fmt: skip
    return sec


def main(argv=None):
    return standalone(run, __doc__, argv)


if __name__ == "__main__":
    main()
