"""A tiny lazy stage graph with an on-disk cache keyed by a hash of each stage's inputs.

A stage is a pure function of its own options and its dependencies' results. Its key is
``sha256(name, options, dependency keys, hapid version)``, so changing one option recomputes
that stage and everything downstream of it, and nothing else. Results are pickled under
``cache_dir/<name>-<key>.pkl`` (written atomically). ``Graph.run`` computes only the stages
the requested targets need and records which stages were computed and which came from cache.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import pickle
import tempfile
from collections.abc import Callable
from pathlib import Path

VERSION = "0.1.0"


@dataclasses.dataclass(frozen=True)
class Stage:
    name: str
    deps: tuple[str, ...]
    options: Callable[[dict], dict]  # scene config → this stage's options (JSON-able)
    fn: Callable  # fn(options, *dep_results) → result
    cache: bool = True


def _canon(obj):
    if isinstance(obj, dict):
        return {str(k): _canon(v) for k, v in sorted(obj.items())}
    if isinstance(obj, list | tuple):
        return [_canon(v) for v in obj]
    if isinstance(obj, float | int | str | bool) or obj is None:
        return obj
    try:
        import numpy as np

        return _canon(np.asarray(obj).tolist())
    except Exception:  # noqa: BLE001
        return repr(obj)


def stage_key(name: str, options: dict, dep_keys: list[str]) -> str:
    blob = json.dumps([VERSION, name, _canon(options), dep_keys], sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


class Graph:
    def __init__(self, stages: list[Stage]):
        self.stages = {s.name: s for s in stages}
        for s in stages:
            for d in s.deps:
                if d not in self.stages:
                    raise ValueError(f"stage {s.name!r} depends on unknown stage {d!r}")

    def needed(self, targets) -> list[str]:
        """Stages needed for ``targets`` in dependency order."""
        order, seen = [], set()

        def visit(name):
            if name in seen:
                return
            if name not in self.stages:
                raise ValueError(f"unknown output {name!r}; known: {sorted(self.stages)}")
            seen.add(name)
            for d in self.stages[name].deps:
                visit(d)
            order.append(name)

        for t in targets:
            visit(t)
        return order

    def run(self, config: dict, targets, cache_dir=None, progress: Callable | None = None):
        """Compute ``targets``; returns ``(results, log)`` with ``log = {"computed": [...],
        "cached": [...], "keys": {...}}``."""
        results, keys = {}, {}
        log = {"computed": [], "cached": [], "keys": keys}
        cache = Path(cache_dir) if cache_dir else None
        for name in self.needed(targets):
            st = self.stages[name]
            opts = st.options(config)
            key = stage_key(name, opts, [keys[d] for d in st.deps])
            keys[name] = key
            path = cache / f"{name}-{key}.pkl" if (cache and st.cache) else None
            if path is not None and path.exists():
                try:
                    with open(path, "rb") as fh:
                        results[name] = pickle.load(fh)
                    log["cached"].append(name)
                    continue
                except Exception:  # noqa: BLE001  (stale/corrupt cache entry: recompute)
                    pass
            if progress:
                progress(name)
            results[name] = st.fn(opts, *[results[d] for d in st.deps])
            log["computed"].append(name)
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
                fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
                try:
                    with os.fdopen(fd, "wb") as fh:
                        pickle.dump(results[name], fh)
                    os.replace(tmp, path)
                except Exception:  # noqa: BLE001  (unpicklable result: just don't cache)
                    if os.path.exists(tmp):
                        os.unlink(tmp)
        return results, log
