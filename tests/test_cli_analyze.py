"""``hapid analyze``: --design, --continuous, the fs/2 check, strict JSON on an unstable loop."""

import json

import numpy as np
import pytest

import hapid  # noqa: F401  (float64)
from hapid import io, pipeline
from hapid.cli import main
from hapid.control import Compensator
from hapid.device import cu5
from hapid.frf import as_frf
from hapid.impedance import ImpedanceModel, SecondOrder
from hapid.tune import save_design


def _strict(text):
    def bad(c):
        raise ValueError(f"non-JSON constant {c}")

    return json.loads(text, parse_constant=bad)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("an")
    eye = np.eye(5)  # a simple PD 5-rod model (cheap; the device closes the loop)
    hand = SecondOrder(0.3 * eye, 5.0 * eye, 400.0 * eye)
    model = ImpedanceModel.from_hand_mechanism(hand, SecondOrder(0.5 * eye, 30.0 * eye, 0.0 * eye))
    io.save_model(d / "m.npz", model, method="rigid")
    save_design(d / "g.npz", Compensator.paper(k=0.4))
    f = np.array([1.0, 5.0, 20.0, 60.0, 100.0])
    s = 2j * np.pi * f[:, None, None]
    ZH = 0.3 * s**2 * eye + 5.0 * s * eye + 400.0 * eye
    io.save_frf(d / "frf.npz", as_frf(f, ZH, ZH + 0.5 * s**2 * eye + 30.0 * s * eye))
    return d, model


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_analyze_design_continuous_and_unstable_report(files, capsys):
    d, model = files
    assert main(["analyze", "--model", str(d / "m.npz"), "--device", "cu5", "--design", str(d / "g.npz"),
                 "--out", str(d / "r1.json")]) == 0  # fmt: skip
    r1 = _strict((d / "r1.json").read_text())
    assert r1["design"].endswith("g.npz") and not r1["continuous"]
    # the same loop through the pipeline stages directly (k = 0.4 from the design file)
    dev = cu5()
    om = pipeline.analysis_grid(1e-3, 1500, dev.fs_hz)
    ref = pipeline.loop(pipeline.controller(model, Compensator.paper(k=0.4), ts=dev.ts),
                        pipeline.device_plant(dev, om)).numbers()  # fmt: skip
    assert r1["stable"] == ref["stable"]
    if ref["stable"]:
        assert r1["iso_bandwidth_hz"] == pytest.approx(ref["iso_bandwidth_hz"], rel=1e-9)
    assert main(["analyze", "--model", str(d / "m.npz"), "--device", "cu5", "--continuous",
                 "--out", str(d / "r2.json")]) == 0  # fmt: skip
    r2 = _strict((d / "r2.json").read_text())
    assert r2["continuous"] and "continuous-time" in capsys.readouterr().out
    # an unstable loop still writes strictly valid JSON (no NaN / Infinity)
    assert main(["analyze", "--model", str(d / "m.npz"), "--device", "cu5", "--k", "40",
                 "--out", str(d / "r3.json")]) == 0  # fmt: skip
    r3 = _strict((d / "r3.json").read_text())
    assert r3["stable"] is False and r3["iso_bandwidth_hz"] is None


def test_frf_beyond_the_sampled_nyquist_frequency_is_a_clear_error(files, capsys):
    d, _ = files
    out = d / "never.json"
    rc = main(["analyze", "--model", str(d / "m.npz"), "--frf", str(d / "frf.npz"), "--fs", "150",
               "--out", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and "fs/2 = 75 Hz" in err and err.count("\n") == 1 and not out.exists()
