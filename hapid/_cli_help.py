"""Help texts of the options whose ``add_argument`` line has none, and the default of every
option in its ``--help`` line (``(default: %(default)s)`` appended where the text does not
already state it). Applied once to the parser by ``hapid.cli.build_parser``; a test checks
that every option of every subcommand has a help text stating its default."""

from __future__ import annotations

import argparse

# (command, dest) -> help; "*" matches any command
HELP: dict[tuple[str, str], str] = {
    ("*", "seed"): "random seed",
    ("*", "device"): "preset device: cu5, tripod3, quad4, hexapod6 or cu5_soft",
    ("simulate", "pattern"): "experiment pattern: which rods each experiment excites",
    ("simulate", "phases"): "multisine phases",
    ("demo", "out"): "output folder",
    ("fit", "method"): "wls: the paper's weighted least squares; nls: hapid's PSD-constrained fit",
    ("fit", "weight"): "NLS residual weights",
    ("fit", "max_steps"): "NLS solver step limit",
    ("fit", "allow_unconverged"): "write the model even if the NLS fit did not converge",
    ("analyze", "model"): "model file whose inverse the controller g Ẑ_T Ẑ_H⁻¹ uses",
    ("analyze", "controller"): "mimo: g Ẑ_T Ẑ_H⁻¹; siso: c·g·I (the paper's baseline)",
    ("posterior", "frf"): "FRF file (.npz, .csv, .mat)",
    ("posterior", "out"): "output samples file (.npz)",
    ("posterior", "method"): "emcee: MCMC sampling; laplace: Gaussian at the fit",
    ("posterior", "f_max_hz"): "likelihood band (Hz)",
    ("robust", "samples"): "posterior samples file (hapid posterior)",
    ("robust", "gm_db"): "required gain margin (dB)",
    ("robust", "pm_deg"): "required phase margin (degrees)",
    ("robust", "max_samples"): "use at most this many posterior samples",
    ("sweep", "scene"): "scene TOML file whose options are swept",
    ("sweep", "out"): "output folder (sweep.csv, sweep.png)",
    ("run", "no_cache"): "recompute every stage",
}


def annotate(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Fill in missing help texts and state every default (in place); returns ``parser``."""
    act = next((a for a in parser._actions if a.dest == "command"), None)
    for cmd, sub in (act.choices if act is not None else {}).items():
        for a in sub._actions:
            if a.dest == "help" or a.help == argparse.SUPPRESS:
                continue
            if not a.help:
                a.help = HELP.get((cmd, a.dest)) or HELP.get(("*", a.dest))
            has_default = (
                not any(a.default is x for x in (None, False, argparse.SUPPRESS)) and not a.required
            )
            if a.help and has_default and "default" not in a.help.lower():
                a.help += " (default: %(default)s)"
    return parser
