"""The stages of ``hapid design`` on :mod:`hapid._stages`' cached graph.

Stage graph (``input`` is read every time; the others are cached by their command's
arguments, the input's sha256 and hapid's source)::

    input ─► frf ─┬─► wls ─┐
                  ├─► nls ─┼─► robust (paper g on every model, loop draws on the FRF)
    input ────────┴─► ml ──┘
            frf ─► posterior ─┐
                        nls ──┴─► tune (tuned g, re-check, certificate)

Each stage runs the library code of its single command (:mod:`hapid.design._commands`) on
its dependencies' results, read back through the same files the command chain writes
(``io.save_*`` then ``io.load_*``), so every number is the single commands' to the bit.
A stage that fails (a fit that does not converge) returns ``{"error": message}`` and the
stages that need it are left out.
"""

from __future__ import annotations

import functools
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from .. import io
from .._cli_fit import FitCommandError, fit_data
from .._cli_kw import posterior_kw, robust_metrics, tune_kw
from .._cli_lab import lab_frf
from .._stages import Graph, Stage
from ..control import Compensator
from ..experiment import estimate_frf
from ..fit import FitFailedError
from ..impedance_frf import ImpedanceFRF
from ..io import load_samples, save_samples
from ..robust import loop_gp_check
from ..tune import tune_from_files
from ..tune._progress import TuneProgress
from ..uncertainty import posterior_from_files
from ._commands import FILES, DesignOptions, commands, resolve

#: a rough guide (s) to each stage's wall time on cu5 with the paper protocol and a warm JAX
#: cache, for the progress lines; measured on an idle 2-core machine (`hapid design run.npz
#: --no-cache`, 83.5 s in all): frf 0.1, wls 0.5, nls 1.1, ml 5.1, posterior 2.2, robust 28.8
#: (3 models × 1000 loop draws), tune 36 s; a cold JAX cache adds ~100 s (188.7 s in all)
EXPECTED_S = {"frf": 1.0, "wls": 2.0, "nls": 3.0, "ml": 8.0, "posterior": 5.0,
              "robust": 35.0, "tune": 50.0}  # fmt: skip
MODELS = ("wls", "nls", "ml")


def _frf_roundtrip(frf, d: Path):
    """``frf`` as the file the command writes reads back (the next command's input)."""
    if isinstance(frf, ImpedanceFRF):
        return io.load_impedance_frf(io.save_impedance_frf(d / "z.npz", frf))
    return io.load_frf(io.save_frf(d / "frf.npz", frf))


def _input(path: str, kind: str) -> dict:
    data = {"run": io.load_run, "frf": io.load_frf, "impedance_frf": io.load_impedance_frf}
    return {"kind": kind, "path": path, "data": data[kind](path) if kind in data else None}


def _frf(parse, o, inp):
    if o["argv"] is None:  # the input is the FRF
        return inp["data"]
    a = parse(resolve(o["argv"], {}, inp["path"]))
    frf = (
        estimate_frf(inp["data"], cond_warn=a.cond_warn) if inp["kind"] == "run" else lab_frf(a)[0]
    )
    with tempfile.TemporaryDirectory() as d:
        return _frf_roundtrip(frf, Path(d))


def _fit(parse, o, frf, inp):
    a = parse(resolve(o["argv"], {}, inp["path"]))
    single = isinstance(frf, ImpedanceFRF)
    if a.method == "ml":
        a.ml_run = inp["data"]
        frf = estimate_frf(a.ml_run)  # hapid fit RUN --method ml: the run's own FRF
    try:
        fitted, q, meta, _ = fit_data(frf, single, a)
    except (FitCommandError, FitFailedError) as e:
        return {"error": str(e)}
    with tempfile.TemporaryDirectory() as d:  # the model as the model file holds it
        p = Path(d) / "m.npz"
        if single:
            model = io.load_impedance_model(io.save_impedance_model(p, fitted.model, **meta))
        else:
            model = io.load_model(io.save_model(p, fitted.model, **meta))
    return {"method": str(meta.get("method", a.method)), "model": model, "meta": meta,
            "status": fitted.status, "notes": list(fitted.notes), "quality": q}  # fmt: skip


def _posterior(parse, o, frf):
    with tempfile.TemporaryDirectory() as d:
        files = {FILES["frf"]: str(Path(d) / "frf.npz"), FILES["posterior"]: str(Path(d) / "s.npz")}
        io.save_frf(files[FILES["frf"]], frf)
        a = parse(resolve(o["argv"], files, files[FILES["frf"]]))
        ps = posterior_from_files(a.frf, a.out, **posterior_kw(a))
        return {"samples": load_samples(a.out), "summary": ps.report()}


def _robust(parse, o, frf, *fits):
    """``hapid robust --frf frf.npz --model …``: the paper g's loop draws per model."""
    a = parse(o["argv"])
    out = {}
    for name, fit in zip(o["models"], fits, strict=True):
        if "error" in fit:
            continue
        rep = loop_gp_check(frf, fit["model"], Compensator.paper(), n_draws=a.max_samples,
                            gm_db=a.gm_db, pm_deg=a.pm_deg, metrics=robust_metrics(a))  # fmt: skip
        out[name] = {"report": rep, "info": rep.draws}
    return out


