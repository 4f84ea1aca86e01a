"""Work split over processes (hapid._distributed): the split is a partition, and two local CPU
processes joined by jax.distributed gather exactly what one process computes."""

import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hapid import _distributed

HERE = Path(__file__).resolve().parent
WORKER = HERE / "dist_worker.py"


@pytest.mark.parametrize("n", [0, 1, 5, 7, 64, 1001])
@pytest.mark.parametrize("count", [1, 2, 3, 8])
def test_block_split_is_an_ordered_partition(n, count):
    blocks = [_distributed.block(n, count, i) for i in range(count)]
    flat = [i for b in blocks for i in b]
    assert flat == list(range(n))  # every item exactly once, in order
    sizes = [len(b) for b in blocks]
    assert max(sizes) - min(sizes) <= 1


def test_block_rejects_bad_rank():
    with pytest.raises(ValueError, match="out of range"):
        _distributed.block(10, 2, 2)


def test_gather_on_one_process_concatenates_in_order_any_dtype():
    parts = [{"a": np.array([1.0, np.nan]), "b": np.array([True, False]), "c": np.arange(4).reshape(2, 2)},
             {},
             {"a": np.array([-np.inf]), "b": np.array([True]), "c": np.array([[7, 8]])}]  # fmt: skip
    g = _distributed.gather(parts)
    np.testing.assert_array_equal(g["a"], [1.0, np.nan, -np.inf])
    assert g["b"].dtype == bool and g["c"].shape == (3, 2)
    # the wire format (np.savez bytes) round-trips exactly, dtypes included
    d = _distributed._decode(_distributed._encode(g))
    for k in g:
        assert d[k].dtype == g[k].dtype
        np.testing.assert_array_equal(d[k], g[k])


