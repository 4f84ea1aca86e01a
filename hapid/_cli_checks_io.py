"""Command-line checks that read a little of the files named (before any work): an output
that would overwrite one of the command's inputs, and ``hapid robust``'s model against the
``--device`` preset (the same number of rods ``n``)."""

from __future__ import annotations

from pathlib import Path

from . import io
from .device import preset


def _same_file(a, b) -> bool:
    try:
        return Path(a).resolve() == Path(b).resolve()
    except OSError:
        return False


def check_out_not_input(outputs: dict, inputs: dict) -> None:
    """Raise ``ValueError`` when an output path (``{flag: path}``) names an input file
    (``{flag: path or [paths]}``): the command would replace its own input."""
    for oflag, out in outputs.items():
        if out is None:
            continue
        for iflag, paths in inputs.items():
            for p in paths if isinstance(paths, list) else [paths]:
                if p is not None and _same_file(out, p):
                    raise ValueError(
                        f"{oflag} {out} is the input file {iflag} {p}: hapid does not overwrite "
                        f"its own input; choose another {oflag}"
                    )


def check_model_matches_device(model_paths, device: str | None) -> None:
    """``hapid robust``: every ``--model`` must have the ``--device`` preset's number of rods."""
    if device is None:
        return

    n_dev = preset(device).n
    for p in model_paths or []:
        n = io.load_model(p).n
        if n != n_dev:
            raise ValueError(
                f"--model {p} is for n = {n} rods but --device {device} has n = {n_dev}; give "
                "a model fitted on that device"
            )
