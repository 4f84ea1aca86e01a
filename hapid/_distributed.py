"""Work split over processes with ``jax.distributed``: sweeps and robust checks beyond one machine.

A batch of work (sweep configurations, robust-check plants) is already cut in chunks, each
one compiled ``vmap`` call. With several processes, every process runs a contiguous block of
those chunks — the same chunks, padded the same way, as on one process — and the per-chunk
results are gathered on every process in chunk order. The gathered results are therefore
bit-identical to one process (same compiled program on the same inputs), and the split is a
partition of the chunks: no item lost or doubled (``tests/test_distributed.py``).

How processes meet (docs/distributed.md):

- ``HAPID_COORDINATOR=host:port``, ``HAPID_NUM_PROCESSES=N``, ``HAPID_PROCESS_ID=i`` in the
  environment of every process (a cluster launcher sets them, e.g. from ``SLURM_PROCID``);
  :func:`initialize` passes them to :func:`jax.distributed.initialize`.
  ``HAPID_COORDINATOR=auto`` lets JAX detect the cluster (SLURM, Open MPI, …) itself.
- ``hapid sweep … --processes N`` / ``hapid robust … --processes N``: :func:`launch_local`
  starts N local processes with those variables (coordinator on 127.0.0.1, a free port).

Gathering uses JAX's own cross-process collective
(:func:`jax.experimental.multihost_utils.process_allgather`; on CPU it runs over gloo, the
default ``jax_cpu_collectives_implementation`` of jaxlib 0.10.2, checked with two local CPU
processes), after a barrier of the coordination service (gloo waits only 30 s for its peers;
a process may finish its block minutes before another). Each process's results are serialized (``np.savez``, no pickle) to a byte array,
padded to the longest, all-gathered and decoded — any dtype and shape, exact.

Only process 0 writes files and prints reports; the others compute and exit.
"""

from __future__ import annotations

import io as _io
import os
import socket
import subprocess
import sys
import threading
import time

import jax
import numpy as np
from jax._src import distributed
from jax.experimental import multihost_utils

ENV_COORDINATOR = "HAPID_COORDINATOR"
ENV_NUM_PROCESSES = "HAPID_NUM_PROCESSES"
ENV_PROCESS_ID = "HAPID_PROCESS_ID"

_STATE = {"initialized": False}


def _env_settings() -> tuple[str, int | None, int | None] | None:
    coord = os.environ.get(ENV_COORDINATOR, "").strip()
    if not coord:
        return None
    try:
        n = os.environ.get(ENV_NUM_PROCESSES)
        i = os.environ.get(ENV_PROCESS_ID)
        n = None if n in (None, "") else int(n)
        i = None if i in (None, "") else int(i)
    except ValueError:
        raise ValueError(
            f"{ENV_NUM_PROCESSES} and {ENV_PROCESS_ID} must be integers, got "
            f"{os.environ.get(ENV_NUM_PROCESSES)!r}, {os.environ.get(ENV_PROCESS_ID)!r}"
        ) from None
    if coord != "auto":
        if n is None or i is None:
            raise ValueError(
                f"{ENV_COORDINATOR} is set: {ENV_NUM_PROCESSES} and {ENV_PROCESS_ID} are needed too"
            )
        if n < 1 or not 0 <= i < n:
            raise ValueError(
                f"{ENV_PROCESS_ID} must be in [0, {ENV_NUM_PROCESSES}) = [0, {n}), got {i}"
            )
    return coord, n, i


def initialize() -> bool:
    """Join the process group described by the ``HAPID_*`` variables (once; before any JAX
    computation). Returns ``True`` if this process is part of a multi-process run."""
    if _STATE["initialized"]:
        return process_count() > 1
    s = _env_settings()
    if s is None:
        return False

    coord, n, i = s
    if coord == "auto":
        jax.distributed.initialize()
    else:
        jax.distributed.initialize(coordinator_address=coord, num_processes=n, process_id=i)
    _STATE["initialized"] = True
    return process_count() > 1


def process_count() -> int:
    """Processes in the run (1 without ``jax.distributed``)."""
    if not _STATE["initialized"]:
        return 1

    return int(jax.process_count())


def process_index() -> int:
    """This process's rank, 0 … ``process_count() − 1`` (0 without ``jax.distributed``)."""
    if not _STATE["initialized"]:
        return 0

    return int(jax.process_index())


def is_main() -> bool:
    """Process 0: the one that writes files and prints."""
    return process_index() == 0


