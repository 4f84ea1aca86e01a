import os

# The suite is compile-bound (hundreds of small programs, each run a few times): XLA's LLVM
# optimization passes are most of a compile and buy nothing here. Measured on 3 compile-heavy
# test files, cold cache, 2 workers: 245 s → 172 s wall. The numerics are the same programs
# (no fast-math); only code generation is less optimized. Set HAPID_TEST_XLA_OPT=1 to test
# the optimized programs users run.
if os.environ.get("HAPID_TEST_XLA_OPT") != "1":
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "")
        + " --xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
    ).strip()

os.environ.setdefault(
    "HAPID_JAX_CACHE", os.path.join(os.path.dirname(__file__), "..", ".hapid_cache", "jax")
)

import hapid  # noqa: E402,F401  (float64 before any test builds arrays)
