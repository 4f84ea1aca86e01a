"""hapid's estimators side by side on one periodic run (for consistency studies)."""

from __future__ import annotations

import equinox as eqx

from .._plain import jsonable
from ..experiment import Run, estimate_frf
from ..impedance import ImpedanceModel
from ._ml import MLResult, fit_ml
from ._nls import fit_nls
from ._result import FitStatus, NLSResult
from ._wls import wls

#: the estimators' names, in the order of :meth:`EstimatorFits.models`
ESTIMATORS = ("ML", "NLS relative", "NLS noise", "WLS")


class EstimatorFits(eqx.Module):
    """Result of :func:`fit_estimators`: every estimator on one run.

    ``ml`` (:class:`~hapid.fit.MLResult`), ``nls_relative`` and ``nls_noise``
    (:class:`~hapid.fit.NLSResult`, relative and noise weights) and ``wls`` (the paper's
    closed-form :class:`~hapid.impedance.ImpedanceModel`). ``status``
    (:class:`~hapid.fit.FitStatus`): ``CONVERGED`` when the three iterative fits converged,
    else the status of the first that did not (in :data:`ESTIMATORS` order)."""

    ml: MLResult
    nls_relative: NLSResult
    nls_noise: NLSResult
    wls: ImpedanceModel

    def results(self) -> dict[str, NLSResult]:
        """The iterative fits by name (``"ML"``, ``"NLS relative"``, ``"NLS noise"``)."""
        return dict(zip(ESTIMATORS[:3], (self.ml, self.nls_relative, self.nls_noise), strict=True))

    def models(self) -> dict[str, ImpedanceModel]:
        """Every estimator's model by name, in :data:`ESTIMATORS` order."""
        return {k: r.model for k, r in self.results().items()} | {"WLS": self.wls}

    @property
    def status(self) -> FitStatus:
        for r in self.results().values():
            if r.status is not FitStatus.CONVERGED:
                return r.status
        return FitStatus.CONVERGED

    @property
    def ok(self) -> bool:
        return self.status is FitStatus.CONVERGED

    def summary(self) -> dict:
        """Strict-JSON dict: ``status``, ``ok`` and ``fits``: name → the fit's own summary
        (``"WLS"``: its ``status`` ``closed form`` and ``ok``)."""
        fits = {k: r.summary() for k, r in self.results().items()}
        fits["WLS"] = {"status": FitStatus.CLOSED_FORM, "ok": True}
        return jsonable({"status": self.status, "ok": self.ok, "fits": fits})


def fit_estimators(run: Run, *, f_max_hz: float | None = None) -> EstimatorFits:
    """Every estimator on one periodic ``run`` (:class:`EstimatorFits`).

    ``nls_relative`` and ``nls_noise`` are :func:`~hapid.fit.fit_nls` (relative and noise
    weights) on ``estimate_frf(run)``; ``ml`` is :func:`~hapid.fit.fit_ml` on the run,
    started at the relative NLS fit; ``wls`` is the paper's :func:`~hapid.fit.wls` model
    (closed form). ``f_max_hz`` (Hz, ``None`` = every frequency) is the fit band of all four.
    """
    frf = estimate_frf(run)
    nls = fit_nls(frf, f_max_hz=f_max_hz)
    return EstimatorFits(
        ml=fit_ml(run, nls, f_max_hz=f_max_hz),
        nls_relative=nls,
        nls_noise=fit_nls(frf, f_max_hz=f_max_hz, weight="noise"),
        wls=wls(frf, f_max_hz=f_max_hz),
    )
