"""The plants ``robust_design`` trains on and holds out: posterior draws as batched models
or sampled on a grid, posterior-*predictive* draws (model plus its model-error term, confined
to the fit band) and the device family's dense grid; and the stylus offsets of the device
family's training (``TRAIN_OFFSETS``, ±4 cm along x, y, z) and held-out (``HOLDOUT_OFFSETS``,
diagonal) poses, in metres.

Plants are frequency-first, ``(S, N, n, n)`` complex, on ω in rad/s.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import numpy as np

from .. import _config  # noqa: F401  (float64)
from .._grids import NYQUIST_F_MIN_HZ, below_nyquist_grid, log_grid_hz, nyquist_grid
from .._grids import continuous_grid as posterior_grid
from ..uncertainty import PosteriorSamples, device_plants, predictive_plants
from ..uncertainty._draws import LoopDraws, ParamDraws
from ..uncertainty._loopgp import loop_gp_plants
from ._objective import Family
from ._scenarios import make_scenarios

TRAIN_OFFSETS = (
    (0.04, 0, 0),
    (-0.04, 0, 0),
    (0, 0.04, 0),
    (0, -0.04, 0),
    (0, 0, 0.04),
    (0, 0, -0.04),
)
PREDICTIVE_TAPER = 0.1  # ln-ω width of the model-error taper beyond the fit band
HOLDOUT_OFFSETS = ((0.03, 0.03, 0), (-0.03, -0.03, 0), (0.03, 0, 0.03), (0, -0.03, -0.03))


def _sample_models(samples, idx):
    if isinstance(samples, PosteriorSamples):
        return samples.models(np.asarray(idx))
    return jax.tree.map(lambda a: a[np.asarray(idx)], samples)


def _n_models(samples) -> int:
    return (
        samples.n_samples
        if isinstance(samples, PosteriorSamples)
        else int(np.shape(samples.hand.M)[0])
    )


def _subset(samples, idx):
    return dataclasses.replace(samples, samples=samples.samples[np.asarray(idx)],
                               log_prob=np.asarray(samples.log_prob)[np.asarray(idx)])  # fmt: skip


def predictive_scenario_plants(samples, idx, omega, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(P (S, N, n, n), RHP poles)``: posterior-*predictive* plants of draws ``idx`` on ω —
    the second-order model of each draw plus its model-error term
    (:func:`hapid.uncertainty.predictive_plants`), so the tuner and the re-check see the
    misfit the data show (delay, unmodeled modes) and not only parameter uncertainty. The
    error term is confined to the fit band (``error_band``, taper ``PREDICTIVE_TAPER`` in
    ln ω): outside it the data say nothing about the error, and the GP's extrapolation (its
    prior) is a random perturbation the data do not support that flips the Nyquist count of
    loops crossing over just above the band (docs/robust-design.md, Evidence E12); there the
    draw is its second-order model. The RHP poles are those of the draw's model (0 for PD
    matrices)."""

    sub = _subset(samples, idx)
    om_fit = np.asarray(samples.predictive["omega"])
    P = predictive_plants(
        sub,
        omega,
        max_samples=None,
        seed=seed,
        error_band=(om_fit[0], om_fit[-1]),
        taper_width=PREDICTIVE_TAPER,
    ).P
    _, pol = posterior_plants(sub.models(), omega)
    return P, pol


class PosteriorPlants(NamedTuple):
    """Plants of a batch of models (:func:`posterior_plants`).

    - ``P``: ``(S, N, n, n)`` complex, each model's ``Ẑ_H Ẑ_T⁻¹`` on ω.
    - ``n_rhp``: ``(S,)`` int, the RHP poles of each ``P̂_s`` (RHP roots of its ``Ẑ_T``).
    """

    P: np.ndarray
    n_rhp: np.ndarray


def posterior_plants(models, omega) -> PosteriorPlants:
    """:class:`PosteriorPlants` ``(P (S, N, n, n), n_rhp (S,))`` of a batched model on
    ``omega (N,)`` rad/s."""

    @jax.jit
    def one(m):
        r = m.total.roots()
        return m.P(1j * omega), np.int64(0) + jax.numpy.sum(jax.numpy.real(r) > 0)

    P, n = jax.vmap(one)(models)
    return PosteriorPlants(np.asarray(P), np.asarray(n))


