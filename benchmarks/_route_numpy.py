"""bench_route's robust check over parameter draws vs a plain numpy loop, in one process.

Run by :mod:`bench_route` with a tree on ``PYTHONPATH``: ``python _route_numpy.py S``. Prints
one JSON line: ``t_hapid`` (warm :func:`hapid.uncertainty.robust_check`, default
spec, after a first call on the same arrays), ``t_numpy`` (the numpy per-draw loop of
bench_fast: det, inv, eigvals, two SVDs per draw), ``same`` (draws whose verdict equals the
LAPACK reference, :func:`bench_fast.reference_robust`: ``analyze_loop`` on every draw).
"""

import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fast import _numpy_robust, _setup, reference_robust  # noqa: E402


def main(S: int) -> dict:
    from hapid.control import Compensator, controller_unstable_poles, inverse_model_response
    from hapid.uncertainty import laplace_samples, posterior_omega, robust_check

    nls = _setup()
    g = Compensator.paper()
    omega = posterior_omega(1000)
    w = jnp.asarray(omega)
    G = inverse_model_response(nls.model, g, w)
    c_rhp = int(controller_unstable_poles(nls.model, g))
    models = laplace_samples(nls, S, key=0).models(np.arange(S))
    Ps = jax.jit(jax.vmap(lambda mm: mm.P(1j * w)))(models)
    robust_check(Ps, G, omega, controller_rhp=c_rhp)  # compile (or cache load)
    t = time.perf_counter()
    rep = robust_check(Ps, G, omega, controller_rhp=c_rhp)
    t_hapid = time.perf_counter() - t
    Pn, Gn = np.asarray(Ps), np.asarray(G)
    t = time.perf_counter()
    _numpy_robust(Pn, Gn)
    t_numpy = time.perf_counter() - t
    ref = reference_robust(Ps, G, w, c_rhp)
    same = int(np.sum(np.asarray(ref.stable) == np.asarray(rep.stable)))
    return {"t_hapid": t_hapid, "t_numpy": t_numpy, "same": same}


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]))))
