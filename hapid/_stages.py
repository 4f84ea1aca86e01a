"""A tiny lazy stage graph with an on-disk cache keyed by each stage's inputs and hapid's source.

A stage is a pure function of its own options and its dependencies' results. Its key is
``sha256(source hash, name, options, dependency keys)``: changing one option recomputes that
stage and everything downstream of it, and nothing else; changing any ``.py`` file of the
``hapid`` package (:func:`source_hash`) invalidates every entry, so results of old code never
survive. ``Graph.run`` computes only the stages the requested targets need and records which
stages were computed, which came from the cache, and how long each took.

Values are stored without pickle, as ``cache_dir/<name>-<key>.npz``: the arrays of the result
plus one JSON string describing its structure (:func:`encode` / :func:`decode`: dicts,
lists, tuples, named tuples, dataclasses and equinox modules of ``hapid`` classes, arrays,
numbers, strings, ``None``). A result that does not fit this description is simply not cached.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib
import json
import time
from collections.abc import Callable
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from . import io

_PKG_ROOT = Path(__file__).resolve().parent


@functools.lru_cache(maxsize=1)
def source_hash() -> str:
    """sha256 of every ``.py`` file of the installed ``hapid`` package (path and bytes)."""
    h = hashlib.sha256()
    for p in sorted(_PKG_ROOT.rglob("*.py")):
        h.update(str(p.relative_to(_PKG_ROOT)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


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
        return _canon(np.asarray(obj).tolist())
    except Exception:  # noqa: BLE001
        return repr(obj)


def stage_key(name: str, options: dict, dep_keys: list[str]) -> str:
    blob = json.dumps([source_hash(), name, _canon(options), dep_keys], sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


# ---- pickle-free codec -----------------------------------------------------------------------
class Unencodable(TypeError):
    """A result the cache cannot store without pickle."""


def _is_array(x) -> bool:
    return isinstance(x, np.ndarray | np.generic) or type(x).__module__.startswith("jax")


def encode(obj) -> tuple[dict, dict]:
    """``(tree, arrays)``: a JSON-able description of ``obj`` and its arrays by name."""
    arrays: dict[str, np.ndarray] = {}

    def enc(x):
        if x is None or isinstance(x, bool | str):
            return x
        if isinstance(x, int) and not isinstance(x, bool):
            return {"int": x}
        if isinstance(x, float):
            return {"float": repr(float(x))}  # np.float64 is a float: its repr is not
        if _is_array(x):
            a = np.asarray(x)
            if a.dtype == object:
                raise Unencodable("object array")
            name = f"a{len(arrays)}"
            arrays[name] = a
            return {"array": name, "jax": not isinstance(x, np.ndarray | np.generic)}
        if isinstance(x, dict):
            if not all(isinstance(k, str) for k in x):
                raise Unencodable("dict with non-string keys")
            return {"dict": {k: enc(v) for k, v in x.items()}}
        if isinstance(x, tuple) and hasattr(x, "_fields"):
            return {"namedtuple": _cls_name(x), "items": [enc(v) for v in x]}
        if isinstance(x, list | tuple):
            return {"list" if isinstance(x, list) else "tuple": [enc(v) for v in x]}
        if dataclasses.is_dataclass(x) and not isinstance(x, type):
            fields = {f.name: enc(getattr(x, f.name)) for f in dataclasses.fields(x)}
            return {"object": _cls_name(x), "fields": fields}
        raise Unencodable(f"cannot store a {type(x).__name__} without pickle")

    return enc(obj), arrays


def _cls_name(x) -> str:
    cls = type(x)
    if not cls.__module__.startswith("hapid"):
        raise Unencodable(f"{cls.__module__}.{cls.__qualname__} is not a hapid class")
    return f"{cls.__module__}:{cls.__qualname__}"


def _cls(name: str):
    mod, _, qual = name.partition(":")
    if not (mod == "hapid" or mod.startswith("hapid.")):
        raise ValueError(f"cache entry names a non-hapid class {name!r}")
    obj = importlib.import_module(mod)
    for part in qual.split("."):
        obj = getattr(obj, part)
    return obj


def decode(tree, arrays):
    """Inverse of :func:`encode` (classes restricted to the ``hapid`` package)."""

    def dec(t):
        if t is None or isinstance(t, bool | str):
            return t
        if "int" in t:
            return int(t["int"])
        if "float" in t:
            return float(t["float"])
        if "array" in t:
            a = arrays[t["array"]]
            return jnp.asarray(a) if t["jax"] else a
        if "dict" in t:
            return {k: dec(v) for k, v in t["dict"].items()}
        if "namedtuple" in t:
            return _cls(t["namedtuple"])(*[dec(v) for v in t["items"]])
        if "list" in t:
            return [dec(v) for v in t["list"]]
        if "tuple" in t:
            return tuple(dec(v) for v in t["tuple"])
        if "object" in t:
            cls = _cls(t["object"])
            obj = object.__new__(cls)
            for k, v in t["fields"].items():
                object.__setattr__(obj, k, dec(v))
            return obj
        raise ValueError(f"bad cache tree node {sorted(t)}")

    return dec(tree)


def _load(path: Path):
    arrays, meta = io.load_cache_entry(path)
    return decode(json.loads(meta), arrays)


def _store(path: Path, result) -> bool:
    try:
        tree, arrays = encode(result)
    except Unencodable:
        return False
    io.save_cache_entry(path, arrays, json.dumps(tree))
    return True


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
        "cached": [...], "keys": {...}, "seconds": {stage: wall time}}``. ``progress(name)``
        is called before a stage is computed; ``cache_dir=None`` bypasses the cache."""
        results, keys, secs = {}, {}, {}
        log = {"computed": [], "cached": [], "keys": keys, "seconds": secs}
        cache = Path(cache_dir) if cache_dir else None
        for name in self.needed(targets):
            st = self.stages[name]
            opts = st.options(config)
            key = stage_key(name, opts, [keys[d] for d in st.deps])
            keys[name] = key
            path = cache / f"{name}-{key}.npz" if (cache and st.cache) else None
            t0 = time.perf_counter()
            if path is not None and path.exists():
                try:
                    results[name] = _load(path)
                    log["cached"].append(name)
                    secs[name] = time.perf_counter() - t0
                    continue
                except Exception:  # noqa: BLE001  (corrupt or foreign entry: recompute)
                    pass
            if progress:
                progress(name)
            results[name] = st.fn(opts, *[results[d] for d in st.deps])
            log["computed"].append(name)
            if path is not None:
                _store(path, results[name])
            secs[name] = time.perf_counter() - t0
        return results, log
