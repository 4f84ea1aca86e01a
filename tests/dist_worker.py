"""Worker for tests/test_distributed.py: a small robust check (and optionally a small sweep),
run as one process or as one of several joined by jax.distributed (HAPID_* variables).
Writes ``<out>.<rank>.npz``: the gathered results and the chunks this process ran."""

import sys

import numpy as np

from hapid import _distributed

_distributed.initialize()

from hapid.uncertainty import robust_check  # noqa: E402

S, N, n, CHUNK = 7, 120, 3, 2


def plants_and_controller():
    """S plants P = D(jω) (I + E) on a log grid, G = k/(1 + s/a)³ I: a spread of verdicts."""
    rng = np.random.default_rng(0)
    omega = 2 * np.pi * np.logspace(-1, 2.5, N)
    lag = 1.0 / (1.0 + 1j * omega / (2 * np.pi * 5.0))
    P = np.empty((S, N, n, n), complex)
    for s in range(S):
        E = 0.3 * rng.standard_normal((n, n))
        P[s] = lag[:, None, None] * (np.eye(n) + E)[None]
    k = np.linspace(0.5, 8.0, S)[:, None, None, None]  # g scales into P: some loops unstable
    P = P * k
    G = np.eye(n)[None] / (1.0 + 1j * omega / (2 * np.pi * 20.0))[:, None, None] ** 3
    return P, G, omega


def compute(with_sweep=False) -> dict:
    """The gathered results (the same on every process) and the chunks this process ran."""
    P, G, omega = plants_and_controller()
    rep = robust_check(P, G, omega, chunk=CHUNK, metrics="all")
    res = {f"robust_{k}": np.asarray(getattr(rep, k)) for k in ("stable", "n_closed_loop_rhp", "gm_db",
                                                                "pm_deg", "disk_margin", "iso_bandwidth_hz", "t_peak_db")}  # fmt: skip
    res["robust_chunks"] = np.asarray(_distributed.local_chunks(S, CHUNK), dtype=int)
    if with_sweep:
        from hapid import scene, sweep

        cfg = scene.merge({"analysis": {"n_freq": 60}})
        sw = sweep.run_sweep(cfg, {"controller.k": [0.5, 0.85, 1.2], "protocol.seed": [0, 1]},
                             chunk=2, progress=False)  # fmt: skip
        res |= {f"sweep_{k}": np.asarray(v) for k, v in sw.metrics.items()}
        res["sweep_rows"] = sw.params
    # a gather where process 0 has nothing: the others' rows, in rank order
    rank = _distributed.process_index()
    g = _distributed.gather([] if rank == 0 else [{"x": np.arange(3.0) + rank}])
    res["empty0_x"] = g.get("x", np.zeros(0))
    res["rank"] = np.asarray(_distributed.process_index())
    res["count"] = np.asarray(_distributed.process_count())
    return res


def main(out, with_sweep=False):
    res = compute(with_sweep)
    np.savez(f"{out}.{_distributed.process_index()}.npz", **res)


if __name__ == "__main__":
    main(sys.argv[1], with_sweep="--sweep" in sys.argv[2:])
