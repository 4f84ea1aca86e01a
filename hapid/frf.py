"""The FRF value object passed from the experiment stage to the fit stage.

``Z_H``, ``Z_T`` are the empirical hand and total impedances ``(N, n, n)`` complex at the
excited angular frequencies ``omega`` (rad/s); ``Z_H_std``, ``Z_T_std`` are the standard
deviations of each element estimate, ``sqrt(E|Ẑ − Z|²)`` (real and imaginary parts together),
or ``None`` when unknown. ``cond_L`` is the condition number of the stacked displacement
matrix 𝓛(jω) per frequency (``None`` when not measured). ``coherence_H``, ``coherence_T``
``(N, n)`` in ``[0, 1]`` are the multiple coherences γ² of each output channel of an H1 estimate
(row ``i`` of ``Z_H`` resp. ``Z_T``; see :func:`hapid.experiment.estimate_frf_h1`), or ``None``
(periodic estimates, too few segments, or not measured).

Precision: hapid computes in float64. float32/complex64 arrays given to ``FRF``/``as_frf``
are upcast (a :class:`PrecisionWarning` says so: the data keep their ~1e-7 relative
precision, which measured stress cases show the fits tolerate); with ``jax_enable_x64``
switched off, building an FRF raises ``RuntimeError``.
"""

from __future__ import annotations

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float

from . import _config  # noqa: F401
from ._constants import TWO_PI
from ._grids import band_mask
from .impedance import plant


class FRF(eqx.Module):
    omega: Float[Array, " N"]
    Z_H: Complex[Array, "N n n"]
    Z_T: Complex[Array, "N n n"]
    Z_H_std: Float[Array, "N n n"] | None = None
    Z_T_std: Float[Array, "N n n"] | None = None
    cond_L: Float[Array, " N"] | None = None
    coherence_H: Float[Array, "N n"] | None = None
    coherence_T: Float[Array, "N n"] | None = None

    def __post_init__(self):
        # hapid computes in float64 (docs/conventions.md): lower-precision input is upcast, with a
        # warning, so that no stage silently runs in float32
        require_x64("FRF")
        for name, dt in _DTYPES.items():
            a = getattr(self, name)
            if a is None or not hasattr(a, "dtype") or a.dtype == dt:
                continue
            if _is_low_precision(a.dtype):
                warnings.warn(
                    f"FRF: {name} is {a.dtype}; upcast to {np.dtype(dt).name} (hapid computes "
                    "in float64; the data keep only their own precision, ~1e-7 relative for "
                    "float32)",
                    PrecisionWarning,
                    stacklevel=4,
                )
            setattr(self, name, jnp.asarray(a, dtype=dt))

    def __check_init__(self):
        check_frf_arrays(self.omega, self.Z_H, self.Z_T, self.Z_H_std, self.Z_T_std)
        check_coherence(self.Z_H, coherence_H=self.coherence_H, coherence_T=self.coherence_T)

    @property
    def n(self) -> int:
        return int(np.shape(self.Z_H)[-1])

    @property
    def freq_hz(self):
        return self.omega / TWO_PI

    @property
    def P(self) -> Complex[Array, "N n n"]:
        """Empirical plant ``P = Z_H Z_T⁻¹``."""
        return plant(self.Z_H, self.Z_T)

    def select(self, mask) -> FRF:
        """A new FRF restricted to the frequencies where ``mask`` (``(N,)`` bool) is true."""
        mask = np.asarray(mask, dtype=bool)
        pick = lambda a: None if a is None else a[..., mask, :, :] if a.ndim >= 3 else a[..., mask]  # noqa: E731
        return FRF(
            omega=self.omega[..., mask],
            Z_H=pick(self.Z_H),
            Z_T=pick(self.Z_T),
            Z_H_std=pick(self.Z_H_std),
            Z_T_std=pick(self.Z_T_std),
            cond_L=None if self.cond_L is None else self.cond_L[..., mask],
            coherence_H=None if self.coherence_H is None else self.coherence_H[..., mask, :],
            coherence_T=None if self.coherence_T is None else self.coherence_T[..., mask, :],
        )

    def band(self, f_min_hz: float = 0.0, f_max_hz: float = np.inf) -> FRF:
        """A new FRF restricted to ``f_min_hz ≤ f ≤ f_max_hz``."""
        f = np.asarray(self.freq_hz)
        return self.select(band_mask(f, f_min_hz, f_max_hz))


class PrecisionWarning(UserWarning):
    """Input arrays of lower than float64 precision were upcast."""


_DTYPES = {
    "omega": np.float64,
    "Z_H": np.complex128,
    "Z_T": np.complex128,
    "Z_H_std": np.float64,
    "Z_T_std": np.float64,
    "cond_L": np.float64,
    "coherence_H": np.float64,
    "coherence_T": np.float64,
}


