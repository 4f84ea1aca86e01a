import gc
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

import pytest  # noqa: E402

import hapid  # noqa: E402,F401  (float64 before any test builds arrays)

# The heaviest test files (seconds of compile and run, measured with --durations=0 on a
# clean-clone `make test`) go first: `make test` hands out whole files (--dist loadfile), and
# a heavy file handed out last leaves the other worker idle (longest-first scheduling).
# Order within a file is kept. test_kernels_eig.py stays before test_control_kernels.py: the
# latter reuses the former's eigvals programs from the persistent cache.
_HEAVY_FIRST = (
    "test_fit_nls.py",
    "test_uncertainty.py",
    "test_uncertainty_gp_corr.py",
    "test_fit_fast.py",
    "test_result_convention.py",
    "test_experiment.py",
    "test_stress.py",
    "test_kernels_eig.py",
    "test_tune_evidence.py",
    "test_uncertainty_gp.py",
    "test_tune.py",
    "test_design.py",
    "test_control_kernels.py",
    "test_properties.py",
    "test_notebooks.py",
    "test_control_discrete.py",
    "test_closed_loop.py",
    "test_wls_batch.py",
    "test_fit_ml.py",
    "test_wall.py",
    "test_device.py",
    "test_control_loop.py",
    "test_control_controller.py",
    "test_control_compensator.py",
)


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(_HEAVY_FIRST)}
    items.sort(key=lambda it: rank.get(it.path.name, len(rank)))  # stable: file order kept


_MAPPINGS_HIGH = 20_000
"""Release the compiled programs after a test module once the process holds this many memory
mappings (a third of Linux's default ``vm.max_map_count``, 65 530)."""


@pytest.fixture(autouse=True, scope="module")
def _release_programs():
    """Drop the compiled programs after a test module when the process holds many memory
    mappings (hapid.clear_programs): a process that keeps every program it compiled reaches
    Linux's vm.max_map_count (each executable maps its code separately) and the XLA compiler
    segfaults — a serial slow-suite run did after 32 tests. Below the threshold nothing is
    dropped, so later modules keep reusing programs in memory."""
    yield
    from hapid._aot import clear_programs, mapping_count

    if mapping_count() > _MAPPINGS_HIGH:  # 0 off Linux: no such limit
        clear_programs()
        gc.collect()
