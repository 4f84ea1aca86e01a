"""Compile time, cold against warm, of the main jitted entry points and the paper pipeline.

    python benchmarks/bench_compile.py [--quick] [--out out/bench]

Each measurement runs in a fresh Python process (``--worker``) whose JAX persistent
compilation cache is a fresh empty folder (``HAPID_JAX_CACHE=<tmpdir>``): **cold** is the
first process on the empty cache, **warm** a second process on the cache the first one
filled. In each process every entry point is called twice on the same shapes: first call
(trace + compile or cache load + run) and second call (run only). Entry points, in
pipeline order, on cu5 with the paper protocol:

- ``periodic_run + estimate_frf`` (simulate the multisine experiments → FRF),
- ``simulate_frf`` under ``eqx.filter_jit`` (the pure-JAX device → FRF path of sweeps),
- ``wls`` (+ ``positize``), ``fit_nls`` (LM, relative weights),
- ``loop_metrics`` with ``hapid.pipeline.SPEC_REPORT`` (the one-loop spec of ``hapid analyze``
  and the paper summary) on the 1500-point analysis grid with the inverse-model controller of
  the NLS model.

Then the whole paper reproduction (``hapid paper``), cold and warm, as ``bench_paper.py``
measures it (full run only; ``--quick`` skips it). Note: hapid writes to the persistent
cache only compilations that took ≥ 0.5 s (``hapid/_config.py``).

Where the compile time of the loop program goes (``--ir N``, a separate mode): every function
of ``hapid.control._kernels`` and ``_metrics`` is wrapped in a ``jax.named_scope`` (in this
process only), ``loop_metrics`` (default spec, N = 1000) on the n-rod preset loop of
``bench_n.py`` is compiled with ``XLA_FLAGS=--xla_dump_to`` in a subprocess, and the
optimized LLVM IR of its kernels (XLA:CPU compile time is mostly LLVM, roughly in
proportion to it) is summed by the innermost two scopes of each kernel's ``op_name``:

    HAPID_JAX_CACHE= PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_compile.py --ir 5
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Section, fs, standalone, table  # noqa: E402


def _worker():
    t0 = time.perf_counter()
    import equinox as eqx
    import jax
    import numpy as np

    import hapid  # noqa: F401
    from hapid.control import Compensator, inverse_model_response, loop_metrics
    from hapid.device import cu5
    from hapid.experiment import Protocol, estimate_frf, periodic_run, simulate_frf
    from hapid.fit import fit_nls, positize, wls
    from hapid.pipeline import SPEC_REPORT

    t_import = time.perf_counter() - t0
    res = {"import": t_import}

    def twice(name, fn):
        t = time.perf_counter()
        out = jax.block_until_ready(fn())
        first = time.perf_counter() - t
        t = time.perf_counter()
        out = jax.block_until_ready(fn())
        res[name] = (first, time.perf_counter() - t)
        return out

    dev, prot = cu5(), Protocol()
    frf = twice(
        "periodic_run + estimate_frf", lambda: estimate_frf(periodic_run(dev, prot, noise_seed=0))
    )
    sim = eqx.filter_jit(lambda d, k: simulate_frf(d, prot, k))
    twice("simulate_frf (filter_jit)", lambda: sim(dev, jax.random.PRNGKey(0)))
    twice("wls + positize", lambda: positize(wls(frf)))
    nls = twice("fit_nls (lm)", lambda: fit_nls(frf))
    f = np.geomspace(1e-3, 0.49999 * dev.fs_hz, 1499)
    omega = 2 * np.pi * np.append(f, 0.5 * dev.fs_hz)
    P = np.asarray(dev.sampled_P(omega))
    G = np.asarray(inverse_model_response(nls.model, Compensator.paper(), omega))
    twice("loop_metrics (SPEC_REPORT, 1500 freqs)",
          lambda: loop_metrics(P, G, omega, spec=SPEC_REPORT).stable)  # fmt: skip
    res["total"] = time.perf_counter() - t0
    print("RESULT " + json.dumps(res))


def _run_worker(cache_dir):
    env = dict(os.environ, HAPID_JAX_CACHE=cache_dir)
    t = time.perf_counter()
    p = subprocess.run(
        [sys.executable, __file__, "--worker"], env=env, capture_output=True, text=True
    )
    wall = time.perf_counter() - t
    if p.returncode != 0:
        raise RuntimeError(p.stderr[-3000:])
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    out = json.loads(line[7:])
    out["process wall"] = wall
    return out


def _paper(out, cache, jax_cache):
    env = dict(os.environ, HAPID_JAX_CACHE=jax_cache)
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "hapid.cli", "paper", "--out", out, "--cache", cache],
                       env=env, capture_output=True, text=True)  # fmt: skip
    if p.returncode != 0:
        raise RuntimeError(p.stderr[-3000:])
    return time.perf_counter() - t


def paper_cold_warm(sec: Section, cache_only: bool = False):
    with tempfile.TemporaryDirectory() as d:
        out, cache, jc = (str(Path(d) / x) for x in ("out", "stages", "jax"))
        cold = _paper(out, cache, jc)
        warm = _paper(out, cache, jc)
        cc = float("nan")
        if cache_only:
            subprocess.run(["rm", "-rf", cache], check=True)
            cc = _paper(out, cache, jc)
    sec.add("### Paper reproduction (`hapid paper`, whole command incl. interpreter start)\n\n" + table([
        {"run": "cold (empty compile cache, empty stage cache)", "time": fs(cold), "goal": "< 120 s"},
        {"run": "warm (both caches filled)", "time": fs(warm), "goal": "< 20 s"},
    ] + ([{"run": "compile cache only (stages recomputed)", "time": fs(cc), "goal": "—"}]
         if cache_only else [])) + f"\n\ncold / warm = {cold / warm:.1f}×")  # fmt: skip
    sec.goal("paper reproduction cold < 120 s", fs(cold), cold < 120)
    sec.goal("paper reproduction warm < 20 s", fs(warm), warm < 20)
    sec.rows["paper"] = {"cold": cold, "warm": warm, "compile_cache_only": cc}


def run(quick: bool = False, out: str = "out/bench") -> Section:
    sec = Section("Compile time: cold vs warm")
    with tempfile.TemporaryDirectory() as d:
        cold = _run_worker(d)
        warm = _run_worker(d)
        n_files = sum(1 for _ in Path(d).rglob("*") if _.is_file())
    rows = []
    for name in cold:
        if name in ("import", "total", "process wall"):
            continue
        (cf, cr), (wf, wr) = cold[name], warm[name]
        rows.append({"entry point": name, "cold first call": fs(cf), "warm first call": fs(wf),
                     "run (2nd call)": fs(min(cr, wr)), "cold compile ≈": fs(max(cf - cr, 0)),
                     "warm compile ≈": fs(max(wf - wr, 0)), "cold/warm first": f"{cf / wf:.1f}×"})  # fmt: skip
    for name in ("import", "total", "process wall"):
        rows.append({"entry point": f"**{name}**", "cold first call": fs(cold[name]),
                     "warm first call": fs(warm[name]), "run (2nd call)": "", "cold compile ≈": "",
                     "warm compile ≈": "", "cold/warm first": f"{cold[name] / warm[name]:.1f}×"})  # fmt: skip
    sec.add(f"### Main entry points (fresh process each; persistent cache: {n_files} files after the "
            "cold run)\n\n" + table(rows) + "\n\n'import' is `import hapid` + submodules; 'total' "
            "the worker's own clock, 'process wall' includes interpreter start. Entry points that run "
            "eagerly (`periodic_run`, `wls`, `positize` are not jitted as a whole) compile one small "
            "XLA program per operation; each takes < 0.5 s, under hapid's persistent-cache threshold "
            "(`hapid/_config.py`), so they are compiled again in every process: where 'warm first "
            "call' ≈ 'cold first call', that is why.")  # fmt: skip
    sec.rows["entry"] = {"cold": cold, "warm": warm}
    if quick:
        sec.add("(paper cold/warm skipped with --quick; run `python benchmarks/bench_compile.py`)")
    else:
        paper_cold_warm(sec)
    return sec


def _ir_worker(n: int):
    """Compile loop_metrics on the n-rod loop with every kernel/metrics function scoped."""
    import functools
    import inspect

    import jax
    import jax.numpy as jnp
    import numpy as np

    import hapid  # noqa: F401
    from hapid.control import _kernels, _metrics

    for mod in (_kernels, _metrics):
        for name, f in list(vars(mod).items()):
            if inspect.isfunction(f) and f.__module__ == mod.__name__:

                @functools.wraps(f)
                def g(*a, _f=f, _n=name, **k):
                    with jax.named_scope("S_" + _n):
                        return _f(*a, **k)

                setattr(mod, name, g)
    from bench_n import _device_loop

    from hapid.uncertainty import posterior_omega

    omega = np.asarray(posterior_omega(1000))
    P, G, p_ol, _ = _device_loop(n, omega)
    w = jnp.asarray(omega)
    f = jax.jit(lambda P, G: _metrics.loop_metrics(P, G, w, p_ol=p_ol))
    f.lower(jnp.asarray(P), jnp.asarray(G)).compile()


def ir_attribution(n: int) -> str:
    """Table: optimized LLVM IR (kB) and kernel count of loop_metrics by function scope."""
    import collections
    import re

    with tempfile.TemporaryDirectory() as d:
        env = dict(os.environ, HAPID_JAX_CACHE="", XLA_FLAGS=f"--xla_dump_to={d} --xla_dump_hlo_module_re=.*lambda.*")  # fmt: skip
        subprocess.run([sys.executable, __file__, "--ir-worker", str(n)], env=env, check=True)
        mod = sorted(
            {m.group(1) for f in os.listdir(d) if (m := re.match(r"(module_\d+\.jit__lambda)", f))}
        )[-1]
        scope = {}
        for line in (Path(d) / f"{mod}.cpu_after_optimizations.txt").read_text().splitlines():
            m = re.match(r"\s*(?:ROOT )?%?([\w.\-]+) = .* fusion\(", line)
            if m:
                on = re.search(r'op_name="([^"]+)"', line)
                sc = re.findall(r"S_(\w+)", on.group(1)) if on else []
                scope[m.group(1)] = "/".join(sc[-2:]) or "(unscoped)"
        size, count, total = collections.Counter(), collections.Counter(), 0
        for f in Path(d).glob(f"{mod}.*ir-with-opt.ll"):
            k = re.search(r"jit__lambda\.(.*?)(?:_kernel_module)?\.ir-with-opt", f.name).group(1)
            b = f.stat().st_size
            total += b
            size[scope.get(k, "(unscoped)")] += b
            count[scope.get(k, "(unscoped)")] += 1
    rows = [{"scope (outer/inner)": k, "IR kB": f"{v / 1e3:.0f}", "share": f"{v / total:.0%}",
             "kernels": count[k]} for k, v in size.most_common(20)]  # fmt: skip
    head = f"loop_metrics, n = {n}, N = 1000: {total / 1e6:.1f} MB optimized LLVM IR"
    return head + "\n" + table(rows)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if "--ir-worker" in argv:
        return _ir_worker(int(argv[argv.index("--ir-worker") + 1]))
    if "--ir" in argv:
        print(ir_attribution(int(argv[argv.index("--ir") + 1])))
        return None
    if "--worker" in argv:
        return _worker()
    return standalone(run, __doc__, argv)


if __name__ == "__main__":
    main()
