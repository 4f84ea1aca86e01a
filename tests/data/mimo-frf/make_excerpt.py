"""Rebuild ``mimo_excerpt.npz`` from the public MIMO-FRF sample data (not run by the tests).

Usage: python make_excerpt.py /path/to/MIMO-FRF/sample_data

Takes ``symexc_1.mat`` (inputs in phase) and ``asymexc_1.mat`` (inputs in opposite phase) as
two experiments, keeps t = 50–80 s of the 100 s logarithmic chirp (about 6.6–53 Hz), and
decimates by 8 (scipy.signal.decimate, FIR anti-alias filter, zero phase) to 125 Hz. Stored
as a hapid time-series file: fs_hz, force = the commanded inputs (V), response = the measured
outputs (accelerometer volts), both (E = 2, T, n = 2) float32, with units force_unit = "V",
length_unit = "V·s²" (the response is an acceleration in volts: x = a/(jω)²).
"""

import sys
from pathlib import Path

import numpy as np
from scipy.io import loadmat
from scipy.signal import decimate

FS, Q, T0, T1 = 1000.0, 8, 50.0, 80.0


def main(src: str, out: str = str(Path(__file__).with_name("mimo_excerpt.npz"))) -> None:
    F, Y = [], []
    for name in ("symexc_1", "asymexc_1"):
        d = loadmat(Path(src) / f"{name}.mat")
        sl = slice(int(T0 * FS), int(T1 * FS))
        F.append(decimate(d["inputvalues"][sl], Q, ftype="fir", zero_phase=True, axis=0))
        Y.append(decimate(d["outputvalues"][sl], Q, ftype="fir", zero_phase=True, axis=0))
    np.savez_compressed(
        out,
        fs_hz=np.float64(FS / Q),
        force=np.stack(F).astype(np.float32),
        response=np.stack(Y).astype(np.float32),
        force_unit=np.asarray("V"),
        length_unit=np.asarray("V·s²"),
    )
    print(f"wrote {out} ({Path(out).stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main(*sys.argv[1:])
