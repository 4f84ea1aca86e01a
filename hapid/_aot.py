"""Ahead-of-time export cache: a jitted program traced and lowered once, reused by later processes.

The persistent XLA cache (:mod:`hapid._config`) skips only the XLA compile; a new process still
traces the Python function to a jaxpr and lowers it to StableHLO, seconds for the large loop
analysis. :func:`cached_jit` wraps a function like ``eqx.filter_jit`` and additionally stores
``jax.export.export(jit(f))(*avals)`` under ``<HAPID_JAX_CACHE>/export/``; a later process
with the same key deserializes it and calls it (``Exported.call``) without tracing ``f``.

Contract of ``cached_jit(fn)(*args)``:

* Same result as ``eqx.filter_jit(fn)(*args)``: array leaves of ``args`` (jax or numpy) are
  the program's inputs, every other leaf is static. The output is any pytree of arrays.
* Key: the function's module and qualified name, the pytree structure of ``args`` with its
  static leaves (their ``repr``), the shape/dtype/weak type of every array leaf, the jax and
  jaxlib versions and a hash of hapid's own source files. A changed source file, shape,
  dtype or static value is a different key (a miss: traced and stored anew), never a stale
  program. A module global that ``fn`` reads when traced (a run-time switch) is *not* in the
  key: pass its value as a static argument (the GP conditionals take
  :func:`hapid.uncertainty._gp.switches`), or a flipped switch reuses the old program, in
  this process and from disk in later ones.
* Falls back silently to ``eqx.filter_jit(fn)`` when the cache is off (``HAPID_JAX_CACHE=""``),
  a static leaf has no stable ``repr`` (an object address), export fails (an unsupported
  primitive, e.g. a host callback), or the folder is unwritable (then the exported program
  is still used in this process). Called on tracers (inside ``jit``/``vmap``) it calls ``fn``
  inline.
* Not differentiable: the stored program carries no VJP (``jax.grad`` through it raises).
  Use it for forward-only programs.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import pickle
import weakref
from collections.abc import Callable
from pathlib import Path

import equinox as eqx
import jax
import jaxlib
import numpy as np
from jax import export

from . import _config
from ._atomic import atomic_write

SUBDIR = "export"
"""Sub-folder of the persistent cache that holds the exported programs."""
_VERSION = 1  # bump when the stored record's layout changes
_SRC = Path(__file__).resolve().parent
_WRAPPERS: weakref.WeakSet = weakref.WeakSet()  # live cached_jit wrappers (clear_programs)


@functools.cache
def source_hash() -> str:
    """SHA-256 of every ``.py`` file of the hapid package (paths and contents, sorted)."""
    h = hashlib.sha256()
    for p in sorted(_SRC.rglob("*.py")):
        h.update(str(p.relative_to(_SRC)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def export_dir() -> Path | None:
    """``<HAPID_JAX_CACHE>/export`` (``None`` when caching is switched off)."""
    base = _config.jax_cache_dir()
    return Path(base) / SUBDIR if base else None


def _aval(x) -> tuple:
    weak = bool(getattr(x, "weak_type", False))
    return (tuple(np.shape(x)), str(np.dtype(x.dtype)), weak)


def cache_key(fn: Callable, args: tuple) -> str | None:
    """The key text of ``fn(*args)`` (module docstring), or ``None`` when a static leaf has
    no stable ``repr``."""
    dyn, static = eqx.partition(args, eqx.is_array)
    leaves, treedef = jax.tree.flatten(static)
    text = "\n".join(
        [
            f"v{_VERSION} jax {jax.__version__} jaxlib {jaxlib.__version__} src {source_hash()}",
            f"{fn.__module__}.{fn.__qualname__}",
            repr(treedef),
            repr(leaves),
            repr(jax.tree.structure(dyn)),
            repr([_aval(x) for x in jax.tree.leaves(dyn)]),
        ]
    )
    if " at 0x" in text:
        return None
    return hashlib.sha256(text.encode()).hexdigest()


@dataclasses.dataclass
class _Program:
    call: Callable  # flat array inputs -> flat outputs
    skeleton: object  # the output pytree with leaf i replaced by the int i


def _unflatten(skeleton, outs):
    idx, treedef = jax.tree.flatten(skeleton)
    return jax.tree.unflatten(treedef, [outs[i] for i in idx])


def _load(path: Path) -> _Program | None:
    try:
        rec = pickle.loads(path.read_bytes())
        exp = rec["exported"]
        return _Program(jax.jit(exp.call), rec["skeleton"])
    except Exception:  # noqa: BLE001  (missing, truncated or incompatible: a miss)
        return None


def _save(path: Path, exp, skeleton) -> None:
    try:
        data = pickle.dumps({"exported": exp, "skeleton": skeleton})
        atomic_write(path, lambda fh: fh.write(data))
    except Exception:  # noqa: BLE001  (unwritable cache: run from memory)
        return


def _export(fn: Callable, args: tuple, name: str) -> tuple[object, object]:
    """``(Exported of fn on args' avals with flat array inputs/outputs, output skeleton)``."""
    dyn, static = eqx.partition(args, eqx.is_array)
    leaves, tree = jax.tree.flatten(dyn)
    box = {}

    def flat(xs):
        out = fn(*eqx.combine(jax.tree.unflatten(tree, xs), static))
        outs, out_tree = jax.tree.flatten(out)
        box["skeleton"] = jax.tree.unflatten(out_tree, list(range(len(outs))))
        return outs

    flat.__name__ = name
    exp = export.export(jax.jit(flat))(leaves)
    # the stored record holds no Python closure (jax.export's VJP rule): forward only
    exp = dataclasses.replace(exp, _get_vjp=None)
    pickle.dumps(box["skeleton"])  # raises here, not at the save, if it cannot be stored
    return exp, box["skeleton"]


def _local_key(static, dyn_tree, leaves) -> tuple | None:
    """An in-process key of a call: the pytree structures, the static leaves (with their
    types) and every array leaf's shape/dtype/weak type — hashable and cheap, unlike
    :func:`cache_key` (``repr`` and SHA-256 of the same), which a batch of calls with the
    same structure would otherwise pay per call. ``None`` when a static leaf is unhashable."""
    s_leaves, s_tree = jax.tree.flatten(static)
    key = (s_tree, dyn_tree, tuple((type(x), x) for x in s_leaves), tuple(map(_aval, leaves)))
    try:
        hash(key)
    except TypeError:
        return None
    return key


def cached_jit(fn: Callable, name: str | None = None) -> Callable:
    """``fn`` jit-compiled through the export cache (module docstring: the contract)."""
    name = name or fn.__name__
    plain = eqx.filter_jit(fn)
    memo: dict[str, _Program | None] = {}
    local: dict[tuple, _Program | None] = {}  # _local_key → the program of memo

    @functools.wraps(fn)
    def wrapper(*args):
        if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(args)):
            return fn(*args)
        folder = export_dir()
        if folder is None:
            return plain(*args)
        dyn, static = eqx.partition(args, eqx.is_array)
        leaves, dyn_tree = jax.tree.flatten(dyn)
        lkey = _local_key(static, dyn_tree, leaves)
        prog = local.get(lkey, False) if lkey is not None else False
        if prog is False:
            key = cache_key(fn, args)
            if key is None:
                return plain(*args)
            prog = memo.get(key, False)
            if prog is False:
                path = folder / f"{name}-{key[:40]}.pkl"
                prog = _load(path)
                if prog is None:
                    try:
                        exp, skeleton = _export(fn, args, name)
                    except Exception:  # noqa: BLE001  (not exportable: ordinary jit)
                        prog = None
                    else:
                        _save(path, exp, skeleton)
                        prog = _Program(jax.jit(exp.call), skeleton)
                memo[key] = prog
            if lkey is not None:
                local[lkey] = prog
        if prog is None:
            return plain(*args)
        return _unflatten(prog.skeleton, prog.call(leaves))

    wrapper.plain = plain
    wrapper.programs = memo  # the programs held in this process, by key (clear_programs)
    wrapper.clear = lambda: (memo.clear(), local.clear())
    _WRAPPERS.add(wrapper)
    return wrapper


def mapping_count() -> int:
    """The memory mappings this process holds (lines of ``/proc/self/maps``; 0 where there is
    no such file, i.e. not Linux): what :func:`clear_programs` brings down."""
    try:
        with open("/proc/self/maps") as fh:
            return sum(1 for _ in fh)
    except OSError:
        return 0


def clear_programs() -> None:
    """Drop every compiled program this process holds: :func:`cached_jit`'s tables and JAX's
    own caches (``jax.clear_caches``). Later calls reload them from the persistent caches.

    Each live XLA:CPU executable keeps its machine code in memory mappings of its own, and
    Linux allows a process ``vm.max_map_count`` of them (65 530 by default): a process that
    compiles thousands of distinct programs — a test session, a long notebook — crashes
    with a segmentation fault in the compiler once it reaches that number."""
    for wrapper in list(_WRAPPERS):
        wrapper.clear()
    jax.clear_caches()
