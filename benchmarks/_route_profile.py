"""bench_route's per-command profile: import, compile, compute, I/O of one CLI command.

``python _route_profile.py ARGS…`` (a tree on ``PYTHONPATH``) times ``import hapid.cli``,
then runs ``hapid.cli.main(ARGS)`` twice in the same process and prints one JSON line:

* ``import``: ``import hapid.cli`` (JAX included);
* ``first`` / ``second``: the two calls; ``first − second`` is what compiling costs the
  first call of a process (tracing, lowering, XLA compile or persistent-cache load);
* ``xla`` / ``cache_load``: of the first call, the time in JAX's compile-or-load step (XLA
  compiles *and* persistent-cache loads) and of it the cache loads (JAX's own monitoring
  events); tracing, lowering and op-by-op dispatch are the rest of ``first − second``;
* ``io``: time inside :mod:`hapid.io`'s load/save functions in the second call;
  ``second − io`` is the compute.

:func:`profile_rows` runs it for every command of the route (for :mod:`bench_route`).
"""

from __future__ import annotations

import contextlib
import io as _io
import json
import os
import subprocess
import sys
import time
from pathlib import Path


def _profile(argv: list[str]) -> dict:
    t = time.perf_counter()
    import hapid.cli as cli  # noqa: PLC0415  (what is timed)

    t_import = time.perf_counter() - t
    import jax

    from hapid import io

    acc = {"io": 0.0, "xla": 0.0, "cache_load": 0.0}

    def listener(event, duration, **_):
        if event == "/jax/core/compile/backend_compile_duration":
            acc["xla"] += duration
        elif event == "/jax/compilation_cache/cache_retrieval_time_sec":
            acc["cache_load"] += duration

    jax.monitoring.register_event_duration_secs_listener(listener)
    for name in dir(io):
        f = getattr(io, name)
        if callable(f) and name.startswith(("load", "save", "read", "write")):

            def timed(*a, _f=f, **k):
                t0 = time.perf_counter()
                try:
                    return _f(*a, **k)
                finally:
                    acc["io"] += time.perf_counter() - t0

            setattr(io, name, timed)
    out = {"import": t_import}
    for call in ("first", "second"):
        if call == "second":
            xla, load = acc["xla"], acc["cache_load"]
            acc["io"] = 0.0
        t = time.perf_counter()
        with contextlib.redirect_stdout(_io.StringIO()):
            rc = cli.main(argv)
        out[call] = time.perf_counter() - t
        out[f"rc_{call}"] = rc
    out.update(io=acc["io"], xla=xla, cache_load=load)
    return out


def profile_rows(tree: Path, routes: dict, cache: Path) -> list[dict]:
    """One row per command: the profile of :func:`_profile` (warm persistent cache: each
    command runs once before, unmeasured, to fill it)."""
    rows = []
    env = dict(os.environ, PYTHONPATH=str(tree), HAPID_JAX_CACHE=str(cache))
    for name, args in routes.items():
        subprocess.run([sys.executable, "-m", "hapid", *args], cwd=tree, env=env,
                       capture_output=True, timeout=3600)  # fmt: skip
        p = subprocess.run([sys.executable, __file__, *args], cwd=tree, env=env, text=True,
                           capture_output=True, timeout=7200)  # fmt: skip
        try:
            r = json.loads(p.stdout.strip().splitlines()[-1])
        except (IndexError, json.JSONDecodeError):
            rows.append({"command": name, "error": (p.stderr or p.stdout).strip()[-300:]})
            continue
        compile_s = r["first"] - r["second"]
        rows.append({"command": name, "import (s)": f"{r['import']:.2f}",
                     "compile: first − second call (s)": f"{compile_s:.2f}",
                     "of it XLA compile (s)": f"{r['xla'] - r['cache_load']:.2f}",
                     "of it cache load (s)": f"{r['cache_load']:.2f}",
                     "of it tracing, lowering, dispatch (s)": f"{compile_s - r['xla']:.2f}",
                     "compute (s)": f"{r['second'] - r['io']:.2f}", "I/O (s)": f"{r['io']:.2f}",
                     "whole first call + import (s)": f"{r['import'] + r['first']:.2f}"})  # fmt: skip
    return rows


if __name__ == "__main__":
    print(json.dumps(_profile(sys.argv[1:])))
