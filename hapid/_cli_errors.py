"""The one error type of the ``hapid`` command: a user mistake, reported as one line (exit
code 2) by :func:`hapid.cli.main`."""

from __future__ import annotations


class CLIError(Exception):
    pass
