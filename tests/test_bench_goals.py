"""The issue-13 goals table of benchmarks/run_all.py: six rows in the issue's order, built only
from rows the bench scripts wrote during this run (benchmarks/README.md, contract)."""

import os
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

import _common  # noqa: E402
import run_all  # noqa: E402


def _row(rid, **kw):
    r = dict(id=rid, work=f"{rid} work", reference="numpy", reference_s=0.03, hapid_s=0.001,
             ratio=30.0, goal="≥ 30×", met=True, reason="")  # fmt: skip
    return r | kw


def test_table_has_the_six_issue_rows_fresh_only(tmp_path):
    since = time.time() - 1.0
    _common.write_goal_rows(str(tmp_path), "bench_fast", [_row("loop_analysis")], quick=False)
    _common.write_goal_rows(str(tmp_path), "bench_throughput",
                            [_row("wls_bound", reference_s=1e-5, hapid_s=4e-4, ratio=0.025, met=False,
                                  reason="per-fit | overhead")], quick=True)  # fmt: skip
    old = _common.write_goal_rows(str(tmp_path), "bench_fit", [_row("nls_scipy")], quick=False)
    os.utime(old, (since - 100, since - 100))  # an earlier run's file
    rows = run_all.issue_table(tmp_path, since)
    # the issue's rows in its order; a row not measured shows the issue's goal
    assert [r["work"] for r in rows[1::2]] == [w for _, w, _, _ in _common.ISSUE_ROWS[1::2]]
    assert rows[1]["goal"] == _common.ISSUE_ROWS[1][2]
    assert len(rows) == 6
    assert (
        rows[0]["met"] == "yes"
        and rows[0]["ratio"] == "30×"
        and "numpy" in rows[0]["numpy / scipy"]
    )
    assert rows[2]["met"] == "**no**" and rows[2]["ratio"] == "2.5 % of bound"
    assert "--quick" in rows[2]["work"] and "|" not in rows[2]["reason"]
    assert rows[3]["met"] == "not measured" and "earlier run" in rows[3]["reason"]
    assert all(r["met"] == "not measured" for r in (rows[1], rows[4], rows[5]))


def test_a_row_measured_at_full_size_in_a_quick_run_is_not_marked_quick(tmp_path):
    since = time.time() - 1.0
    rows = [_row("loop_analysis", quick=False), _row("robust_check")]
    _common.write_goal_rows(str(tmp_path), "bench_fast", rows, quick=True)
    t = run_all.issue_table(tmp_path, since)
    assert "--quick" not in t[0]["work"] and "--quick" in t[1]["work"]


def test_write_goal_rows_rejects_an_incomplete_or_unknown_row(tmp_path):
    with pytest.raises(ValueError, match="missing"):
        _common.write_goal_rows(str(tmp_path), "x", [{"id": "loop_analysis"}], quick=False)
    with pytest.raises(ValueError, match="unknown id"):
        _common.write_goal_rows(str(tmp_path), "x", [_row("loop")], quick=False)


def test_a_section_goal_line_fills_a_row_without_json(tmp_path):
    sec = _common.Section("throughput")
    sec.goal("fit_nls_batch (B = 64) ≥ 4× a Python loop of fit_nls", "5.1× wall | x", True)
    sec.goal("log-prob ≥ 20× numpy", "3×", False)  # not an issue row
    rows = run_all.issue_table(tmp_path, time.time(), [sec])
    assert rows[4]["met"] == "yes" and rows[4]["ratio"] == "5.1× wall / x"
    assert "goal line" in rows[4]["reason"]
    assert sum(r["met"] == "not measured" for r in rows) == 5