def block(n: int, count: int | None = None, index: int | None = None) -> range:
    """Items ``[index·n // count, (index + 1)·n // count)`` of ``range(n)``: the contiguous
    block of process ``index`` of ``count`` (default: this process). Over all indices the
    blocks partition ``range(n)`` in order; sizes differ by at most one."""
    count = process_count() if count is None else int(count)
    index = process_index() if index is None else int(index)
    if count < 1 or not 0 <= index < count:
        raise ValueError(f"process index {index} out of range for {count} processes")
    return range(index * n // count, (index + 1) * n // count)


def local_chunks(n_items: int, chunk: int) -> list[int]:
    """Start offsets of the chunks of ``range(n_items)`` (size ``chunk``) this process runs."""
    starts = range(0, n_items, chunk)
    return [starts[c] for c in block(len(starts))]


def _encode(d: dict) -> np.ndarray:
    buf = _io.BytesIO()
    np.savez(buf, **d)
    return np.frombuffer(buf.getvalue(), dtype=np.uint8)


def _decode(b: np.ndarray) -> dict:
    with np.load(_io.BytesIO(b.tobytes()), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _concat(parts: list[dict]) -> dict:
    parts = [p for p in parts if p]
    if not parts:
        return {}
    return {k: np.concatenate([np.asarray(p[k]) for p in parts]) for k in parts[0]}


def barrier() -> None:
    """Wait until every process is here (the ``jax.distributed`` coordination service; timeout
    ``HAPID_GATHER_TIMEOUT_S``, default 24 h). The CPU collective (gloo) itself waits only 30 s
    for its peers, less than one process may spend on its last chunk while another is done."""
    _STATE["barriers"] = _STATE.get("barriers", 0) + 1
    timeout_s = float(os.environ.get("HAPID_GATHER_TIMEOUT_S", 86400))
    distributed.global_state.client.wait_at_barrier(
        f"hapid_gather_{_STATE['barriers']}", int(1000 * timeout_s)
    )


def allgather_bytes(b: np.ndarray) -> list[np.ndarray]:
    """Every process's ``uint8`` array, on every process, in rank order (a JAX collective,
    after a :func:`barrier`)."""
    barrier()
    lens = np.asarray(multihost_utils.process_allgather(np.array([b.size], np.int64))).reshape(-1)
    pad = np.zeros(max(int(lens.max()), 1), np.uint8)
    pad[: b.size] = b
    allb = np.asarray(multihost_utils.process_allgather(pad)).reshape(lens.size, -1)
    return [allb[p, : int(lens[p])] for p in range(lens.size)]


def gather(parts: list[dict]) -> dict:
    """Concatenate this process's per-chunk results (dicts of arrays, leading axis = items,
    in chunk order) and then every process's, in rank order, on every process. With the
    chunks split by :func:`local_chunks`, the result is in the one-process order."""
    local = _concat(parts)
    if process_count() == 1:
        return local
    return _concat([_decode(b) for b in allgather_bytes(_encode(local))])


# ---- local launcher ------------------------------------------------------------------------


def local_launch_needed(n: int) -> bool:
    """``--processes n``: ``True`` if this process must launch ``n`` local workers
    (:func:`launch_local`), ``False`` if it is one already (``HAPID_*`` set, matching ``n``)
    or ``n`` is 1."""
    s = _env_settings()
    if s is None:
        return n > 1
    if s[1] is not None and s[1] != n:
        raise ValueError(
            f"--processes {n} disagrees with {ENV_NUM_PROCESSES}={s[1]}; give one of them"
        )
    return False


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _relay_stdout(stream) -> None:
    """Copy process 0's stdout to ours, without the collective library's connection lines
    (``[Gloo] Rank 0 is connected to …``), which are not hapid's output."""
    for raw in iter(stream.readline, b""):
        if not raw.startswith(b"[Gloo]"):
            sys.stdout.write(raw.decode(errors="replace"))
            sys.stdout.flush()
    stream.close()


def launch_local(argv: list[str], n: int, *, timeout: float | None = None) -> int:
    """Run ``python -m hapid.cli argv`` as ``n`` local processes joined by ``jax.distributed``
    (coordinator 127.0.0.1 on a free port); process 0's output is shown, the others' stdout
    is discarded (their errors are shown); the collective library's ``[Gloo]`` connection lines are dropped
    from process 0's output. If one fails, the others are stopped. Returns the
    largest exit code."""
    if n < 1:
        raise ValueError(f"--processes must be ≥ 1, got {n}")
    coord = f"127.0.0.1:{_free_port()}"
    procs = []
    for i in range(n):
        env = dict(os.environ)
        env.update({ENV_COORDINATOR: coord, ENV_NUM_PROCESSES: str(n), ENV_PROCESS_ID: str(i)})
        procs.append(
            subprocess.Popen(
                [sys.executable, "-m", "hapid.cli", *argv],
                env=env,
                stdout=subprocess.PIPE if i == 0 else subprocess.DEVNULL,
            )  # fmt: skip
        )
    relay = threading.Thread(target=_relay_stdout, args=(procs[0].stdout,), daemon=True)
    relay.start()
    t0 = time.monotonic()
    rcs: list[int | None] = [None] * n
    while any(rc is None for rc in rcs):
        for k, p in enumerate(procs):
            if rcs[k] is None:
                rcs[k] = p.poll()
        if any(rc not in (None, 0) for rc in rcs) or (timeout and time.monotonic() - t0 > timeout):
            for k, p in enumerate(procs):
                if rcs[k] is None:
                    p.terminate()
                    rcs[k] = p.wait()
            break
        time.sleep(0.05)
    relay.join(timeout=5.0)
    failed = [int(rc) for rc in rcs if rc and rc > 0]  # a worker's own exit code first
    return failed[0] if failed else max(abs(int(rc)) for rc in rcs)
