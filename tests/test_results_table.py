"""The README's results table ("What you get on the default device") is what ``hapid paper``
computes. The expected numbers are parsed from README.md itself, so the README and the code
cannot drift apart silently.

Tolerances (the README rounds; a stated tolerance is half a unit of its last digit plus a
small allowance): dB values ± 0.06 dB, degrees ± 0.6°, bandwidths ± 0.006 Hz (two decimals
printed), peak frequencies ± 0.06 Hz; the tuned-g column (the result of an optimization) ±
0.05 Hz, ± 0.1 dB, ± 1°.

The fast test checks the rows that need neither a controller nor the NLS fit (plant span,
WLS P·P̂⁻¹ band); the slow test runs the whole paper scene (tuned g included) and checks
every cell.
"""

import re
from pathlib import Path

import numpy as np
import pytest

import hapid  # noqa: F401  (float64)
from hapid import scene

README = Path(__file__).resolve().parent.parent / "README.md"
NUM = r"[−+-]?\d+(?:\.\d+)?"


def _num(s: str) -> float:
    return float(s.replace("−", "-"))


def readme_table() -> dict[str, list[str]]:
    """``{quantity: [paper, wls, nls, tuned]}`` from the README's results table."""
    text = README.read_text()
    sec = text.split("## What you get on the default device", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in sec.splitlines():
        if line.startswith("|") and not line.startswith("|---") and "quantity" not in line:
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            rows[cells[0]] = cells[1:] + [""] * (5 - len(cells))
    return rows


def _pair(cell: str) -> tuple[float, float]:
    a, b = re.findall(NUM, cell)[:2]
    return _num(a), _num(b)


def _check_bands(t, res, cols):
    from hapid.fit import pphat_band_db
    from hapid.impedance import span_db

    dev, frf = res["device"], res["frf"]
    w = np.asarray(frf.omega)
    P = np.asarray(dev.sampled_P(w))
    band = np.asarray(frf.freq_hz) <= 30.0
    span = np.asarray(span_db(P))[band]
    lo, hi = _pair(t["plant singular-value span, 1–30 Hz"][1])
    assert span.min() == pytest.approx(lo, abs=0.06) and span.max() == pytest.approx(hi, abs=0.06)
    for col, key in cols:
        elo, ehi = _pair(t["P·P̂⁻¹ band to 30 Hz"][col])
        blo, bhi = (float(x) for x in pphat_band_db(P, res[key]["model"], w, 30.0))
        assert blo == pytest.approx(elo, abs=0.06), key
        assert bhi == pytest.approx(ehi, abs=0.06), key


def test_readme_table_parses():
    t = readme_table()
    assert {"plant singular-value span, 1–30 Hz", "P·P̂⁻¹ band to 30 Hz", "MIMO iso-bandwidth",
            "MIMO GM / PM", "peak of σ̄(T)"} <= set(t)  # fmt: skip


def test_plant_span_and_wls_pphat_band_match_the_readme(tmp_path):
    res = scene.run_scene(
        scene.merge({}), ["device", "frf", "wls"], out_dir=tmp_path, cache_dir=None
    ).results
    _check_bands(readme_table(), res, [(1, "wls")])


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_whole_results_table_matches_the_readme(tmp_path):
    t = readme_table()
    res = scene.run_scene(scene.merge({}), ["summary"], out_dir=tmp_path, cache_dir=None).results
    _check_bands(t, res, [(1, "wls"), (2, "nls")])
    s = res["summary"]
    assert s.ok, s.status
    cols = {1: s.fits["wls"]["mimo"], 2: s.fits["nls"]["mimo"], 3: s.tuned["mimo"]}
    for col, m in cols.items():
        tuned = col == 3
        assert m["stable"]
        bw = _num(re.findall(NUM, t["MIMO iso-bandwidth"][col])[0])
        assert m["iso_bandwidth_hz"] == pytest.approx(bw, abs=0.05 if tuned else 0.006), col
        gm, pm = _pair(t["MIMO GM / PM"][col])
        assert m["gm_db"] == pytest.approx(gm, abs=0.1 if tuned else 0.06), col
        assert m["pm_deg"] == pytest.approx(pm, abs=1.0 if tuned else 0.6), col
        pk, pk_hz = _pair(t["peak of σ̄(T)"][col])
        assert m["t_peak_db"] == pytest.approx(pk, abs=0.1 if tuned else 0.06), col
        # the tuned loop's σ̄(T) has two near-equal maxima (4.30 dB at 17.3 Hz, 4.40 dB at
        # 25.3 Hz, README history) and a flat top at 25 Hz: with its value held to 0.1 dB
        # above, the location moves by a few tenths of a hertz with the BLAS (25.06 Hz on
        # 2026-12-07); a jump to the other maximum still fails
        assert m["t_peak_hz"] == pytest.approx(pk_hz, abs=0.5 if tuned else 0.06), col
    siso = _num(re.findall(NUM, t["SISO iso-bandwidth (6 dB / 30° gain)"][1])[0])
    assert s.siso["design rule"]["iso_bandwidth_hz"] == pytest.approx(siso, abs=0.006)