def test_env_settings_are_checked(monkeypatch):
    monkeypatch.setenv("HAPID_COORDINATOR", "127.0.0.1:1")
    monkeypatch.setenv("HAPID_NUM_PROCESSES", "2")
    monkeypatch.setenv("HAPID_PROCESS_ID", "2")
    with pytest.raises(ValueError, match="HAPID_PROCESS_ID must be in"):
        _distributed._env_settings()
    monkeypatch.delenv("HAPID_PROCESS_ID")
    with pytest.raises(ValueError, match="needed too"):
        _distributed._env_settings()
    monkeypatch.setenv("HAPID_PROCESS_ID", "1")
    with pytest.raises(ValueError, match="disagrees"):
        _distributed.local_launch_needed(3)
    assert not _distributed.local_launch_needed(2)


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(out, procs, *extra, timeout=600):
    env = dict(
        os.environ, PYTHONPATH=str(HERE.parent) + os.pathsep + os.environ.get("PYTHONPATH", "")
    )
    for k in ("HAPID_COORDINATOR", "HAPID_NUM_PROCESSES", "HAPID_PROCESS_ID"):
        env.pop(k, None)
    if procs == 1:
        r = subprocess.run([sys.executable, str(WORKER), str(out), *extra], env=env,
                           capture_output=True, text=True, timeout=timeout)  # fmt: skip
        assert r.returncode == 0, r.stderr[-3000:]
        return
    coord = f"127.0.0.1:{_free_port()}"
    ps = [subprocess.Popen([sys.executable, str(WORKER), str(out), *extra],
                           env=env | {"HAPID_COORDINATOR": coord, "HAPID_NUM_PROCESSES": str(procs),
                                      "HAPID_PROCESS_ID": str(i)},
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
          for i in range(procs)]  # fmt: skip
    try:
        errs = [p.communicate(timeout=timeout)[1] for p in ps]
    finally:
        for p in ps:
            if p.poll() is None:
                p.kill()
    for p, e in zip(ps, errs, strict=True):
        assert p.returncode == 0, e[-3000:]


_GATHER = """
import sys, time
import numpy as np
from hapid import _distributed as d
assert d.initialize()
rank = d.process_index()
time.sleep(float(sys.argv[1]) * rank)  # a late process: gloo alone waits only 30 s
parts = [] if rank == 0 else [{"x": np.arange(3.0) + rank, "b": np.array([True, False, True])}]
g = d.gather(parts)  # process 0 has nothing: the others' rows, in rank order
print("GATHERED", g["x"].tolist(), g["b"].tolist())
"""


def _gather_two(delay, timeout):
    coord = f"127.0.0.1:{_free_port()}"
    env = dict(
        os.environ, PYTHONPATH=str(HERE.parent), HAPID_COORDINATOR=coord, HAPID_NUM_PROCESSES="2"
    )
    ps = [subprocess.Popen([sys.executable, "-c", _GATHER, str(delay)], env=env | {"HAPID_PROCESS_ID": str(i)},
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
          for i in range(2)]  # fmt: skip
    try:
        outs = [p.communicate(timeout=timeout) for p in ps]
    finally:
        for p in ps:
            if p.poll() is None:
                p.kill()
    for p, (o, e) in zip(ps, outs, strict=True):
        assert p.returncode == 0, e[-3000:]
        assert "GATHERED [1.0, 2.0, 3.0] [True, False, True]" in o, o + e[-2000:]


@pytest.mark.slow  # also covered inside the robust-check two-process test (dist_worker)
def test_two_processes_gather_when_one_has_no_items():
    _gather_two(0.0, 120)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_gather_waits_for_a_process_that_arrives_late():
    _gather_two(40.0, 200)


def _check_two_equal_one(tmp_path, prefix, *extra):
    from dist_worker import compute  # one process: this one (same code, flags and cache)

    one = compute(with_sweep="--sweep" in extra)
    _run(tmp_path / "two", 2, *extra)
    assert int(one["count"]) == 1
    ranks = [np.load(tmp_path / f"two.{r}.npz") for r in (0, 1)]
    assert [int(z["rank"]) for z in ranks] == [0, 1] and all(int(z["count"]) == 2 for z in ranks)
    # the split: each process ran a block of the chunks; together every chunk exactly once
    ran = [list(z["robust_chunks"]) for z in ranks]
    assert sorted(ran[0] + ran[1]) == list(one["robust_chunks"]) and ran[0] and ran[1]
    # the gathered results, on every process, bit-identical to one process
    keys = [k for k in one if k.startswith(prefix) and k != "robust_chunks"]
    assert keys
    for z in ranks:
        for k in keys:
            assert z[k].dtype == one[k].dtype, k
            np.testing.assert_array_equal(z[k], one[k], err_msg=k)
    return one


@pytest.mark.slow  # CI budget: three processes each compile the loop analysis (make test-all)
def test_two_processes_gather_the_one_process_robust_check(tmp_path):
    one = _check_two_equal_one(tmp_path, "robust_")
    for r in (0, 1):  # process 0 had no rows: it still gets process 1's
        np.testing.assert_array_equal(
            np.load(tmp_path / f"two.{r}.npz")["empty0_x"], [1.0, 2.0, 3.0]
        )
    st = one["robust_stable"]
    assert st.any() and (~st).any()  # a spread of verdicts, so "identical" can fail


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_two_processes_gather_the_one_process_sweep(tmp_path):
    one = _check_two_equal_one(tmp_path, "sweep_", "--sweep")
    assert one["sweep_rows"].shape == (6, 2)
    assert np.unique(one["sweep_pphat_min_db"]).size > 1  # seeds differ, so equality can fail


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_cli_processes_flag_launches_local_workers(tmp_path):
    """`hapid sweep --processes 2` writes the same table as one process."""
    scene = HERE.parent / "scenes" / "paper.toml"
    args = [str(scene), "--vary", "controller.k=0.5,0.85,1.2", "--chunk", "1"]
    env = dict(os.environ, PYTHONPATH=str(HERE.parent))
    for tag, more in (("one", []), ("two", ["--processes", "2"])):
        r = subprocess.run([sys.executable, "-m", "hapid.cli", "sweep", *args, *more, "--out", str(tmp_path / tag)],
                           env=env, capture_output=True, text=True, timeout=800)  # fmt: skip
        assert r.returncode == 0, r.stderr[-3000:]
    assert (tmp_path / "one" / "sweep.csv").read_text() == (
        tmp_path / "two" / "sweep.csv"
    ).read_text()
