"""Global JAX configuration applied on ``import hapid``.

float64 is switched on before any array is created: the s² terms of an impedance at 100 Hz
are ~4·10⁵ times the constant terms, and float32 loses the fit (docs/conventions.md, "Arrays, units, precision").
"""

import os

# XLA:CPU (jaxlib 0.10.2) deadlocks when it schedules batched LAPACK kernels concurrently
# (measured: SVD ∥ LU, LU ∥ eig — all threads idle, every time). The concurrency-optimized
# scheduler is what runs them side by side; switching it off removed the hang in every case
# we reproduced. It only takes effect if set before the CPU backend starts, i.e. when hapid
# is imported before any JAX computation; hapid's own kernels avoid the pattern regardless
# (``hapid._linalg``, ``hapid.control._lapack``).
_FLAG = "--xla_cpu_enable_concurrency_optimized_scheduler=false"
if _FLAG.split("=")[0] not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _FLAG).strip()

# The scheduler flag does not remove every case: a batched sweep (`hapid sweep`, 256
# configurations of the paper scene) still hung on 2 cores, two XLA worker threads each in a
# batched LAPACK kernel (LU ∥ triangular solve, triangular solve ∥ eig) waiting in
# `jax::ParallelBatchMap` for work that only the other, equally blocked, worker could run.
# The hang needs every thread of XLA's pool blocked at once, and that pool has one thread
# per core; a pool two threads larger than the cores (at least 4: PJRT_NPROC, read when the
# CPU backend starts) leaves workers free. A PJRT_NPROC or NPROC the user set is kept.
# Measured (hang gone, cost elsewhere): benchmarks/README.md, "XLA's thread pool".
if "PJRT_NPROC" not in os.environ and "NPROC" not in os.environ:
    os.environ["PJRT_NPROC"] = str(max(4, (os.cpu_count() or 1) + 2))

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

# Persistent compilation cache: compile time dominates small JAX problems. Users may point it
# elsewhere with HAPID_JAX_CACHE, or switch it off with HAPID_JAX_CACHE="".
_cache = os.environ.get(
    "HAPID_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "hapid", "jax")
)


def jax_cache_dir() -> str:
    """The persistent-cache folder in use (``""``: caching switched off, or not creatable)."""
    return _cache


if _cache:
    try:
        os.makedirs(_cache, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", _cache)
        # every program, however small: a new process otherwise recompiles each small
        # program it dispatches (≈ 160 in a `hapid robust`, 26 ms each) instead of reading it
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    except OSError:  # read-only home: run without the persistent cache
        _cache = ""
