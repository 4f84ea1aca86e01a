"""hapid's estimators side by side on one periodic run (for consistency studies)."""

from __future__ import annotations

from ..experiment import Run, estimate_frf
from ..impedance import ImpedanceModel
from ._ml import fit_ml
from ._nls import fit_nls
from ._result import NLSResult
from ._wls import wls

#: the names :func:`fit_estimators` returns, in order
ESTIMATORS = ("ML", "NLS relative", "NLS noise", "WLS")


def fit_estimators(
    run: Run, *, f_max_hz: float | None = None
) -> dict[str, NLSResult | ImpedanceModel]:
    """Every estimator on one periodic ``run``, keyed by the names of :data:`ESTIMATORS`.

    ``"NLS relative"`` and ``"NLS noise"`` are :func:`~hapid.fit.fit_nls` (relative and noise
    weights) on ``estimate_frf(run)``; ``"ML"`` is :func:`~hapid.fit.fit_ml` on the run,
    started at the relative NLS fit; these three are results (``.model``, ``.ok``). ``"WLS"``
    is the paper's :func:`~hapid.fit.wls` model (closed form). ``f_max_hz`` (Hz, ``None`` =
    every frequency) is the fit band of all four.
    """
    frf = estimate_frf(run)
    nls = fit_nls(frf, f_max_hz=f_max_hz)
    return {
        "ML": fit_ml(run, nls, f_max_hz=f_max_hz),
        "NLS relative": nls,
        "NLS noise": fit_nls(frf, f_max_hz=f_max_hz, weight="noise"),
        "WLS": wls(frf, f_max_hz=f_max_hz),
    }
