"""Every default hapid uses in more than one place, written once.

Commands, scenes, estimators and checks read their defaults from here, so that every estimator
and command shares the fit band unless told otherwise. Units: Hz, dB, degrees, counts.
"""

FIT_BAND_HZ = 40.0
"""Upper edge (Hz) of the band every model fit uses unless told otherwise: NLS, ML, the
posterior, predictive draws and the scenes' fits. A second-order model fitted over the whole
1–100 Hz FRF of a device with a delay and chain modes bends to the misfit above ~40 Hz. The
paper's closed-form WLS keeps every frequency (as in the paper) unless a band is given."""

GM_DB = 6.0
"""Required gain margin (dB) of a robust check, a tuned design and the SISO gain rule."""

PM_DEG = 30.0
"""Required phase margin (degrees)."""

FS_HZ = 1000.0
"""Sampling rate (Hz) of the simulated device, its experiments and sampled-loop analyses."""

N_DRAWS = 1000
"""Loop or parameter draws in a robust check."""

DRAWS = ("auto", "loop_gp", "params")
"""The draw families of ``--draws`` (``hapid robust``, ``hapid tune``, ``hapid predict``):
``loop_gp`` (the loop conditioned on the measured FRF), ``params`` (the posterior's parameter
draws), ``auto`` (``loop_gp`` when the measured FRF is known). ``hapid predict`` offers
``params`` (its default: the band measured calibrated) and ``loop_gp``."""

NLS_MAX_STEPS = 500
"""Step limit of the NLS fit of ``hapid fit`` and of the fit ``hapid posterior`` centres on."""

NPERSEG = 2048
"""Samples per Welch segment of an H1 estimate (``hapid frf --h1`` on non-periodic records)."""