def _is_low_precision(dtype) -> bool:
    dt = np.dtype(dtype)
    return dt.kind in "fc" and dt.itemsize < (16 if dt.kind == "c" else 8)


def require_x64(what: str) -> None:
    """Raise a clear error when JAX's float64 has been switched off after ``import hapid``."""
    if not jax.config.jax_enable_x64:
        raise RuntimeError(
            f"{what}: hapid computes in float64, but jax_enable_x64 is off (switched off "
            "after `import hapid`?); hapid has no float32 mode. Re-enable it with "
            "jax.config.update('jax_enable_x64', True)"
        )


def check_frf_arrays(omega, Z_H, Z_T, Z_H_std=None, Z_T_std=None) -> None:
    """Validate FRF arrays with clear errors; a no-op on traced values' contents.

    Shapes are always checked. Values (finite, positive, increasing frequencies) are checked
    only when concrete (outside ``jit``); batched FRFs (leading batch axes) are allowed.
    """
    omega_shape = np.shape(omega)
    zs = np.shape(Z_H)
    if len(zs) < 3 or zs[-1] != zs[-2]:
        raise ValueError(f"FRF: Z_H must be (N, n, n), got shape {zs}")
    if np.shape(Z_T) != zs:
        raise ValueError(f"FRF: Z_T has shape {np.shape(Z_T)}, Z_H has {zs}; they must match")
    if omega_shape[-1:] != zs[-3:-2]:
        raise ValueError(f"FRF: {omega_shape[-1:]} frequencies but Z_H has {zs[-3]} frequency rows")
    for name, std in (("Z_H_std", Z_H_std), ("Z_T_std", Z_T_std)):
        if std is not None and np.shape(std) != zs:
            raise ValueError(f"FRF: {name} has shape {np.shape(std)}, expected {zs}")
    if _is_concrete(omega) and _is_concrete(Z_H) and _is_concrete(Z_T):
        w = np.asarray(omega)
        if not np.all(np.isfinite(w)):
            raise ValueError("FRF: frequencies contain NaN or inf")
        if np.any(w <= 0):
            raise ValueError("FRF: frequencies must be > 0")
        if np.any(np.diff(w, axis=-1) <= 0):
            raise ValueError("FRF: frequencies must be strictly increasing")
        for name, a in (("Z_H", Z_H), ("Z_T", Z_T), ("Z_H_std", Z_H_std), ("Z_T_std", Z_T_std)):
            if a is not None and _is_concrete(a) and not np.all(np.isfinite(np.asarray(a))):
                bad = tuple(int(i) for i in np.argwhere(~np.isfinite(np.asarray(a)))[0])
                raise ValueError(f"FRF: {name} contains NaN or inf (first at index {bad})")


def check_coherence(Z_H, **coherences) -> None:
    """Validate coherence arrays: shape ``(..., N, n)`` matching ``Z_H`` ``(..., N, n, n)``;
    values (checked only when concrete) finite and in ``[0, 1]``. ``None`` entries pass."""
    want = np.shape(Z_H)[:-1]
    for name, g in coherences.items():
        if g is None:
            continue
        if np.shape(g) != want:
            raise ValueError(f"FRF: {name} has shape {np.shape(g)}, expected (N, n) = {want}")
        if _is_concrete(g):
            a = np.asarray(g)
            if not np.all((a >= 0) & (a <= 1)):
                raise ValueError(f"FRF: {name} must lie in [0, 1] (coherence γ²)")


def _is_concrete(x) -> bool:
    return x is not None and not isinstance(x, jax.core.Tracer)


def as_frf(
    freq_hz, Z_H, Z_T, Z_H_std=None, Z_T_std=None, cond_L=None, coherence_H=None, coherence_T=None
) -> FRF:
    """Build an FRF from Hz frequencies and arrays (the file contract's units).

    float32/complex64 input is upcast to float64/complex128 with a :class:`PrecisionWarning`;
    with ``jax_enable_x64`` switched off this raises ``RuntimeError`` (hapid is float64).
    """
    require_x64("as_frf")
    f = jnp.asarray(freq_hz)  # keep the input dtype: FRF upcasts (and warns) in one place
    opt = lambda a: None if a is None else jnp.asarray(a)  # noqa: E731
    return FRF(
        omega=TWO_PI * f.astype(jnp.float64) if not _is_low_precision(f.dtype) else TWO_PI * f,
        Z_H=jnp.asarray(Z_H),
        Z_T=jnp.asarray(Z_T),
        Z_H_std=opt(Z_H_std),
        Z_T_std=opt(Z_T_std),
        cond_L=opt(cond_L),
        coherence_H=opt(coherence_H),
        coherence_T=opt(coherence_T),
    )
