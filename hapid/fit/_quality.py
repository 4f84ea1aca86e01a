# ruff: noqa: F722  (jaxtyping shape strings such as "N n n" are not Python expressions)
"""Fit quality on every fit: how well a fitted ``M s² + B s + K`` describes the data it was
fitted to, over the band actually used.

Figures (per impedance block: ``Z`` for a single impedance, ``Z_H`` and ``Z_T`` for the
haptic pair), all on the frequencies kept for the fit:

- data-fit relative error ``e(ω) = ‖Ẑ(jω) − Z(jω)‖_F / ‖Z(jω)‖_F`` in dB (``20 log10 e``),
  summarized by its median and maximum; 0 dB is a 100 % error, −20 dB a 10 % error;
- asymmetry of the *measured* data ``a(ω) = ‖Z − Zᵀ‖_F / ‖Z + Zᵀ‖_F`` (0 symmetric, 1 purely
  antisymmetric), median over the band: a symmetric ``M, B, K`` model assumes collocated force
  and response, so it cannot describe the antisymmetric part;
- noise-aware: with the FRF's element std ``σ_ij`` (std of the complex estimate), the fraction
  of frequencies where the model lies inside the data's ``level`` confidence region,
  ``Σ_ij 2|Ẑ_ij − Z_ij|²/σ_ij² ≤ χ²_{2n²}(level)`` (elements independent, complex Gaussian).
  About ``level`` when the model is right and the std honest; near 0 when model error
  dominates the noise.

Warnings (``FitQuality.warnings``): median relative error above ``MEDIAN_WARN_DB`` (the model
does not describe the data); positizing made the fit worse (median up by more than
``POSITIZE_WORSE_DB``); measured Z far from symmetric (median asymmetry above
``ASYMMETRY_WARN``).

Other report lines (a Cramér–Rao band, an error against a known true plant) are attached
with :meth:`FitQuality.with_line`; they are printed by ``hapid fit`` and stored in the
model file with the rest.
"""

from __future__ import annotations

import dataclasses
import enum

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from .._constants import TWO_PI
from .._plain import jsonable

#: warn when the median data-fit relative error exceeds this (dB; −6 dB ≈ 50 %)
MEDIAN_WARN_DB = -6.0
#: warn when positizing raised the median relative error by more than this (dB)
POSITIZE_WORSE_DB = 1.0
#: warn when the median asymmetry ‖Z − Zᵀ‖/‖Z + Zᵀ‖ of the measured data exceeds this
ASYMMETRY_WARN = 0.2
#: confidence level of the noise-aware figure
LEVEL = 0.95


def relative_error(
    Z: Complex[Array, "N n n"], Z_hat: Complex[Array, "N n n"]
) -> Float[Array, " N"]:
    """``‖Ẑ − Z‖_F / ‖Z‖_F`` per frequency (``(N,)``, linear). Jittable."""
    fro = lambda A: jnp.sqrt(jnp.sum(jnp.abs(A) ** 2, axis=(-2, -1)))  # noqa: E731
    return fro(Z_hat - Z) / fro(Z)


def asymmetry(Z: Complex[Array, "N n n"]) -> Float[Array, " N"]:
    """``‖Z − Zᵀ‖_F / ‖Z + Zᵀ‖_F`` per frequency (``(N,)``; 0 for a symmetric Z). Jittable."""
    Zt = jnp.swapaxes(Z, -1, -2)
    fro = lambda A: jnp.sqrt(jnp.sum(jnp.abs(A) ** 2, axis=(-2, -1)))  # noqa: E731
    return fro(Z - Zt) / jnp.maximum(fro(Z + Zt), jnp.finfo(jnp.float64).tiny)


def chi2_statistic(
    Z: Complex[Array, "N n n"], Z_hat: Complex[Array, "N n n"], Z_std: Float[Array, "N n n"]
) -> Float[Array, " N"]:
    """``Σ_ij 2|Ẑ_ij − Z_ij|²/σ_ij²`` per frequency: χ² with ``2n²`` degrees of freedom when
    the model is the truth and σ the std of the complex element estimate. Jittable."""
    return jnp.sum(2.0 * jnp.abs(Z_hat - Z) ** 2 / Z_std**2, axis=(-2, -1))


def inside_confidence(Z, Z_hat, Z_std, level: float = LEVEL):
    """``(N,)`` bool: the model lies inside the data's ``level`` confidence region."""
    from scipy.stats import chi2  # local: CLI start-up (scipy.stats, ~0.4 s)

    n = np.shape(Z)[-1]
    stat = np.sum(
        2.0 * np.abs(np.asarray(Z_hat) - np.asarray(Z)) ** 2 / np.asarray(Z_std) ** 2, axis=(-2, -1)
    )
    return stat <= chi2.ppf(level, 2 * n * n)


def _db(x):
    x = np.asarray(x, dtype=float)
    return np.where(np.isnan(x), np.nan, 20.0 * np.log10(np.maximum(np.nan_to_num(x), 1e-300)))


class QualityStatus(enum.StrEnum):
    """Outcome of :class:`FitQuality`: ``ok`` (no warning) or ``warnings``."""

    OK = "ok"
    WARNINGS = "warnings"


