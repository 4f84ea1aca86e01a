"""The three-valued verdict: construction rules, combination and strict JSON."""

import json

import pytest

from hapid.verdict import Check, Verdict, worst


def test_combination_order():
    p, n, f = Check(Verdict.PASSED), Check("not established", reason="r"), Check("failed", "x")
    assert worst(p, p) is Verdict.PASSED
    assert worst(p, n) is Verdict.NOT_ESTABLISHED
    assert worst(n, f, p) is Verdict.FAILED
    assert p.ok and not n.ok and not f.ok


def test_rules_and_json():
    with pytest.raises(ValueError, match="why"):
        Check(Verdict.NOT_ESTABLISHED)
    with pytest.raises(ValueError, match="no reason"):
        Check(Verdict.PASSED, reason="but")
    c = Check(
        "not established", reason="draws end at 100 Hz", remedy="measure to 200 Hz", name="GM"
    )
    d = json.loads(json.dumps(c.summary(), allow_nan=False))
    assert d["verdict"] == "not established" and c.status is Verdict.NOT_ESTABLISHED
    assert c.line().startswith("GM: not established: draws end at 100 Hz")