def _tune(parse, o, nls, post):
    if "error" in nls:
        return {"error": f"no NLS model to tune on ({nls['error']})"}
    with tempfile.TemporaryDirectory() as d:
        files = {FILES[k]: str(Path(d) / FILES[k]) for k in ("nls", "posterior", "tune")}
        io.save_model(files[FILES["nls"]], nls["model"], **nls["meta"])
        save_samples(files[FILES["posterior"]], post["samples"])
        a = parse(resolve(o["argv"], files, ""))
        bar = TuneProgress(expected_s=EXPECTED_S["tune"])  # stages, steps, objective on stderr
        try:
            res = tune_from_files(a.model, a.samples, None, **tune_kw(a), progress=bar)
        finally:
            bar.close()
    return {"g": res.g, "info": res.summary(), "decision": res.decision.reason,
            "kept_start": res.kept_start}  # fmt: skip


def _timed(name: str, fn: Callable, say: Callable[[str], None]) -> Callable:
    def run(o, *deps):
        t0 = time.perf_counter()
        say(f"{name} … (expected ≈ {EXPECTED_S.get(name, 1.0):.0f} s on cu5)")
        out = fn(o, *deps)
        say(f"{name} done in {time.perf_counter() - t0:.1f} s")
        return out

    return run


def stderr(msg: str) -> None:
    """Progress line on stderr."""
    print(f"hapid design: {msg}", file=sys.stderr, flush=True)


def plan(o: DesignOptions, skip=(), only=()) -> dict[str, list[str] | None]:
    """``{stage: argv}`` of the stages to run (``frf``: None when the input is the FRF):
    without ``skip``ped stages and those needing them; with ``only``, those and what they
    need. Raises ``ValueError`` for a stage name not in this design."""
    cmds: dict[str, list[str] | None] = {"frf": None} | commands(o)
    for s in (*skip, *only):
        if s not in cmds:
            raise ValueError(
                f"stage {s!r} is not part of this design (its stages: {', '.join(cmds)})"
            )
    keep = [s for s in cmds if s not in skip]
    if "robust" in cmds:  # the robust check runs on the models that are fitted
        argv = cmds["robust"]
        models = [m for m in MODELS if m in keep]
        cmds["robust"] = _only_models(argv, models)
        if not models and "robust" in keep:
            keep.remove("robust")
    if "tune" in keep and not {"nls", "posterior"} <= set(keep):
        keep.remove("tune")
    if only:
        keep = [s for s in keep if s in only or s in needs(only, o)]
    return {s: cmds[s] for s in keep}


def needs(stages, o: DesignOptions) -> set[str]:
    """The stages ``stages`` depend on (transitively)."""
    deps = {"frf": (), "wls": ("frf",), "nls": ("frf",), "ml": ("frf",), "posterior": ("frf",),
            "robust": ("frf",) + tuple(m for m in MODELS if m != "ml" or o.kind == "run"),
            "tune": ("nls", "posterior")}  # fmt: skip
    out: set[str] = set()
    todo = list(stages)
    while todo:
        for d in deps[todo.pop()]:
            if d not in out:
                out.add(d)
                todo.append(d)
    return out


def _only_models(argv: list[str], models: list[str]) -> list[str]:
    out, i = [], 0
    while i < len(argv):
        if argv[i] == "--model":
            if Path(argv[i + 1]).stem in models:
                out += argv[i : i + 2]
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


def build(o: DesignOptions, cmds: dict, input_path: str, sha: str, parse: Callable,
          say: Callable[[str], None] = stderr) -> Graph:  # fmt: skip
    """The stage graph of a design (``cmds``: :func:`plan`'s). ``parse(argv)`` parses a
    ``hapid`` command line; ``say`` gets the progress lines."""

    def opts(name, **extra):
        return lambda c: {"argv": cmds.get(name)} | extra

    stages = [Stage("input", (), lambda c: {"sha256": sha, "kind": o.kind},
                    lambda _o: _input(input_path, o.kind), cache=False)]  # fmt: skip
    table = {"frf": (("input",), _frf), "wls": (("frf", "input"), _fit),
             "nls": (("frf", "input"), _fit), "ml": (("frf", "input"), _fit),
             "posterior": (("frf",), _posterior), "tune": (("nls", "posterior"), _tune)}  # fmt: skip
    for name, (deps, fn) in table.items():
        if name in cmds:
            stages.append(
                Stage(name, deps, opts(name), _timed(name, functools.partial(fn, parse), say))
            )
    if "robust" in cmds:
        models = tuple(Path(t).stem for t in cmds["robust"] if t.endswith(".npz") and
                       Path(t).stem in MODELS)  # fmt: skip
        stages.append(Stage("robust", ("frf", *models), opts("robust", models=models),
                            _timed("robust", functools.partial(_robust, parse), say)))  # fmt: skip
    return Graph(stages)


def run(graph: Graph, cmds: dict, cache_dir) -> tuple[dict, dict]:
    """Compute every stage of ``cmds``: ``(results, log)`` as :meth:`hapid._stages.Graph.run`."""
    return graph.run({}, [s for s in cmds if s in graph.stages], cache_dir=cache_dir)
