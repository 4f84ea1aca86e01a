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
