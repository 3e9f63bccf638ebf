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


def test_kernel_mode_flags_are_per_thread():
    """``python_mode`` / ``numpy_mode`` set their flag for their own thread only; a thread that
    never set one reads False (the flags' class defaults, read on every kernel call)."""
    import threading

    from fgopt import _jit

    seen = {}

    def other():
        seen["python"], seen["numpy"] = _jit._mode.python, _jit.numpy_only()

    with _jit.python_mode(), _jit.numpy_mode():
        assert _jit._mode.python and _jit.numpy_only()
        t = threading.Thread(target=other)
        t.start()
        t.join()
    assert seen == {"python": False, "numpy": False}
    assert not _jit._mode.python and not _jit.numpy_only()
