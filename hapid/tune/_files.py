"""Design files (``.npz``) and the file-level entry point of ``hapid tune``.

Design file: ``k ()``, ``lag_zeros (q,)``, ``lag_poles (q,)``, ``notch_omega (m,)``,
``notch_zeta_num (m,)``, ``notch_zeta_den (m,)``, ``lowpass (r,)`` — rad/s and
dimensionless, the fields of :class:`hapid.control.Compensator` — plus ``json`` (a string:
tuning history, constraint values, validation table).
"""

from __future__ import annotations

from .. import io
from ..device import preset
from ..io import load_design as load_design
from ..io import load_samples
from ..io import save_design as save_design
from ..uncertainty._files import DRAWS, resolve_draws
from ._recipe import robust_design


def design_info(out: dict) -> dict:
    """The JSON-able part of a :func:`.robust_design` result."""
    r = out["result"]
    return {"bandwidth_claimed_hz": r.bandwidth_hz, "bandwidth0_claimed_hz": r.bandwidth0_hz,
            "constraints": r.constraints, "feasible": r.feasible, "history": r.history,
            "parameters": r.parameters(), "families": out["families"], "wall_s": r.wall_s,
            "table": out.get("table", {}), "loop": out.get("loop")} | (
                {} if out.get("check") is None else {"verdict": out["check"].verdict.value,
                "reason": out["check"].reason, "remedy": out["check"].remedy})  # fmt: skip


def tune_from_files(model_path, samples_path=None, out=None, *, device=None, frf=None,
                    draw_family: str = "auto", **options) -> dict:  # fmt: skip
    """Load a model (and samples, and the measured FRF ``frf`` — the evidence), run
    :func:`.robust_design`, write the design file. ``device``: a preset name or a device.

    Without ``frf`` the measured FRF a samples file from ``hapid posterior`` stores
    (``PosteriorSamples.measured``, every measured frequency) is the evidence. ``draw_family``:
    ``"loop_gp"`` (draws of ``Q = P P̂⁻¹`` conditioned on that FRF), ``"params"`` (the samples'
    own plants) or ``"auto"`` (default: ``loop_gp`` when a measured FRF is
    known, else the samples)."""

    if draw_family not in DRAWS:  # before any file is read
        raise ValueError(f"draw_family must be one of {DRAWS}, got {draw_family!r}")
    model = io.load_model(model_path)
    if frf is not None:
        options["frf"] = io.load_frf(frf)
    samples = None
    if samples_path is not None:
        samples = load_samples(samples_path, n=model.n)
        if frf is None and samples.measured is not None:
            options["frf"] = samples.measured
    kind = resolve_draws(draw_family, options.get("frf"))
    options["draw_family"] = kind
    dev = None
    if device is not None:
        dev = preset(device) if isinstance(device, str) else device
    res = robust_design(model, samples=samples, device=dev, **options)
    if out is not None:
        save_design(out, res["result"].g, **design_info(res))
    return res
