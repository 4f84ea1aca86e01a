"""The status enums of the control results: :class:`ControllerStatus` (realizability of the
inverse-model controller) and :class:`LoopStatus` (closed-loop stability verdict). The value
is the word the CLI and the JSON files use."""

from __future__ import annotations

import enum


class ControllerStatus(enum.StrEnum):
    """Outcome of :class:`~hapid.control.ControllerCheck`; ``ok`` means ``OK``."""

    OK = "ok"
    UNSTABLE = "unstable"
    NON_MINIMUM_PHASE = "non-minimum-phase"
    UNSTABLE_NON_MINIMUM_PHASE = "unstable, non-minimum-phase"


class LoopStatus(enum.StrEnum):
    """Closed-loop verdict of :class:`~hapid.control.LoopMetrics` (and of the sweep's
    points); ``ok`` means ``STABLE``.

    ``SINGULAR``: a closed-loop pole on the imaginary axis (I + L singular at a grid
    frequency); ``UNRESOLVED``: the grid did not resolve the Nyquist count.
    """

    STABLE = "stable"
    UNSTABLE = "unstable"
    SINGULAR = "singular"
    UNRESOLVED = "unresolved"
