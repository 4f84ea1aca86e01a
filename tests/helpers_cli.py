"""Shared by the CLI edge and fuzz tests: valid small files built by hand (no simulation), and
an in-process runner that records exit code, stdout/stderr, warnings and files written."""

from __future__ import annotations

import contextlib
import gc
import io
import os
import warnings
from pathlib import Path

import numpy as np

from hapid.cli import main

N_RODS = 3  # small files: the CLI never needs to do real work on them to reject an option


def write_valid_files(d: Path, n: int = N_RODS) -> dict[str, Path]:
    """A valid run, FRF, model, samples and scene file in ``d`` (cheap: numpy only)."""
    from hapid import io as hio
    from hapid.fit import n_params
    from hapid.frf import as_frf
    from hapid.impedance import ImpedanceModel, SecondOrder

    d.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    E, Tp, periods = n, 100, 2
    sig = {k: rng.normal(size=(E, Tp * periods, n)) for k in ("R_A", "R_I", "L")}
    np.savez(
        d / "run.npz", fs_hz=1000.0, period_samples=Tp, freq_hz=np.array([10.0, 20.0, 50.0]), **sig
    )
    f = np.array([1.0, 2.0, 5.0, 10.0])
    Z = rng.normal(size=(4, n, n)) + 1j * rng.normal(size=(4, n, n)) + 5 * np.eye(n)
    hio.save_frf(d / "frf.npz", as_frf(f, Z, 2 * Z, np.full(Z.shape, 0.01), np.full(Z.shape, 0.01)))
    eye = np.eye(n)
    so = SecondOrder(0.1 * eye, 2.0 * eye, 100.0 * eye)
    hio.save_model(d / "model.npz", ImpedanceModel(so, so + so))
    p = n_params(n)
    np.savez(d / "samples.npz", samples=rng.normal(size=(8, p)), log_prob=np.zeros(8), n=np.int64(n),
             names=np.asarray([f"t{i}" for i in range(p)]), omega_ref=1.0, z_ref=1.0,
             method=np.asarray("fake"))  # fmt: skip
    hio.save_run(d / "run.csv", hio.load_run(d / "run.npz"))
    hio.save_frf(d / "frf.csv", hio.load_frf(d / "frf.npz"))
    (d / "scene.toml").write_text('[controller]\nk = 0.6\n[outputs]\nwant = ["summary"]\n')
    return {k: d / f"{k}.{ext}" for k, ext in (("run", "npz"), ("frf", "npz"), ("model", "npz"),
                                                ("samples", "npz"), ("scene", "toml"))}  # fmt: skip


def listing(d: Path) -> set:
    return {str(p.relative_to(d)) for p in Path(d).rglob("*")}


def run_cli(argv, cwd: Path):
    """Run ``hapid.cli.main(argv)`` in-process inside ``cwd``: ``(rc, stdout, stderr,
    warnings, new files)``."""
    before = listing(cwd)
    out, err = io.StringIO(), io.StringIO()
    old = os.getcwd()
    fmt = warnings.formatwarning
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        os.chdir(cwd)
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                try:
                    rc = main([str(a) for a in argv])
                except SystemExit as e:
                    rc = e.code
            gc.collect(1)  # unclosed files warn when freed (young generations: cheap)
        finally:
            os.chdir(old)
            warnings.formatwarning = fmt
    return rc, out.getvalue(), err.getvalue(), list(w), listing(cwd) - before


def assert_clean_error(argv, cwd: Path, must_contain: str | None = None) -> str:
    """The CLI's promise for bad input: exit 2, exactly one ``hapid: error:`` line, no
    traceback, no warning, no file written. Returns the error line."""
    rc, out, err, warns, new = run_cli(argv, cwd)
    lines = [ln for ln in err.splitlines() if ln.startswith("hapid: error:")]
    assert rc == 2, f"{argv}: exit {rc}\nstdout: {out}\nstderr: {err}"
    assert len(lines) == 1, f"{argv}: {len(lines)} error lines\n{err}"
    assert "Traceback" not in err + out, f"{argv}: traceback\n{err}"
    assert not [ln for ln in err.splitlines() if "warning" in ln.lower()], f"{argv}: {err}"
    assert not warns, f"{argv}: warnings {[str(x.message) for x in warns]}"
    assert not new, f"{argv}: wrote {sorted(new)}"
    if must_contain is not None:
        assert must_contain in lines[0], f"{argv}: {lines[0]!r} lacks {must_contain!r}"
    return lines[0]
