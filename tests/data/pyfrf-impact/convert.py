"""Write impact_series.npz from pyFRF 1.1.4's ``data/impact2_response0.lvm``.

The source is the sdist ``pyfrf-1.1.4.tar.gz`` on PyPI (MIT licence, ./LICENSE). The LabVIEW
text file holds five triggered impact-hammer records (51 200 samples each at 51.2 kHz,
force in N, acceleration in m/s²). They are stored unchanged except for the cast to float32
(the file prints six decimals, so float32 keeps every value to < 1 part in 10⁶).

    python tests/data/pyfrf-impact/convert.py path/to/impact2_response0.lvm
"""

import sys
from pathlib import Path

import numpy as np


def read_lvm(path) -> tuple[np.ndarray, float]:
    """The records of a two-channel LabVIEW .lvm file: ``(E, N, 2)`` and the sample rate in Hz."""
    records, rows, dt = [], [], None
    for line in Path(path).read_text().splitlines():
        cells = line.split("\t")
        if cells[0] == "Delta_X":
            dt = float(cells[1])
        if len(cells) >= 3 and cells[0] == "":
            try:
                rows.append((float(cells[1]), float(cells[2])))
                continue
            except ValueError:
                pass
        if rows:
            records.append(np.array(rows))
            rows = []
    if rows:
        records.append(np.array(rows))
    return np.stack(records), 1.0 / dt


if __name__ == "__main__":
    data, fs = read_lvm(sys.argv[1])
    out = Path(__file__).with_name("impact_series.npz")
    np.savez_compressed(out, fs_hz=np.float64(fs), force=data[..., :1].astype(np.float32),
                        response=data[..., 1:].astype(np.float32), force_unit=np.asarray("N"),
                        length_unit=np.asarray("m"))  # fmt: skip
    print(out, data.shape, fs)