@dataclasses.dataclass(frozen=True)
class FitQuality:
    """Data-fit quality of one fit over the band it used (see the module docstring).

    Fields: ``method`` (text); ``band_hz`` the requested ``(f_min, f_max)`` in Hz;
    ``freq_hz`` ``(N,)`` the frequencies kept; ``blocks`` the impedance names (``("Z",)`` or
    ``("Z_H", "Z_T")``); ``rel_err_db`` ``(B, N)``; ``median_db``, ``max_db`` ``(B,)``;
    ``asymmetry`` ``(B,)`` median over the band; ``inside_fraction`` ``(B,)`` (NaN without
    std); ``level``; ``warnings`` (one line each); ``lines`` extra report lines
    (name → text, e.g. ``"cramer_rao"``, ``"vs_true"``).
    """

    method: str
    band_hz: tuple[float, float]
    freq_hz: np.ndarray
    blocks: tuple[str, ...]
    rel_err_db: np.ndarray
    median_db: np.ndarray
    max_db: np.ndarray
    asymmetry: np.ndarray
    inside_fraction: np.ndarray
    level: float = LEVEL
    warnings: tuple[str, ...] = ()
    lines: tuple[tuple[str, str], ...] = ()

    @property
    def ok(self) -> bool:
        """True when no warning was raised."""
        return not self.warnings

    @property
    def status(self) -> QualityStatus:
        """:class:`QualityStatus`: ``OK``, or ``WARNINGS`` (listed in :attr:`warnings`)."""
        return QualityStatus.WARNINGS if self.warnings else QualityStatus.OK

    @property
    def worst_median_db(self) -> float:
        return float(np.max(self.median_db))

    def with_line(self, name: str, text: str) -> FitQuality:
        """A copy with one more named report line (printed and stored)."""
        return dataclasses.replace(self, lines=self.lines + ((name, text),))

    def with_warning(self, text: str) -> FitQuality:
        return dataclasses.replace(self, warnings=self.warnings + (text,))

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok``, the band, per-block errors, ``warnings`` and the
        extra lines; non-finite numbers (``inside_fraction`` without std) as ``None``."""
        out = {
            "status": self.status.value,
            "method": self.method,
            "band_hz": [float(b) for b in self.band_hz],
            "n_freq": int(np.size(self.freq_hz)),
            "freq_min_hz": float(np.min(self.freq_hz)),
            "freq_max_hz": float(np.max(self.freq_hz)),
            "level": float(self.level),
            "ok": self.ok,
            "warnings": list(self.warnings),
        }
        for k, b in enumerate(self.blocks):
            out[b] = {
                "median_rel_err_db": float(self.median_db[k]),
                "max_rel_err_db": float(self.max_db[k]),
                "asymmetry": float(self.asymmetry[k]),
                "inside_fraction": float(self.inside_fraction[k]),
            }
        out.update({name: text for name, text in self.lines})
        return jsonable(out)

    def report(self) -> list[str]:
        """The printed report: one line per block, extra lines, then the warnings."""
        f = np.asarray(self.freq_hz)
        lo, hi = self.band_hz
        band = f"{lo:g}–{hi:g} Hz" if np.isfinite(hi) else f"≥ {lo:g} Hz"
        band = "all" if lo <= 0 and not np.isfinite(hi) else band
        out = [f"fit quality over {f.min():g}–{f.max():g} Hz ({f.size} frequencies; band {band}):"]
        for k, b in enumerate(self.blocks):
            s = (
                f"data-fit relative error of {b}: median {self.median_db[k]:+.1f} dB, "
                f"max {self.max_db[k]:+.1f} dB"
            )
            if np.isfinite(self.inside_fraction[k]):
                s += (
                    f"; inside the data's {100 * self.level:.0f} % region at "
                    f"{100 * self.inside_fraction[k]:.0f} % of frequencies"
                )
            s += f"; measured asymmetry {self.asymmetry[k]:.2f}"
            out.append(s)
        out += [text for _, text in self.lines]
        out += [f"warning: {w}" for w in self.warnings]
        return out

    def to_arrays(self) -> dict:
        """Arrays for a model file (keys ``quality_*``)."""
        d = {
            "quality_method": np.asarray(self.method),
            "quality_band_hz": np.asarray(self.band_hz, dtype=np.float64),
            "quality_freq_hz": np.asarray(self.freq_hz, dtype=np.float64),
            "quality_blocks": np.asarray(self.blocks, dtype=str),
            "quality_rel_err_db": np.asarray(self.rel_err_db, dtype=np.float64),
            "quality_median_db": np.asarray(self.median_db, dtype=np.float64),
            "quality_max_db": np.asarray(self.max_db, dtype=np.float64),
            "quality_asymmetry": np.asarray(self.asymmetry, dtype=np.float64),
            "quality_inside_fraction": np.asarray(self.inside_fraction, dtype=np.float64),
            "quality_level": np.float64(self.level),
            "quality_warnings": np.asarray(self.warnings, dtype=str),
        }
        for name, text in self.lines:
            d[f"quality_line_{name}"] = np.asarray(text)
        return d


def fit_quality(
    omega: Float[Array, " N"],
    data: dict,
    fitted: dict,
    std: dict | None = None,
    *,
    method: str = "",
    band_hz: tuple[float, float] = (0.0, np.inf),
    before: FitQuality | None = None,
    level: float = LEVEL,
) -> FitQuality:
    """Quality of a fit on the frequencies ``omega`` (rad/s, ``(N,)``) it used.

    ``data``/``fitted``: block name → ``(N, n, n)`` measured and model impedances (same keys,
    same order); ``std``: block name → ``(N, n, n)`` element std or ``None``. ``before``: the
    quality of the same fit before positizing (adds the "positizing made it worse" warning).
    """
    std = std or {}
    data = {b: np.asarray(v) for b, v in data.items()}  # numpy at the edge: no per-shape compile
    fitted = {b: np.asarray(v) for b, v in fitted.items()}
    std = {b: None if v is None else np.asarray(v) for b, v in std.items()}
    fro = lambda A: np.sqrt(np.sum(np.abs(A) ** 2, axis=(-2, -1)))  # noqa: E731
    # a block whose data are zero everywhere (Z_H = 0: a single impedance in the pair) has no
    # relative error: it is left out, with a line giving the model's size instead
    lines = tuple(
        (f"zero_{b}", f"{b}: the data are zero, so no relative error (max ‖Ẑ‖_F of the model "
                      f"{float(np.max(fro(fitted[b]))):.3g})")
        for b in data if not np.any(fro(data[b]) > 0)
    )  # fmt: skip
    blocks = tuple(b for b in data if np.any(fro(data[b]) > 0))
    if not blocks:
        raise ValueError("fit_quality: every data block is zero")
    norm = {b: fro(data[b]) for b in blocks}
    rel = np.stack(
        [fro(fitted[b] - data[b]) / np.where(norm[b] > 0, norm[b], np.nan) for b in blocks]
    )
    rel_db = _db(rel)  # NaN where a block's data are zero at that frequency
    med, mx = np.nanmedian(rel_db, axis=1), np.nanmax(rel_db, axis=1)
    tr = lambda A: np.swapaxes(A, -1, -2)  # noqa: E731
    asym = np.array(
        [
            float(
                np.median(
                    fro(data[b] - tr(data[b])) / np.maximum(fro(data[b] + tr(data[b])), 1e-300)
                )
            )
            for b in blocks
        ]
    )
    inside = np.array(
        [
            float(np.mean(inside_confidence(data[b], fitted[b], std[b], level)))
            if std.get(b) is not None and np.all(np.asarray(std[b]) > 0)
            else np.nan
            for b in blocks
        ]
    )
    warns = []
    for k, b in enumerate(blocks):
        if not med[k] <= MEDIAN_WARN_DB:
            warns.append(
                f"the model does not describe {b}: median relative error {med[k]:+.1f} dB "
                f"(> {MEDIAN_WARN_DB:g} dB) over the band"
            )
        if before is not None and b in before.blocks:
            m0 = float(before.median_db[before.blocks.index(b)])
            if med[k] > m0 + POSITIZE_WORSE_DB:
                warns.append(
                    f"positizing made the fit of {b} worse: median relative error "
                    f"{m0:+.1f} → {med[k]:+.1f} dB"
                )
        if asym[k] > ASYMMETRY_WARN:
            warns.append(
                f"measured {b} is far from symmetric (median ‖Z−Zᵀ‖/‖Z+Zᵀ‖ = {asym[k]:.2f}): a "
                "symmetric M, B, K model assumes collocated force and response"
            )
    return FitQuality(
        method=method,
        band_hz=(float(band_hz[0]), float(band_hz[1])),
        freq_hz=np.asarray(omega) / TWO_PI,
        blocks=blocks,
        rel_err_db=rel_db,
        median_db=med,
        max_db=mx,
        asymmetry=asym,
        inside_fraction=inside,
        level=level,
        warnings=tuple(warns),
        lines=lines,
    )


def pair_quality(frf, model, **kw) -> FitQuality:
    """:func:`fit_quality` of a hand/total model on an FRF (the frequencies of ``frf``)."""
    w = frf.omega
    return fit_quality(
        w,
        {"Z_H": frf.Z_H, "Z_T": frf.Z_T},
        {"Z_H": _eval(model.hand, w), "Z_T": _eval(model.total, w)},
        {"Z_H": frf.Z_H_std, "Z_T": frf.Z_T_std},
        **kw,
    )


def impedance_quality(zfrf, model, **kw) -> FitQuality:
    """:func:`fit_quality` of a single ``SecondOrder`` model on an ``ImpedanceFRF``."""
    w = zfrf.omega
    return fit_quality(w, {"Z": zfrf.Z}, {"Z": _eval(model, w)}, {"Z": zfrf.Z_std}, **kw)


def _eval(model, omega):
    """``M (jω)² + B jω + K`` in numpy (``(N, n, n)``)."""
    s = 1j * np.asarray(omega)[:, None, None]
    return np.asarray(model.M) * s**2 + np.asarray(model.B) * s + np.asarray(model.K)
