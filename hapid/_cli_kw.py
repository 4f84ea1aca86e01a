"""How the ``hapid`` commands turn their parsed options into library keyword arguments — one
place, shared by the commands and by ``hapid design`` (which parses the same commands)."""

from __future__ import annotations

from ._cli_device import device_from_args


def device_or_none(a):
    """The device of ``--device`` and its variant options (None without ``--device``)."""
    return None if a.device is None else device_from_args(a)


def posterior_kw(a) -> dict:
    """The options of ``hapid posterior`` (parsed ``a``) for
    :func:`hapid.uncertainty.posterior_from_files`, files aside."""
    from .uncertainty import (  # local: CLI start-up: hapid.uncertainty (~0.7 s)
        GP,
        MODEL_ERRORS,
        model_error_from,
    )

    gp = issubclass(MODEL_ERRORS[a.model_error], GP)
    error = model_error_from(a.model_error, gp_hyper=a.gp_hyper if gp else None,
                             error_scale=a.error_scale)  # fmt: skip
    return dict(
        method=a.method, n_samples=a.samples, n_steps=a.steps, seed=a.seed,
        backend_path=a.hdf5, fit_options={"f_max_hz": a.f_max_hz, "max_steps": a.max_steps},
        posterior_options={"model_error": error},
        sampler_options={"moves": a.moves} | ({"n_walkers": a.walkers} if a.walkers else {}),
        fix_boundary=not a.free_boundary, boundary_refit=not a.keep_boundary,
    )  # fmt: skip


def robust_metrics(a):
    """``robust_check``'s ``metrics`` for ``hapid robust --all-metrics``."""
    return "all" if a.all_metrics else ()


def tune_kw(a) -> dict:
    """The options of ``hapid tune`` (parsed ``a``) for :func:`hapid.tune.tune_from_files`,
    the model, samples and output files aside."""
    g0 = None
    if a.extra_lag or a.extra_notch:  # a richer template: the paper g plus identity terms
        from .control import Compensator  # local: CLI start-up (hapid.io, equinox)
        from .tune import extend_structure  # local: CLI start-up (hapid.tune, ~0.8 s)

        g0 = extend_structure(Compensator.paper(), lag_hz=a.extra_lag or (),
                              notch_hz=a.extra_notch or ())  # fmt: skip
    from .tune import Recipe  # local: CLI start-up (hapid.tune, ~0.8 s)

    recipe = Recipe(n_train=a.n_train, n_holdout=a.n_holdout, quantile=a.quantile,
                    n_subjects=a.subjects, seed=a.seed, max_steps=a.max_steps,
                    keep_dc_gain=not a.free_dc, evidence_bandwidth=a.evidence_bandwidth)  # fmt: skip
    return dict(device=device_or_none(a), frf=a.frf, g0=g0,
                ts=None if a.fs is None else 1.0 / a.fs, recipe=recipe,
                model_error=a.predictive, draws="loop_gp" if a.loop_draws else a.draws)  # fmt: skip


def uncertified_warning(row: dict) -> str:
    """One warning line when the returned design's re-check row says the evidence does not
    certify it (``certified`` False, :func:`hapid.tune._evidence.certificate`), else ``""``."""
    if row.get("certified", True):
        return ""
    return (f"WARNING: the returned g is NOT certified by the evidence (measured loci min |1 + λ| "
            f"{row.get('frf_min_loci_distance', float('nan')):.3g}, floor 0.5; loop gain beyond "
            f"{row.get('evidence_hz', float('nan')):.3g} Hz {row.get('beyond_loop_gain', float('nan')):.3g}, "
            "bound 0.5; nominal loop stable: "
            f"{row.get('nominal_stable')}): the measured FRF cannot exclude a crossing of −1 "
            "between its frequencies, so the real loop may be unstable. Measure the FRF densely "
            "around the crossover and tune on it (hapid simulate --freqs 1,2,...).")  # fmt: skip
