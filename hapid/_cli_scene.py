"""The scene commands of ``hapid``: ``paper`` (the paper's figures), ``run`` (a scene file) and
``sweep`` (a batched sweep over numeric scene options). Library imports stay inside the
commands (start-up time)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ._cli_errors import CLIError
from ._cli_processes import _is_main


def cmd_paper(a):
    from . import scene  # local: CLI start-up (hapid.io, equinox)

    cfg = scene.load_scene(a.scene) if a.scene else scene.merge({})
    want = ["fig5", "fig6", "fig7", "fig8", "fig9", "fig10", "summary", "frf_file", "model_files"]
    t0 = time.perf_counter()
    run = scene.run_scene(cfg, want, out_dir=a.out, cache_dir=None if a.no_cache else a.cache,
                          progress=lambda name: print(f"  … {name}", flush=True))  # fmt: skip
    out = Path(a.out)
    print((out / "summary.md").read_text())
    print(f"computed {len(run.computed)} stages ({len(run.cached)} from cache) in "
          f"{time.perf_counter() - t0:.1f} s")  # fmt: skip
    print("per stage: " + ", ".join(f"{k} {v:.1f} s" + (" (cache)" if k in run.cached else "")
                                     for k, v in run.seconds.items()))  # fmt: skip
    print(f"figures: {', '.join(str(out / f'fig{i}.png') for i in range(5, 11))}")
    print(f"summary: {out / 'summary.md'}, {out / 'summary.json'}")


def cmd_run(a):
    from . import scene  # local: CLI start-up (hapid.io, equinox)

    cfg = scene.load_scene(a.scene)
    for kv in a.set or []:
        key, _, val = kv.partition("=")
        cfg = scene.set_option(cfg, key, _parse_value(val))
    want = a.outputs.split(",") if a.outputs else None
    t0 = time.perf_counter()
    run = scene.run_scene(cfg, want, out_dir=a.out, cache_dir=None if a.no_cache else a.cache,
                          progress=lambda name: print(f"  … {name}", flush=True))  # fmt: skip
    print(f"computed: {', '.join(run.computed) or '—'}; from cache: {', '.join(run.cached) or '—'} "
          f"({time.perf_counter() - t0:.1f} s)")  # fmt: skip
    print("per stage: " + ", ".join(f"{k} {v:.1f} s" for k, v in run.seconds.items()))
    print(f"outputs in {a.out or cfg['outputs']['dir']}")


def _parse_value(val: str):
    try:
        return json.loads(val)
    except json.JSONDecodeError:
        return val


def cmd_sweep(a):
    from . import scene, sweep  # local: CLI start-up (hapid.fit, optimistix)

    cfg = scene.load_scene(a.scene)
    vary = {}
    for item in a.vary:
        key, _, vals = item.partition("=")
        if not vals:
            raise CLIError(f"--vary needs key=v1,v2,…; got {item!r}")
        try:
            vary[key] = [float(v) for v in vals.split(",")]
        except ValueError:
            raise CLIError(f"--vary {key}: values must be numbers, got {vals!r}") from None
    t0 = time.perf_counter()
    res = sweep.run_sweep(cfg, vary, chunk=a.chunk, estimator=a.estimator)
    if not _is_main():
        return  # jax.distributed: process 0 writes the results (all processes hold them)
    out = Path(a.out)
    csv_path = sweep.write_csv(out / "sweep.csv", res)
    fig_path = sweep.plot_sweep(res, out / "sweep.png")
    bw = res.metrics["iso_bandwidth_hz"]
    print(f"{len(res)} configurations in {time.perf_counter() - t0:.1f} s; stable: {res.n_stable}; "
          f"iso-bandwidth {np.nanmin(bw):.2f}–{np.nanmax(bw):.2f} Hz"
          if res.n_stable else f"{len(res)} configurations; none stable")  # fmt: skip
    print(sweep.STAND_IN_NOTE)
    (out / "sweep_note.txt").write_text(sweep.STAND_IN_NOTE + "\n")
    print(f"table → {csv_path}; figure → {fig_path}; note → {out / 'sweep_note.txt'}")
