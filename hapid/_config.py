"""Global JAX configuration applied on ``import hapid``.

float64 is switched on before any array is created: the s² terms of an impedance at 100 Hz
are ~4·10⁵ times the constant terms, and float32 loses the fit (DESIGN.md, Conventions).
"""

import os

import jax

jax.config.update("jax_enable_x64", True)

# Persistent compilation cache: compile time dominates small JAX problems. Users may point it
# elsewhere with HAPID_JAX_CACHE, or switch it off with HAPID_JAX_CACHE="".
_cache = os.environ.get("HAPID_JAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "hapid", "jax"))
if _cache:
    try:
        os.makedirs(_cache, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", _cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    except OSError:  # read-only home: run without the persistent cache
        pass
