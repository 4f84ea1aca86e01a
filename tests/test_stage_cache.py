"""The stage cache: keyed by inputs and hapid's source, stored without pickle, bypassable."""

import numpy as np
import pytest

import hapid  # noqa: F401  (float64)
from hapid import _stages, scene
from hapid._stages import Graph, Stage


def _graph(calls):
    from hapid.control import Compensator
    from hapid.fit import CRHPReport
    from hapid.frf import as_frf

    def a(o):
        calls.append("a")
        f = np.array([1.0, 2.0, 3.0])
        Z = (1 + 1j) * np.ones((3, 2, 2)) * f[:, None, None] + np.eye(2)
        return {"g": Compensator.paper(k=o["k"]), "frf": as_frf(f, Z, 2 * Z), "n": 3, "x": 0.5,
                "crhp": CRHPReport(np.int64(1), np.int64(0)), "label": "α", "none": None,
                "pair": (1, [2.0, "b"])}  # fmt: skip

    def b(o, ra):
        calls.append("b")
        return {"twice_k": 2 * ra["g"].k}

    return Graph([Stage("a", (), lambda c: {"k": c["k"]}, a), Stage("b", ("a",), lambda c: {}, b)])


def test_cache_round_trip_without_pickle_and_source_hash_invalidates(tmp_path, monkeypatch):
    calls = []
    g = _graph(calls)
    cfg = {"k": 0.7}
    first, log1 = g.run(cfg, ["b"], cache_dir=tmp_path)
    assert log1["computed"] == ["a", "b"] and calls == ["a", "b"]
    for p in tmp_path.glob("*.npz"):  # stored without pickle: loads with allow_pickle=False
        with np.load(p, allow_pickle=False) as z:
            assert "__meta__" in z.files
    second, log2 = g.run(cfg, ["b"], cache_dir=tmp_path)
    assert log2["cached"] == ["a", "b"] and calls == ["a", "b"]
    ra, rb = first["a"], second["a"]
    assert type(rb["g"]).__name__ == "Compensator" and float(rb["g"].k) == pytest.approx(0.7)
    np.testing.assert_array_equal(np.asarray(rb["frf"].Z_H), np.asarray(ra["frf"].Z_H))
    assert rb["n"] == 3 and rb["x"] == 0.5 and rb["label"] == "α" and rb["none"] is None
    assert (
        rb["pair"] == (1, [2.0, "b"])
        and int(rb["crhp"].hand) == 1
        and rb["crhp"]._fields == ("hand", "total")
    )
    # an option change recomputes only downstream of it
    g.run({"k": 0.8}, ["b"], cache_dir=tmp_path)
    assert calls == ["a", "b", "a", "b"]
    # a change of hapid's source invalidates every entry
    monkeypatch.setattr(_stages, "source_hash", lambda: "edited-source")
    _, log3 = g.run(cfg, ["b"], cache_dir=tmp_path)
    assert log3["computed"] == ["a", "b"] and calls[-2:] == ["a", "b"]
    # no cache dir (--no-cache): everything recomputed, nothing read
    _, log4 = g.run(cfg, ["b"], cache_dir=None)
    assert log4["computed"] == ["a", "b"] and not log4["cached"]
    assert set(log4["seconds"]) == {"a", "b"}


def test_source_hash_follows_the_package_files(tmp_path, monkeypatch):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "b.py").write_text("y = 2\n")
    monkeypatch.setattr(_stages, "_PKG_ROOT", pkg)
    _stages.source_hash.cache_clear()
    try:
        h1 = _stages.source_hash()
        _stages.source_hash.cache_clear()
        (pkg / "sub" / "b.py").write_text("y = 3\n")
        h2 = _stages.source_hash()
        assert h1 != h2
        k1 = _stages.stage_key("a", {}, [])
        _stages.source_hash.cache_clear()
        (pkg / "sub" / "b.py").write_text("y = 2\n")
        assert _stages.source_hash() == h1 and _stages.stage_key("a", {}, []) != k1
    finally:
        _stages.source_hash.cache_clear()


def test_foreign_classes_are_not_decoded():
    tree = {"object": "os:system", "fields": {}}
    with pytest.raises(ValueError, match="non-hapid class"):
        _stages.decode(tree, {})


def test_tuned_g_is_a_stage_of_the_summary():
    need = scene.graph().needed(["summary"])
    assert "tuned" in need and "tuned_mimo" in need
    assert scene.graph().stages["tuned"].cache