def count_grid(fs_hz: float, dense_factor: int, n_freq: int) -> np.ndarray:
    """The device family's dense grid (rad/s, sorted, ``(dense_factor + 1) · n_freq``
    points): :func:`below_nyquist_grid` with ``dense_factor · n_freq`` points (0.1 Hz to
    0.499 f_s), a low tail from the analysis grid's 10⁻³ Hz up to 0.1 Hz and the Nyquist
    frequency itself — so that its Nyquist count closes at both ends as the analysis'
    (:func:`hapid._grids.nyquist_grid`) does: ``det(I + L)`` can sit at −90° at 0.1 Hz
    (docs/robust-design.md, Evidence E7)."""
    band = below_nyquist_grid(fs_hz, dense_factor * n_freq)
    tail = log_grid_hz(NYQUIST_F_MIN_HZ, 0.1, n_freq)[:-1]
    return np.sort(np.concatenate([tail, band, [np.pi * float(fs_hz)]]))


def loop_draw_family(lgp, model, *, n_freq: int, dense_factor: int, n_train: int,
                     n_holdout: int, n_holdout_freq: int, quantile: float, bandwidth: bool,
                     seed: int, ts: float | None):  # fmt: skip
    """The ``posterior`` family of loop draws (``Q = P P̂⁻¹`` conditioned on the measured FRF,
    :func:`hapid.uncertainty.loop_gp_plants`) and its held-out plants: ``(Family,
    held-out P (S, N, n, n), held-out ω (N,))``.

    Trained and held out on one loop: with ``ts`` (s, the controller's rate) both close the
    loop with the controller discretized at ``ts`` on :func:`nyquist_grid` (to π/ts); without
    it, the continuous loop on :func:`posterior_grid` (why: docs/robust-design.md, Evidence
    E6, "One loop for training and re-check"). ``dense_factor > 1``: the same draws on a
    denser grid (one joint GP draw) for the tuner's grid exchange and Nyquist count."""

    grid = posterior_grid if ts is None else (lambda n: nyquist_grid(1.0 / ts, n))
    om = grid(n_freq)
    dense = None
    if dense_factor > 1:
        om_d = grid(dense_factor * n_freq)
        P_all = loop_gp_plants(lgp, model, np.concatenate([om, om_d]), n_train, seed)
        P, P_d = P_all[:, : om.size], P_all[:, om.size :]
        dense = make_scenarios(P_d, model, om_d, ts=ts)
    else:
        P = loop_gp_plants(lgp, model, om, n_train, seed)
    om_h = grid(n_holdout_freq)
    hold = loop_gp_plants(lgp, model, om_h, n_holdout, seed + 1)
    fam = Family(make_scenarios(P, model, om, ts=ts), quantile=quantile, bandwidth=bandwidth,
                 bw_quantile=0.5, name="posterior", dense=dense)  # fmt: skip
    return fam, hold, om_h


