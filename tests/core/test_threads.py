"""Threaded linearization gives the same H, g and cost as the serial path."""

import numpy as np

import fgopt
from fgopt.datasets import grid_3d, manhattan_2d


def test_threaded_linearization_matches_serial():
    for data in (manhattan_2d(1200, seed=2), grid_3d(800, seed=2)):
        # the same backend for both: the NumPy backend may lay H out in another order
        serial = fgopt.Problem(data.graph, data.initial, backend="numba")
        threaded = fgopt.Problem(data.graph, data.initial, threads=2)
        assert max(len(b.source) for b in threaded.batches) >= 512  # the threaded path runs
        c1 = serial.linearize(serial.initial_state())
        c2 = threaded.linearize(threaded.initial_state())
        assert np.isclose(c1, c2, rtol=1e-12)
        # the kernel's own J^T J and the threaded path's (formed from J) round differently
        scale_H, scale_g = np.abs(serial.H_data).max(), np.abs(serial.g).max()
        np.testing.assert_allclose(threaded.H_data, serial.H_data, rtol=1e-11, atol=1e-13 * scale_H)
        np.testing.assert_allclose(threaded.g, serial.g, rtol=1e-11, atol=1e-13 * scale_g)


def test_optimize_with_threads_option():
    data = manhattan_2d(800, seed=3)
    r1 = fgopt.optimize(data.graph, data.initial)
    r2 = fgopt.optimize(data.graph, data.initial, threads=2)
    assert r2.success and np.isclose(r1.final_cost, r2.final_cost, rtol=1e-9)
