"""Write examples/hammer_series.npz: five synthetic impact-hammer hits (one record each,
fs 25.6 kHz, 0.25 s per hit) on a structure with modes at 900 Hz (ζ 5e-3) and 2640 Hz
(ζ 2e-3), force in N and acceleration in m/s², noise on both channels. Its exact impedance is
``hapid.experiment._hammer.modal_impedance(f, MODES)``.

    python examples/make_hammer_series.py
"""

from pathlib import Path

from hapid import io
from hapid.experiment._hammer import hammer_records

MODES = ((900.0, 5e-3, 0.5), (2640.0, 2e-3, 0.8))

if __name__ == "__main__":
    ts = hammer_records(modes=MODES, hit_spacing_s=0.25, separate=True, seed=7)
    print(io.save_timeseries(Path(__file__).with_name("hammer_series.npz"), ts))
