"""The ahead-of-time export cache (:mod:`hapid._aot`): a stored program gives the traced
program's numbers, is reused without tracing, and misses on a changed source hash or shape."""

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hapid  # noqa: F401  (float64)
from hapid import _aot
from hapid.cli import main
from hapid.control import _metrics


class _Gain(eqx.Module):
    k: jax.Array
    steps: int = eqx.field(static=True)


@jax.custom_jvp
def _softplus(x):
    return jnp.log1p(jnp.exp(x))


_softplus.defjvp(lambda p, t: (_softplus(p[0]), t[0] * jax.nn.sigmoid(p[0])))

TRACES = []


def _prog(g, x):
    """A small program with a while_loop, a scan, a custom_jvp and a static field."""
    TRACES.append(1)  # runs only when traced
    y = jax.lax.fori_loop(0, g.steps, lambda i, v: jnp.sin(v) * g.k + 0.1 * i, x)
    c = jax.lax.while_loop(lambda c: c[0] < 7, lambda c: (c[0] + 1, c[1] * 1.5), (0, x.sum()))[1]
    s = jax.lax.scan(lambda a, b: (a + b, a * b), 0.0, x)[1]
    return {"y": _softplus(y), "c": c, "s": s, "svd": jnp.linalg.svd(jnp.outer(x, x))[1]}


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setattr(_aot, "export_dir", lambda: tmp_path / "export")
    return tmp_path / "export"


def _close(a, b):
    for k in a:
        np.testing.assert_allclose(np.asarray(a[k]), np.asarray(b[k]), rtol=1e-12, atol=1e-300)


def test_stored_program_equals_traced_and_misses_on_source_or_shape(cache, monkeypatch):
    g, x = _Gain(jnp.asarray(0.7), 5), jnp.linspace(0.1, 1.0, 4)
    want = eqx.filter_jit(_prog)(g, x)
    TRACES.clear()
    first = _aot.cached_jit(_prog)(g, x)  # exports (one trace) and stores
    assert len(TRACES) == 1 and len(list(cache.glob("*.pkl"))) == 1
    _close(first, want)
    TRACES.clear()
    again = _aot.cached_jit(_prog)  # a fresh wrapper: as a new process, reads the file
    for _ in range(2):
        _close(again(g, x), want)
    assert TRACES == []  # no tracing of the Python function
    # a changed shape, static value or source hash is a miss (traced, a new file)
    _aot.cached_jit(_prog)(g, jnp.linspace(0.1, 1.0, 5))
    _aot.cached_jit(_prog)(_Gain(jnp.asarray(0.7), 6), x)
    assert len(TRACES) == 2 and len(list(cache.glob("*.pkl"))) == 3
    monkeypatch.setattr(_aot, "source_hash", lambda: "changed")
    _close(_aot.cached_jit(_prog)(g, x), want)
    assert len(TRACES) == 3 and len(list(cache.glob("*.pkl"))) == 4


def test_off_unwritable_and_traced_fall_back(tmp_path, monkeypatch):
    g, x = _Gain(jnp.asarray(0.3), 3), jnp.linspace(0.2, 0.9, 3)
    want = eqx.filter_jit(_prog)(g, x)
    monkeypatch.setattr(_aot, "export_dir", lambda: None)  # HAPID_JAX_CACHE=""
    _close(_aot.cached_jit(_prog)(g, x), want)
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setattr(_aot, "export_dir", lambda: blocker / "export")  # cannot be created
    _close(_aot.cached_jit(_prog)(g, x), want)
    # inside jit and vmap the function is traced inline (one path, batched correctly)
    f = _aot.cached_jit(_prog)
    batched = jax.vmap(lambda k: f(_Gain(k, 3), x)["y"])(jnp.asarray([0.3, 0.3]))
    np.testing.assert_allclose(batched[0], want["y"], rtol=1e-12)
    # a static leaf without a stable repr (an object address) is not stored
    assert _aot.cache_key(_prog, (object(), x)) is None


def test_cache_dir_off(monkeypatch):
    """HAPID_JAX_CACHE="" (``_config`` keeps ``""``): no export folder, so no stored programs."""
    monkeypatch.setattr(hapid._config, "_cache", "")
    assert _aot.export_dir() is None
    monkeypatch.setattr(hapid._config, "_cache", "/some/dir")
    assert str(_aot.export_dir()) == "/some/dir/export"


def _numbers(path):
    return {k: v for k, v in json.loads(path.read_text()).items() if not isinstance(v, str)}


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_analyze_from_stored_program_equals_traced(tmp_path, monkeypatch, capsys):
    """``hapid analyze`` with the loop program exported, then read back by a fresh wrapper (as
    a new process would), writes the same report numbers as the ordinary traced jit."""
    from hapid import io
    from hapid.impedance import ImpedanceModel, SecondOrder

    eye = np.eye(5)
    hand = SecondOrder(0.3 * eye, 5.0 * eye, 400.0 * eye)
    io.save_model(tmp_path / "m.npz", ImpedanceModel.from_hand_mechanism(
        hand, SecondOrder(0.5 * eye, 30.0 * eye, 0.0 * eye)), method="rigid")  # fmt: skip
    args = ["analyze", "--model", str(tmp_path / "m.npz"), "--device", "cu5", "--out"]
    monkeypatch.setattr(_aot, "export_dir", lambda: None)  # the traced path
    assert main([*args, str(tmp_path / "traced.json")]) == 0
    monkeypatch.setattr(_aot, "export_dir", lambda: tmp_path / "export")
    monkeypatch.setattr(_metrics, "_metrics_jit", _aot.cached_jit(_metrics.metrics_screened))
    assert main([*args, str(tmp_path / "exported.json")]) == 0
    assert len(list((tmp_path / "export").glob("metrics_screened-*.pkl"))) == 1
    traces = []
    monkeypatch.setattr(_metrics, "grid_pass", lambda *a: traces.append(1))  # must not run
    monkeypatch.setattr(_metrics, "_metrics_jit", _aot.cached_jit(_metrics.metrics_screened))
    assert main([*args, str(tmp_path / "stored.json")]) == 0
    assert traces == []
    want = _numbers(tmp_path / "traced.json")
    assert sum(isinstance(v, float) and np.isfinite(v) for v in want.values()) >= 4
    for name in ("exported.json", "stored.json"):
        got = _numbers(tmp_path / name)
        assert got.keys() == want.keys()
        for k, v in want.items():
            if isinstance(v, float):
                assert got[k] == pytest.approx(v, rel=1e-12, abs=1e-12, nan_ok=True), k
            else:
                assert got[k] == v, k
