"""One fit band: `hapid fit RUN --method ml` with defaults fits the same band as `--method nls`
(hapid.defaults.FIT_BAND_HZ), on a run measured beyond that band."""

import re

import numpy as np
import pytest
from helpers_fit import random_truth

from hapid import io
from hapid.cli import main
from hapid.defaults import FIT_BAND_HZ
from hapid.device import SecondOrderDevice
from hapid.experiment import Protocol, estimate_frf, periodic_run

FREQ_HZ = (2.0, 5.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0)  # measured past the fit band


def _band(text: str) -> tuple[float, float, int]:
    m = re.search(r"band: ([0-9.]+)–([0-9.]+) Hz, (\d+) of", text)
    assert m, text
    return float(m.group(1)), float(m.group(2)), int(m.group(3))


@pytest.mark.slow  # three fits compile (~45 s of one core); make test-all runs it
def test_ml_and_nls_default_to_one_band(tmp_path, capsys):
    t = random_truth(2, 5)
    dev = SecondOrderDevice(hand=t.hand, mechanism=t.mechanism)
    run = periodic_run(dev, Protocol(freq_hz=FREQ_HZ, n_periods=3, pattern="hadamard",
                                     force_noise=0.01), hold="bandlimited")  # fmt: skip
    io.save_run(tmp_path / "run.npz", run)
    io.save_frf(tmp_path / "frf.npz", estimate_frf(run))
    bands = {}
    for method, src in (("ml", "run.npz"), ("nls", "frf.npz"), ("wls", "frf.npz")):
        out = tmp_path / f"{method}.npz"
        rc = main(["fit", str(tmp_path / src), "--method", method, "--allow-unconverged",
                   "--out", str(out)])  # fmt: skip
        assert rc == 0 and out.exists()
        bands[method] = _band(capsys.readouterr().out)
    assert bands["ml"] == bands["nls"]
    assert bands["nls"][1] <= FIT_BAND_HZ < max(FREQ_HZ)
    assert bands["nls"][2] == int(np.sum(np.asarray(FREQ_HZ) <= FIT_BAND_HZ))
    # the paper's WLS keeps every measured frequency unless told otherwise
    assert bands["wls"][1] == max(FREQ_HZ) and bands["wls"][2] == len(FREQ_HZ)


@pytest.mark.parametrize("method", ["nls", "ml"])
def test_model_fits_default_band_is_the_table_value(method):
    """The band rule behind `hapid fit`: NLS and ML on the haptic pair default to FIT_BAND_HZ;
    WLS and single impedances keep every frequency; an explicit --f-max-hz wins."""
    from argparse import Namespace

    from hapid._cli_fit import _default_f_max

    assert _default_f_max(Namespace(f_max_hz=None, method=method), pair=True) == FIT_BAND_HZ
    assert _default_f_max(Namespace(f_max_hz=None, method=method), pair=False) is None
    assert _default_f_max(Namespace(f_max_hz=25.0, method=method), pair=True) == 25.0
    assert _default_f_max(Namespace(f_max_hz=None, method="wls"), pair=True) is None
