"""A phase margin decided in a measurement gap is "not established", never "passed".

The loop draws interpolate the measured FRF; between two measured frequencies far apart a
true locus can turn a few degrees more than the draws show (docs/robust-design.md, E6). So
when the draws' ``|PM|`` 5 % quantile clears the requirement by less than
:data:`hapid.defaults.GAP_PM_DEG` and the crossovers that decide it lie in such a gap, the
verdict of ``hapid robust`` (:func:`hapid.uncertainty._cover.cover_check`) and of ``hapid tune``
(:func:`hapid.tune._check.design_check`) is ``not established``, with the band to measure.
"""

import dataclasses

import numpy as np
import pytest

from hapid.defaults import GAP_PM_DEG, GAP_RATIO
from hapid.tune._check import design_check
from hapid.uncertainty import RobustReport
from hapid.uncertainty._cover import EvidenceCover, deciding_pm_hz, gap_check
from hapid.verdict import Verdict

PAPER_HZ = tuple(range(1, 11)) + tuple(range(15, 101, 5))  # the paper protocol's frequencies
DENSE_HZ = tuple(float(f) for f in range(1, 101))  # every 1 Hz


def _report(pm_deg, pm_hz):
    """Stable draws with GM 10 dB and the given ``|PM|`` and gain-crossover frequencies."""
    pm = np.asarray(pm_deg, dtype=float)
    one = np.ones_like(pm)
    return RobustReport(stable=one.astype(bool), n_closed_loop_rhp=0 * one, gm_db=10 * one,
                        pm_deg=pm, disk_margin=one, disk_gm_db=one, disk_pm_deg=one,
                        iso_bandwidth_hz=one, t_peak_db=one, gm_freq_hz=60 * one,
                        pm_freq_hz=np.broadcast_to(np.asarray(pm_hz, float), pm.shape))  # fmt: skip


def _cover(freqs):
    return EvidenceCover((1.0, 100.0), 0.3, 0.5, 100.0, 1.0, "continuous-time controller",
                         tuple(float(f) for f in freqs))  # fmt: skip


def test_gap_rule_fires_only_inside_a_wide_gap_and_near_the_requirement():
    # between 15 and 20 Hz (ratio 1.33 > GAP_RATIO), 1.9° above 30°: not established
    reason, remedy = gap_check(31.9, 30.0, 16.4, PAPER_HZ)
    assert "15" in reason and "20" in reason and "31.9" in reason
    assert remedy.startswith("measure the FRF between 15 and 20 Hz") and "every 1 Hz" in remedy
    assert gap_check(30.0 + GAP_PM_DEG, 30.0, 16.4, PAPER_HZ) is None  # clears the allowance
    assert gap_check(29.0, 30.0, 16.4, PAPER_HZ) is None  # below it: the check failed already
    assert gap_check(31.9, 30.0, 9.5, PAPER_HZ) is None  # 9–10 Hz: ratio 1.11 ≤ GAP_RATIO
    assert gap_check(31.9, 30.0, 16.4, DENSE_HZ) is None  # 16–17 Hz: measured densely
    assert gap_check(31.9, 30.0, 15.0, PAPER_HZ) is None  # at a measured frequency
    assert gap_check(31.9, 30.0, 150.0, PAPER_HZ) is None  # outside the band: the band rules
    assert gap_check(31.9, 30.0, float("nan"), PAPER_HZ) is None  # no crossover
    # the ratio is the threshold: a gap exactly GAP_RATIO wide is not a gap
    assert gap_check(31.9, 30.0, 10.5, (10.0, 10.0 * GAP_RATIO)) is None
    assert gap_check(31.9, 30.0, 10.5, (10.0, 10.0 * GAP_RATIO * 1.01)) is not None


def test_robust_verdict_is_not_established_in_a_gap_and_passed_when_measured_densely():
    rng = np.random.default_rng(0)
    pm = 31.5 + 4.0 * rng.random(1000)  # 5 % quantile ≈ 31.7°: within 3° of 30°
    rep = _report(pm, 16.4)
    assert deciding_pm_hz(rep) == pytest.approx(16.4)
    paper = dataclasses.replace(rep, cover=_cover(PAPER_HZ))
    ck = paper.check
    assert ck.verdict is Verdict.NOT_ESTABLISHED
    assert "between 15 and 20 Hz" in ck.remedy and "16.4 Hz" in ck.reason
    assert paper.summary()["evidence"]["frequencies_hz"][:3] == [1.0, 2.0, 3.0]
    dense = dataclasses.replace(rep, cover=_cover(DENSE_HZ))
    assert dense.check.verdict is Verdict.PASSED
    # a margin clear of the allowance passes on the paper's frequencies too
    wide = dataclasses.replace(_report(pm + GAP_PM_DEG, 16.4), cover=_cover(PAPER_HZ))
    assert wide.check.verdict is Verdict.PASSED
    # a failed check stays failed (the gap rule never turns a failure into anything else)
    low = dataclasses.replace(_report(pm - 5.0, 16.4), cover=_cover(PAPER_HZ))
    assert low.check.verdict is Verdict.FAILED


def test_tune_verdict_applies_the_gap_rule_unless_a_true_plant_settles_it():
    kw = dict(gm_db=6.0, pm_deg=30.0, quantile=0.975)
    row = {"nominal_stable": True, "frf_min_loci_distance": 0.7, "beyond_loop_gain": 0.3,
           "evidence_hz": 100.0, "certified": True, "posterior_frac_meeting_margins": 1.0,
           "posterior_pm_deg_q05": 31.9, "posterior_pm_deciding_hz": 16.4}  # fmt: skip
    ck = design_check(row, **kw, frequencies_hz=PAPER_HZ)
    assert ck.verdict is Verdict.NOT_ESTABLISHED and "between 15 and 20 Hz" in ck.remedy
    assert design_check(row, **kw, frequencies_hz=DENSE_HZ).verdict is Verdict.PASSED
    assert design_check(row, **kw).verdict is Verdict.PASSED  # frequencies unknown
    true = row | {"true_stable": True, "true_gm_db": 8.0, "true_pm_deg": 32.0}
    assert design_check(true, **kw, frequencies_hz=PAPER_HZ).verdict is Verdict.PASSED


def test_gap_ratio_is_wider_than_the_dense_protocols_spacing():
    """The rule's threshold leaves 1 Hz steps above 5 Hz (ratios ≤ 1.2) out of it, and takes
    the paper's 5 Hz steps from 10 to 25 Hz in."""
    f = np.asarray(PAPER_HZ, float)
    gaps = [(a, b) for a, b in zip(f[:-1], f[1:], strict=True) if b / a > GAP_RATIO]
    assert (10.0, 15.0) in gaps and (15.0, 20.0) in gaps and (20.0, 25.0) in gaps
    assert all(b / a <= GAP_RATIO for a, b in zip(DENSE_HZ[4:-1], DENSE_HZ[5:], strict=True))
