"""Progress of a tuning run on stderr: phase lines and a tqdm bar over the continuation stages.

The convention of hapid's other long runs (the emcee sampler, ``hapid sweep``): a tqdm bar on
stderr, so that stdout keeps only the report. :class:`TuneProgress` adds the tuner's own
figures — the stage, its BFGS steps, the penalized objective and the worst smooth constraint
at the stage's end — and the time elapsed against the time expected. A BFGS stage runs as
one compiled loop; a host callback inside it would put a process-specific pointer into the
program and defeat the persistent compilation cache, so the bar is redrawn by a timer while
a stage runs (elapsed time moves, the figures are those of the last finished stage).
"""

from __future__ import annotations

import sys
import threading
import time

from tqdm import tqdm

from .._constants import TUNE_EXPECTED_S as EXPECTED_S

REFRESH_S = 5.0
"""Seconds between redraws of the bar while a stage runs."""


class TuneProgress:
    """Reports a tuning run on ``file`` (default stderr); every method is a no-op when
    ``enabled`` is False.

    - :meth:`phase`: one line ``tune: <what> (<elapsed> s / ~<expected> s expected)`` for
      the steps around the optimization (plants, start, re-checks);
    - :meth:`stage` / :meth:`stage_done`: a tqdm bar over the continuation stages (its total
      grows when a stage is repeated after a grid exchange), redrawn every
      :data:`REFRESH_S` s; its postfix the last finished stage's steps, objective and worst
      constraint (name and value, ≤ 0 met).

    ``expected_s``: the run's expected wall time (s), printed next to the elapsed time;
    ``command``: the prefix of the phase lines (``hapid robust`` reports its steps through
    :meth:`phase` too, with ``command="robust"``).
    """

    def __init__(self, file=None, enabled: bool = True, expected_s: float = EXPECTED_S,
                 command: str = "tune"):  # fmt: skip
        self.command = command
        self.file = sys.stderr if file is None else file
        self.enabled = bool(enabled)
        self.expected_s = float(expected_s)
        self.t0 = time.perf_counter()
        self.bar = None
        self._stop = threading.Event()
        self._timer = None
        self._last = "no stage finished yet"

    def elapsed(self) -> str:
        """``'<elapsed> s / ~<expected> s expected'``."""
        return f"{time.perf_counter() - self.t0:.0f} s / ~{self.expected_s:.0f} s expected"

    def phase(self, what: str) -> None:
        """One line on ``file``: what the run is doing now, and the time."""
        if self.enabled:
            self._write(f"{self.command}: {what} ({self.elapsed()})")

    def stage(self, index: int, n_stages: int, mu: float) -> None:
        """Stage ``index`` (0-based) of ``n_stages`` (penalty weight ``mu``) starts."""
        if not self.enabled:
            return
        if self.bar is None:
            self.bar = tqdm(total=n_stages, desc="tune", unit="stage", file=self.file,
                            leave=True, mininterval=0.0)  # fmt: skip
            self._timer = threading.Thread(target=self._redraw, daemon=True)
            self._timer.start()
        self.bar.total = max(n_stages, self.bar.n + 1)
        self.bar.set_description_str(f"tune stage {index + 1}/{self.bar.total} (μ = {mu:g})")
        self._postfix(self.bar)

    def stage_done(self, rec: dict) -> None:
        """A stage finished (``rec``: a history entry of :func:`hapid.tune.tune`)."""
        if not (self.enabled and self.bar is not None):
            return
        worst = max(rec["constraints"].items(), key=lambda kv: kv[1], default=("-", 0.0))
        added = sum(rec.get("grid_added", ()))
        self._last = (f"last stage: {rec['steps']} steps, objective {rec['objective']:.4g}, "
                      f"worst {worst[0]} {worst[1]:+.3g}"
                      + (f", {added} grid point(s) added (stage repeated)" if added else ""))  # fmt: skip
        self.bar.update(1)
        self._postfix(self.bar)

    def close(self) -> None:
        """Close the bar (and stop its timer)."""
        self._stop.set()
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def _postfix(self, bar) -> None:
        bar.set_postfix_str(f"{self._last}; {self.elapsed()}")

    def _redraw(self) -> None:
        while not self._stop.wait(REFRESH_S):
            bar = self.bar
            if bar is not None:
                self._postfix(bar)

    def _write(self, line: str) -> None:
        if self.bar is not None:
            self.bar.write(line, file=self.file)
        else:
            print(line, file=self.file, flush=True)


def note(progress, what: str) -> None:
    """:meth:`TuneProgress.phase` when ``progress`` is a :class:`TuneProgress`, else nothing."""
    if isinstance(progress, TuneProgress):
        progress.phase(what)
