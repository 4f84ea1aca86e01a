"""``import hapid`` gives XLA's CPU thread pool more threads than the machine has cores
(hapid._config): with one thread per core, two batched LAPACK kernels running side by side
in one program can each wait in ``jax::ParallelBatchMap`` for a worker that the other holds,
and the process hangs idle (a batched ``hapid sweep`` did, every time, on 2 cores; the slow
test ``test_sweep_of_256_configurations_matches_single_runs`` is that case). A pool size the
user set is kept."""

import os
import subprocess
import sys

import pytest

CODE = """
import glob, os
import hapid, jax.numpy as jnp
x = jnp.ones((300, 300)); (x @ x).block_until_ready()
names = [open(f).read().strip() for f in glob.glob("/proc/self/task/*/comm")]
print(os.environ.get("PJRT_NPROC"), names.count("tf_XLAEigen"))
"""

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def _run(**env):
    base = {k: v for k, v in os.environ.items() if k not in ("PJRT_NPROC", "NPROC")}
    out = subprocess.run([sys.executable, "-c", CODE], env=base | env, capture_output=True,
                         text=True, timeout=120, check=True)  # fmt: skip
    nproc, threads = out.stdout.split()
    return nproc, int(threads)


def test_the_pool_has_two_threads_more_than_the_cores():
    nproc, threads = _run()
    assert int(nproc) == max(4, os.cpu_count() + 2)
    assert threads == int(nproc)  # the pool XLA started is that size


def test_a_pool_size_the_user_set_is_kept():
    assert _run(PJRT_NPROC="3") == ("3", 3)
    nproc, threads = _run(NPROC="5")
    assert nproc == "None" and threads == 5
