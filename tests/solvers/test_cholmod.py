"""fgopt's CHOLMOD wrapper runs CHOLMOD's OpenMP loops serially, and leaves the process's
OpenMP setting as it found it (nested and concurrent users included)."""

import threading

import numpy as np
import pytest

pytest.importorskip("sksparse.cholmod")

from fgopt import Problem  # noqa: E402
from fgopt.datasets import grid_3d  # noqa: E402
from fgopt.solvers.linear import cholmod  # noqa: E402
from fgopt.solvers.linear.cholmod import CholmodSolver, serial_openmp  # noqa: E402


def _levels_api():
    api = cholmod._openmp_levels_api()
    if not api:
        pytest.skip("this CHOLMOD is built without OpenMP: nothing to serialize")
    return api


def test_serial_openmp_makes_every_region_inactive_then_restores():
    """Inside, max-active-levels is 0 (every parallel region runs with one thread); after, the
    value found before is back, also after nesting and after an exception."""
    get, set_ = _levels_api()
    before = get()
    with serial_openmp():
        assert get() == 0
        with serial_openmp():
            assert get() == 0
        assert get() == 0
    assert get() == before
    with pytest.raises(RuntimeError):
        with serial_openmp():
            raise RuntimeError("inside")
    assert get() == before
    set_(3)  # a user's own setting is what comes back
    try:
        with serial_openmp():
            assert get() == 0
        assert get() == 3
    finally:
        set_(before)


def test_serial_openmp_from_threads_restores_each_threads_value():
    """Users in several threads each see 0 inside and find the value they left after."""
    get, _ = _levels_api()
    before = get()
    seen, errors = [], []

    def user():
        try:
            for _ in range(50):
                # the wrapper's own lock: under a runtime whose setting is per process, another
                # thread's region must not run between reading the value and checking it
                with cholmod._openmp_lock:
                    found = get()
                    with serial_openmp():
                        seen.append(get())
                    if get() != found:
                        errors.append((found, get()))
        except Exception as e:  # surfaced below: an assert in a thread would be lost
            errors.append(e)

    threads = [threading.Thread(target=user) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert seen == [0] * 150
    assert get() == before


def test_factorize_runs_cholmod_serially_and_solves():
    """CholmodSolver's numeric factorization runs inside serial_openmp, and its solution of a
    3D pose graph's H (supernodal) matches a dense solve."""
    get, _ = _levels_api()
    synthetic = grid_3d(200, seed=1)
    p = Problem(synthetic.graph, synthetic.initial)
    p.linearize(p.initial_state())
    H = p.H_data.copy()
    H[p.pattern.diag_pos] += 1e-3
    solver = CholmodSolver(mode="supernodal")
    solver.analyze(p.pattern)
    levels = []
    factor = solver._factor

    class Recording:  # CHOLMOD's Factor is an immutable extension type: wrap, not patch
        def cholesky_inplace(self, A, *args, **kwargs):
            levels.append(get())
            return factor.cholesky_inplace(A, *args, **kwargs)

        def __call__(self, b):
            return factor(b)

        def copy(self):  # the pivot test reads D from a copy of a supernodal factor
            return factor.copy()

        def P(self):
            return factor.P()

    solver._factor = Recording()
    solver.factorize(H)
    assert levels == [0]
    x, x_dense = solver.solve(p.g), np.linalg.solve(p.pattern.full(H).toarray(), p.g)
    assert np.linalg.norm(x - x_dense) <= 1e-9 * np.linalg.norm(x_dense)

