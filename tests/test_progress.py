"""emcee progress: one bar over all chunks of an adaptive run, advanced by the steps taken."""

import emcee
import numpy as np

from hapid.uncertainty._sampler import _adaptive_bar, _run_chunk


def test_one_bar_counts_every_step_of_every_chunk(capsys):
    s = emcee.EnsembleSampler(8, 2, lambda x: -0.5 * np.sum(x**2, axis=1), vectorize=True)
    state = emcee.State(np.random.default_rng(0).normal(size=(8, 2)))
    bar = _adaptive_bar(True, 1000)
    for _ in range(3):
        state = _run_chunk(s, state, 20, 2, bar)
    assert s.iteration == 60 and bar.n == 120 and bar.total == 1000
    bar.close()
    err = capsys.readouterr().err
    assert err.count("| 0/1000") == 1  # one bar was opened (emcee's own opens one per chunk)
    assert _adaptive_bar(False, 1000) is None


def test_robust_says_what_it_checks_on_stderr_before_the_long_step(tmp_path, monkeypatch):
    """``hapid robust``: a progress line on stderr (not stdout) before the loop draws are made
    and checked — the ~13 s step — and none with ``--quiet``."""
    from helpers_cli import run_cli, write_valid_files

    import hapid.robust

    write_valid_files(tmp_path)
    calls = []

    def stop(*a, **k):  # stands in for the long step: the line must already be out
        calls.append(k.get("n_draws"))
        raise ValueError("stopped by the test")

    monkeypatch.setattr(hapid.robust, "loop_gp_check", stop)
    argv = ["robust", "--frf", "frf.npz", "--model", "model.npz", "--max-samples", "37"]
    rc, out, err, _, _ = run_cli(argv, tmp_path)
    assert rc == 2 and calls == [37]
    lines = err.splitlines()
    said = [i for i, ln in enumerate(lines) if ln.startswith("robust: 37 loop draws conditioned")]
    stopped = [i for i, ln in enumerate(lines) if "stopped by the test" in ln]
    assert said and stopped and said[0] < stopped[0], err
    assert "expected)" in lines[said[0]]  # elapsed against the expected time
    assert "robust:" not in out
    rc, out, err, _, _ = run_cli(argv + ["--quiet"], tmp_path)
    assert rc == 2 and calls == [37, 37] and "robust:" not in err + out