def draw_family(draws, model, recipe, rng, ts: float | None):
    """The chance-constrained ``posterior`` family of ``draws`` (:class:`ParamDraws` or
    :class:`LoopDraws`) and its held-out plants: ``(Family, held-out plants, held-out ω or
    None, info dict)``. Held-out plants are a batched model (parameter draws) or
    ``(S, N, n, n)`` arrays on the held-out ω (loop or predictive draws; ω ``None`` means
    :func:`posterior_grid` with ``recipe.n_holdout_freq`` points)."""
    r = recipe
    if isinstance(draws, LoopDraws):
        lgp = draws.gp(model)
        fam, hold, om_h = loop_draw_family(
            lgp, model, n_freq=r.n_freq, dense_factor=r.dense_factor, n_train=r.n_train,
            n_holdout=r.n_holdout, n_holdout_freq=r.n_holdout_freq, quantile=r.quantile,
            bandwidth=r.posterior_bandwidth, seed=r.seed, ts=ts,
        )  # fmt: skip
        info = {"train": int(r.n_train), "held_out": int(r.n_holdout),
                "plants": "loop GP (Q = P P̂⁻¹ conditioned on the measured FRF)",
                "loop_gp": {"ell": lgp.ell, "eta": lgp.eta, "sigma2": lgp.sigma2}}  # fmt: skip
        return fam, hold, (om_h if ts is not None else None), info
    if not isinstance(draws, ParamDraws):
        raise TypeError(f"draws must be ParamDraws or LoopDraws, got {type(draws).__name__}")
    samples = draws.samples
    S = _n_models(samples)
    if S < 2:
        raise ValueError("robust_design: need at least 2 posterior samples (train + held out)")
    perm = rng.permutation(S)
    k = min(r.n_train, S // 2)
    tr, ho = perm[:k], perm[k : k + r.n_holdout]
    omc = posterior_grid(r.n_freq)
    pred = draws.has_error_term
    if pred:
        P, pol = predictive_scenario_plants(samples, tr, omc, seed=r.seed)
        hold = predictive_scenario_plants(samples, ho, posterior_grid(r.n_holdout_freq),
                                          seed=r.seed + 1)[0]  # fmt: skip
    else:
        P, pol = posterior_plants(_sample_models(samples, tr), omc)
        hold = _sample_models(samples, ho)
    dense = None
    if r.dense_factor > 1 and not pred:
        omc_d = posterior_grid(r.dense_factor * r.n_freq)
        P_d, pol_d = posterior_plants(_sample_models(samples, tr), omc_d)
        dense = make_scenarios(P_d, model, omc_d, p_ol=pol_d)
    fam = Family(make_scenarios(P, model, omc, p_ol=pol), quantile=r.quantile,
                 bandwidth=r.posterior_bandwidth, bw_quantile=0.5, name="posterior", dense=dense)  # fmt: skip
    info = {"train": int(k), "held_out": int(len(ho)),
            "plants": f"predictive ({samples.error_kind} model error)" if pred else "models"}  # fmt: skip
    return fam, hold, None, info


def device_family(device, model, recipe):
    """The worst-case ``device`` family: the device's true sampled plants at the
    ``TRAIN_OFFSETS`` poses and ``recipe.n_subjects`` virtual subjects (not the nominal
    plant), with their dense grid (:func:`count_grid`). ``(Family, info dict)``."""
    r, seed = recipe, recipe.seed
    omd = below_nyquist_grid(device.fs_hz, r.n_freq)
    poses = [device.pose.moved(*o) for o in TRAIN_OFFSETS]
    labels, P = device_plants(device, omd, poses=poses, n_subjects=r.n_subjects, key=seed + 1,
                              include_nominal=False)  # fmt: skip
    dense = None
    if r.dense_factor > 1:
        omd_d = count_grid(device.fs_hz, r.dense_factor, r.n_freq)
        P_d = []  # in chunks of the training grid's size: the compiled plant program is reused
        for chunk in omd_d.reshape(-1, r.n_freq):
            labels_d, P_c = device_plants(device, chunk, poses=poses, n_subjects=r.n_subjects,
                                          key=seed + 1, include_nominal=False)  # fmt: skip
            if list(labels_d) != list(labels):
                raise RuntimeError(
                    "robust_design: dense device variants differ from the training ones"
                )
            P_d.append(np.asarray(P_c))
        dense = make_scenarios(
            np.concatenate(P_d, axis=1), model, omd_d, ts=device.ts, labels=labels
        )
    fam = Family(make_scenarios(P, model, omd, ts=device.ts, labels=labels), quantile=1.0,
                 bw_quantile=0.5, name="device", dense=dense)  # fmt: skip
    return fam, {"train": len(labels)}


def held_out_variants(device, recipe):
    """``(labels, P)`` of the device's held-out variants (``HOLDOUT_OFFSETS`` poses,
    ``recipe.n_holdout_subjects`` other subjects) on :func:`hapid._grids.nyquist_grid`."""
    hp = [device.pose.moved(*o) for o in HOLDOUT_OFFSETS]
    return device_plants(device, nyquist_grid(device.fs_hz), poses=hp,
                         n_subjects=recipe.n_holdout_subjects, key=recipe.seed + 1000,
                         include_nominal=False)  # fmt: skip
