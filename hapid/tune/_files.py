"""Design files (``.npz``) and the file-level entry point of ``hapid tune``.

Design file: ``k ()``, ``lag_zeros (q,)``, ``lag_poles (q,)``, ``notch_omega (m,)``,
``notch_zeta_num (m,)``, ``notch_zeta_den (m,)``, ``lowpass (r,)`` — rad/s and
dimensionless, the fields of :class:`hapid.control.Compensator` — plus ``json`` (a string:
:meth:`.RobustDesign.summary`).
"""

from __future__ import annotations

from .. import io
from ..defaults import DRAWS
from ..device import preset
from ..io import load_design as load_design
from ..io import load_samples
from ..io import save_design as save_design
from ..uncertainty._draws import draws_from
from ._recipe import Recipe, RobustDesign, robust_design


def tune_from_files(model_path, samples_path=None, out=None, *, device=None, frf=None,
                    draws: str = "auto", model_error: bool = False, g0=None, requirements=None,
                    recipe: Recipe | None = None, ts: float | None = None,
                    progress=None) -> RobustDesign:  # fmt: skip
    """Load a model (and samples, and the measured FRF ``frf`` — the evidence), run
    :func:`.robust_design`, write the design file ``out``. ``device``: a preset name or a
    device.

    Without ``frf`` the measured FRF a samples file from ``hapid posterior`` stores
    (``PosteriorSamples.measured``, every measured frequency; older files: the fit data) is
    the evidence. ``draws`` (:func:`hapid.uncertainty.draws_from`): ``"loop_gp"`` (the loop
    conditioned on that FRF), ``"params"`` (the samples' own plants; with ``model_error``
    their posterior-predictive plants) or ``"auto"`` (``loop_gp`` when a measured FRF is
    known). The other keywords are :func:`.robust_design`'s. Raises ``ValueError`` for an
    unknown ``draws`` (before any file is read) or draws the files cannot give."""

    if draws not in DRAWS:  # before any file is read
        raise ValueError(f"draws must be one of {DRAWS}, got {draws!r}")
    model = io.load_model(model_path)
    measured = None if frf is None else io.load_frf(frf)
    samples = None if samples_path is None else load_samples(samples_path, n=model.n)
    if measured is None and samples is not None:
        measured = samples.measured
    evidence = measured if measured is not None else getattr(samples, "predictive", None)
    source = None
    if samples is not None or measured is not None or draws != "auto":
        source = draws_from(draws, samples=samples, measured=measured, model_error=model_error)
    dev = preset(device) if isinstance(device, str) else device
    res = robust_design(model, source, evidence=evidence, device=dev, g0=g0,
                        requirements=requirements, recipe=recipe, ts=ts, progress=progress)  # fmt: skip
    if out is not None:
        save_design(out, res.g, **res.summary())
    return res
