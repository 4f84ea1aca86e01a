"""Numerical constants used across hapid (one definition each).

Plain Python floats (no numpy/JAX import), so that light modules such as the CLI can use them
without paying an array-library import.
"""

import math

#: 2π — converts Hz to rad/s (``omega = TWO_PI * f_hz``).
TWO_PI = 2.0 * math.pi

#: Fraction of the sampling frequency at which log-spaced analysis grids of sampled systems stop
#: (just below Nyquist, f_s/2; the Nyquist point itself is appended separately).
BELOW_NYQUIST = 0.49999

#: Coherence γ² below this is reported as low (H1 estimates: noise, leakage or nonlinearity).
COHERENCE_LOW = 0.9

#: Small-gain level κ: beyond the measured band a loop with σ̄(L) ≤ κ has |1 + λ| ≥ 1 − κ, so
#: GM ≥ 6 dB at any crossing there (κ = 1/2); used by the tuner's evidence and analyze's check.
KAPPA = 0.5

#: Wall time (s) of ``hapid tune`` with its defaults on cu5 (150 training / 200 held-out draws,
#: 3–4 continuation stages stopped at ``defaults.TUNE_TOL``, re-check): 47 s (43–51) measured
#: through the CLI on an idle 2-core machine, warm, by ``benchmarks/bench_route.py``
#: (benchmarks/README.md); 41–96 s over the study devices. The "expected" time of its
#: progress report and ``--help``.
TUNE_EXPECTED_S = 60.0

#: Wall time (s) of ``hapid robust`` with its defaults (one model, 1000 loop draws on 1000
#: frequencies): 13.5 s (13.2–13.8) warm on a 2-core machine, ~56 s on the first run (compiles),
#: by ``benchmarks/bench_route.py`` (benchmarks/README.md). The "expected" time of its progress.
ROBUST_EXPECTED_S = 15.0
