"""Every default hapid uses in more than one place, written once.

Commands, scenes, estimators and checks read their defaults from here, so that every estimator
and command shares the fit band unless told otherwise. Units: Hz, dB, degrees, counts.
"""

FIT_BAND_HZ = 40.0
"""Upper edge (Hz) of the band every model fit uses unless told otherwise: NLS, ML, the
posterior, predictive draws and the scenes' fits; the paper's WLS keeps every frequency unless
a band is given. Why: docs/conventions.md, "Fits"; docs/robust-design.md, Evidence E12."""

GM_DB = 6.0
"""Required gain margin (dB) of a robust check, a tuned design and the SISO gain rule."""

PM_DEG = 30.0
"""Required phase margin (degrees) of a robust check, a tuned design and the SISO gain rule."""

PPHAT_BAND_HZ = 30.0
"""Upper edge (Hz) of the band over which the P·P̂⁻¹ band (dB) and the anisotropy reduction are
read (the paper's "to 30 Hz"): ``hapid fit --band-hz``, ``hapid paper``, ``hapid design``, the
scenes' ``analysis.band_hz`` and :func:`hapid.fit.pphat_band_db` callers."""

CONTINUOUS_BAND_HZ = (5e-3, 5e3)
"""Frequency span (Hz) of a continuous-time loop analysis (``hapid analyze --continuous``): far
below the lowest and above the highest dynamics of the devices, so the Nyquist count closes."""

FS_HZ = 1000.0
"""Sampling rate (Hz) of the simulated device, its experiments and sampled-loop analyses."""

N_DRAWS = 1000
"""Loop or parameter draws in a robust check (``hapid robust``/``hapid design --max-samples``,
``hapid.robust``)."""

DRAWS = ("auto", "loop_gp", "params")
"""The draw families of ``--draws`` (``hapid robust``, ``hapid tune``, ``hapid predict``):
``loop_gp`` (the loop conditioned on the measured FRF), ``params`` (the posterior's parameter
draws), ``auto`` (``loop_gp`` when the measured FRF is known). ``hapid predict`` offers
``params`` (its default: recalibrated on the leave-one-frequency-out check, the band measured
calibrated on 3–6 rods; as drawn, ``--no-recalibrate``, too narrow at 16–40 Hz on 6 rods) and
``loop_gp``."""

NLS_MAX_STEPS = 2000
"""Step limit of the NLS and ML fits (``hapid fit``, the fit ``hapid posterior`` centres on, the
scenes, ``hapid.fit.fit_nls``/``fit_ml``/``fit_impedance``). A fit that converges stops early, so
the limit costs time only on a fit that would fail anyway; a 6-rod pair needs ~1300 steps."""

NLS_SOLVER = "lm"
"""Solver of the NLS and ML fits, by the name the CLI (``--solver``) and the scenes
(``fit.solver``) use: optimistix Levenberg–Marquardt. The library takes solver objects;
``hapid.fit.solver_from`` maps names to them and ``hapid.fit.DEFAULT_SOLVER`` is this one with
the two tolerances and the linear solver below."""

NLS_RTOL = 1e-8
"""Relative Cauchy tolerance of the fits' solver (on the parameters, scaled units)."""

NLS_ATOL = 1e-10
"""Absolute Cauchy tolerance of the fits' solver (on the residuals, scaled units)."""

NLS_LINEAR_SOLVER = "cholesky"
"""Linear solver of the least-squares fits' steps: the Cholesky normal equations (``"qr"`` is
optimistix's default). Why: docs/conventions.md, "CPU pitfalls"."""

NPERSEG = 2048
"""Samples per Welch segment of an H1 estimate (``hapid frf --h1`` on non-periodic records)."""

TUNE_TOL = 1e-3
"""Relative and absolute tolerance of the tuner's continuation stages (the BFGS Cauchy test on
the objective and the log-parameters) when a family is chance-constrained (posterior or loop
draws): stopping early keeps the tuner from fitting the training draws' tail. Used by
``hapid.tune``. Why: docs/robust-design.md, Evidence E5."""

TUNE_PM_ALLOWANCE_DEG = 3.0
"""Degrees added to the phase-margin requirement the tuner *trains* on when a family is
chance-constrained (posterior or loop draws); worst-case families (device variants) train on
the requirement itself, and the re-check and the verdict keep the requirement asked for. Used
by ``hapid.tune``. Why: docs/robust-design.md, Evidence E6 ("One loop for training and
re-check")."""

GAP_RATIO = 1.2
"""Two consecutive measured frequencies further apart than this ratio leave a *measurement gap*
between them: a phase margin the draws decide there is read from their interpolation. Used by
the verdicts of ``hapid robust`` and ``hapid tune`` (:func:`hapid.uncertainty._cover.gap_check`).
Why: a locus's phase between two measured points was seen to turn 4–5° more than the loop draws
show across a 1.33 ratio (15 → 20 Hz); an interpolation error grows about as the square of the
gap's width in ln ω, so across 1.2 it is about (ln 1.2 / ln 1.33)² ≈ 0.4 of that, ≈ 2°, inside
:data:`GAP_PM_DEG` (docs/robust-design.md, Evidence E6)."""

GAP_PM_DEG = TUNE_PM_ALLOWANCE_DEG
"""Degrees by which a phase margin decided in a measurement gap (:data:`GAP_RATIO`) must exceed
the requirement for the verdict to be ``passed``; below that (and above the requirement) it is
``not established``, with the frequencies to measure. The same figure as the tuner's training
allowance: the largest shortfall between measured points seen on the true plants
(docs/robust-design.md, Evidence E6)."""

TUNE_TOL_WORST = 1e-8
"""The same tolerance when every family is worst-case (quantile 1: the device's variants of
``hapid paper``'s tuned column): no draws to over-fit, and a loose solve leaves the penalty's
constraints unmet. Why: docs/robust-design.md, Evidence E5."""

TUNE_N_TRAIN = 150
"""Training draws of the tuner's chance constraint (``hapid tune --n-train``)."""

TUNE_N_HOLDOUT = 200
"""Held-out draws the tuned and the start g are re-checked on (``hapid tune --n-holdout``)."""

TUNE_QUANTILE = 0.975
"""Fraction of the draws on which a tuned design must meet the margins (chance level)."""

TUNE_N_SUBJECTS = 16
"""Virtual subjects among a device's training variants (``hapid tune --subjects``)."""

TUNE_MAX_STEPS = 300
"""BFGS steps per continuation stage of the tuner (``hapid tune --max-steps``)."""
