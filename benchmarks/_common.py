"""Shared benchmark helpers: machine header, timing, tables."""

from __future__ import annotations

import os
import platform
import time
from importlib import metadata


def header(title: str) -> str:
    pk = []
    for name in ("jax", "jaxlib", "numpy", "scipy", "optimistix", "jaxopt", "emcee", "equinox"):
        try:
            pk.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            pass
    lines = [
        f"# {title}",
        f"machine: {platform.machine()}, {os.cpu_count()} cores, {platform.processor() or 'cpu'}; "
        f"python {platform.python_version()}",
        "versions: " + ", ".join(pk),
        f"date: {time.strftime('%Y-%m-%d %H:%M:%S')}",
    ]
    return "\n".join(lines)


def timeit(fn, *, repeat: int = 5, number: int = 1) -> float:
    """Best-of-``repeat`` wall time of ``number`` calls, in seconds per call."""
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t) / number)
    return best


def table(rows: list[dict]) -> str:
    keys = list(rows[0])
    w = {k: max(len(k), *(len(str(r[k])) for r in rows)) for k in keys}
    out = ["| " + " | ".join(k.ljust(w[k]) for k in keys) + " |",
           "|" + "|".join("-" * (w[k] + 2) for k in keys) + "|"]  # fmt: skip
    for r in rows:
        out.append("| " + " | ".join(str(r[k]).ljust(w[k]) for k in keys) + " |")
    return "\n".join(out)
