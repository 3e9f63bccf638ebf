"""Threaded linearization gives the same H, g and cost as the serial path."""

import numpy as np

import fgopt
from fgopt.datasets import grid_3d, manhattan_2d


def test_threaded_linearization_matches_serial():
    for data in (manhattan_2d(1200, seed=2), grid_3d(800, seed=2)):
        serial = fgopt.Problem(data.graph, data.initial)
        threaded = fgopt.Problem(data.graph, data.initial, threads=2)
        assert max(len(b.source) for b in threaded.batches) >= 512  # the threaded path runs
        c1 = serial.linearize(serial.initial_state())
        c2 = threaded.linearize(threaded.initial_state())
        assert np.isclose(c1, c2, rtol=1e-12)
        assert np.allclose(serial.H_data, threaded.H_data, rtol=1e-12, atol=1e-12)
        assert np.allclose(serial.g, threaded.g, rtol=1e-12, atol=1e-12)


def test_optimize_with_threads_option():
    data = manhattan_2d(800, seed=3)
    r1 = fgopt.optimize(data.graph, data.initial)
    r2 = fgopt.optimize(data.graph, data.initial, threads=2)
    assert r2.success and np.isclose(r1.final_cost, r2.final_cost, rtol=1e-9)
