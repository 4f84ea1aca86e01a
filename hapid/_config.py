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

# CPU devices: XLA:CPU runs one program on one core (the loop kernels are small matrices), so
# independent programs — the per-plant grid passes of a robust check, the chunks of a sweep —
# use a second core only as a second JAX device. HAPID_CPU_DEVICES=k (default 1) asks for k.
_DEV = "--xla_force_host_platform_device_count"


def _cpu_devices() -> int:
    raw = os.environ.get("HAPID_CPU_DEVICES", "").strip()
    if not raw:
        return 1
    if raw == "auto":
        return max(1, min(os.cpu_count() or 1, 8))
    try:
        k = int(raw)
    except ValueError:
        raise ValueError(
            f"HAPID_CPU_DEVICES must be a positive integer or 'auto', got {raw!r}"
        ) from None
    if k < 1:
        raise ValueError(f"HAPID_CPU_DEVICES must be a positive integer or 'auto', got {raw!r}")
    return k


if _DEV not in os.environ.get("XLA_FLAGS", "") and _cpu_devices() > 1:
    os.environ["XLA_FLAGS"] = (os.environ["XLA_FLAGS"] + f" {_DEV}={_cpu_devices()}").strip()

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
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    except OSError:  # read-only home: run without the persistent cache
        _cache = ""
