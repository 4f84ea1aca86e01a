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
