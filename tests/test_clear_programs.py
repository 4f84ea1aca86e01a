"""``hapid.clear_programs`` releases the compiled programs a process holds: a process that keeps
every program it compiled reaches Linux's ``vm.max_map_count`` (each XLA:CPU executable maps
its code separately; 65 530 by default) and the compiler segfaults — what a serial run of the
slow suite did after 32 tests (65 087 mappings at the crash)."""

import gc
import sys

import jax.numpy as jnp
import numpy as np
import pytest

import hapid
from hapid import _aot


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="counts /proc/self/maps")
def test_clear_programs_releases_compiled_code_and_results_stay_the_same():
    def f(x, k):
        y = x
        for i in range(k % 4 + 2):
            y = jnp.tanh(y @ x.T + i) * k
        return jnp.linalg.solve(y + 10 * jnp.eye(y.shape[-1]), x)

    prog = _aot.cached_jit(f, name="test_clear_programs_f")
    xs = [np.full((3 + k % 5, 3 + k % 5), 0.01 * (k + 1)) for k in range(40)]
    before = [np.asarray(prog(x, k)) for k, x in enumerate(xs)]  # 40 programs (k is static)
    exported = _aot.export_dir() is not None  # else cached_jit is eqx.filter_jit: no table
    assert len(prog.programs) == (40 if exported else 0)
    gc.collect()
    held = _aot.mapping_count()
    hapid.clear_programs()
    gc.collect()
    released = held - _aot.mapping_count()
    assert released >= 40, f"clear_programs released {released} memory mappings of 40 programs"
    assert not prog.programs
    after = [np.asarray(prog(x, k)) for k, x in enumerate(xs)]  # reloaded from the caches
    assert len(prog.programs) == (40 if exported else 0)  # through the export cache again
    for a, b in zip(before, after, strict=True):
        np.testing.assert_array_equal(a, b)
