"""The file writers (all in hapid.io): atomic, honouring the umask, strict JSON."""

import csv
import json
import os
import stat

import numpy as np
import pytest
from oracle_loop import analyze_loop

from hapid import io
from hapid.control import Compensator
from hapid.fit import Scale, n_params
from hapid.io import load_samples
from hapid.io._common import _atomic_write
from hapid.tune import load_design
from hapid.uncertainty import PosteriorSamples, param_names


def _strict_loads(s):
    def refuse(c):
        raise ValueError(f"non-JSON constant {c}")

    return json.loads(s, parse_constant=refuse)


@pytest.fixture
def umask():
    old = os.umask(0o022)
    yield lambda m: os.umask(m)
    os.umask(old)


def _samples(n=2, S=5):
    rng = np.random.default_rng(0)
    d = n_params(n)
    diag = {"method": "laplace", "acceptance": 0.3, "tau": np.arange(3.0)}
    return PosteriorSamples(np.abs(rng.normal(size=(S, d))), rng.normal(size=S), Scale(np.float64(60.0), np.float64(300.0)),
                            n, tuple(param_names(n)), diag)  # fmt: skip


def _writers(tmp_path):
    g = Compensator.paper()
    return {
        "json": lambda: io.save_json(tmp_path / "r.json", {"a": 1.0}),
        "text": lambda: io.save_text(tmp_path / "r.md", "# hi\n"),
        "csv": lambda: io.save_csv(tmp_path / "t.csv", ["x", "y"], [[1, 2]]),
        "samples": lambda: io.save_samples(tmp_path / "s.npz", _samples()),
        "design": lambda: io.save_design(tmp_path / "d.npz", g, note="x"),
        "cache": lambda: io.save_cache_entry(tmp_path / "c.npz", {"x": np.ones(2)}, "{}"),
    }


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_every_writer_honours_the_umask(tmp_path, umask, mask):
    umask(mask)
    for name, write in _writers(tmp_path).items():
        p = write()
        mode = stat.S_IMODE(os.stat(p).st_mode)
        assert mode == 0o666 & ~mask, f"{name}: mode {oct(mode)} with umask {oct(mask)}"
    # same as a plain open() would give
    plain = tmp_path / "plain"
    plain.write_text("x")
    assert stat.S_IMODE(os.stat(plain).st_mode) == 0o666 & ~mask
    assert not list(tmp_path.glob(".*.tmp")), "temporary files left behind"


def test_failed_write_leaves_nothing(tmp_path):
    target = tmp_path / "out.json"
    target.write_text('{"old": true}')

    def boom(fh):
        fh.write(b'{"half": ')
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        _atomic_write(target, boom)
    assert json.loads(target.read_text()) == {"old": True}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_report_of_an_unstable_loop_is_strict_json(tmp_path):
    # L = 50/(s+1)³ on each of 2 channels: the critical gain of a triple lag is 8, so unstable
    omega = np.geomspace(1e-2, 1e3, 400)
    s = 1j * omega
    n = 2
    L = 50.0 / (s + 1.0) ** 3
    P = L[:, None, None] * np.eye(n)
    G = np.broadcast_to(np.eye(n, dtype=complex), P.shape)
    summary = analyze_loop(P, G, omega).numbers()
    assert summary["stable"] is False
    assert any(isinstance(v, float) and not np.isfinite(v) for v in summary.values()), summary
    with pytest.raises(ValueError, match="non-JSON"):
        _strict_loads(json.dumps(summary))  # what the old writers produced
    p = io.save_json(
        tmp_path / "report.json", {"report": summary, "arr": np.array([1.0, np.nan, -np.inf])}
    )
    back = _strict_loads(p.read_text())
    assert back["report"]["stable"] is False and back["arr"] == [1.0, None, None]
    for k, v in summary.items():
        assert back["report"][k] == (
            v if not (isinstance(v, float) and not np.isfinite(v)) else None
        )


def test_samples_and_design_round_trip(tmp_path):
    ps = _samples()
    p = io.save_samples(tmp_path / "s", ps)
    assert p.name == "s.npz"
    back = load_samples(p, n=2)
    np.testing.assert_array_equal(back.samples, ps.samples)
    np.testing.assert_array_equal(back.log_prob, ps.log_prob)
    assert back.names == ps.names and back.diagnostics["method"] == "laplace"
    g = Compensator.paper(k=0.7)
    io.save_design(tmp_path / "d.npz", g, bad=float("nan"), arr=np.arange(3))
    g2, info = load_design(tmp_path / "d.npz")
    assert float(g2.k) == pytest.approx(0.7) and info == {"bad": None, "arr": [0, 1, 2]}
    np.testing.assert_array_equal(np.asarray(g2.lowpass), np.asarray(g.lowpass))


def test_csv_writer(tmp_path):
    p = io.save_csv(tmp_path / "t.csv", ["a", "b"], [[1, "x,y"], [2.5, "z"]])
    with open(p, newline="") as fh:
        assert list(csv.reader(fh)) == [["a", "b"], ["1", "x,y"], ["2.5", "z"]]
