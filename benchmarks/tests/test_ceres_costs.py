"""pyceres callback costs: analytic Jacobians vs central differences."""

import numpy as np
import pytest

pytest.importorskip("pyceres")

from benchmarks.peers.ceres_runner import cost_classes  # noqa: E402


def _check(cost, params, sizes, nres):
    def ev(ps, jac):
        r = np.zeros(nres)
        J = [np.zeros(nres * s) for s in sizes] if jac else None
        cost.Evaluate([p.copy() for p in ps], r, J)
        return r, J

    _, J = ev(params, True)
    for b, s in enumerate(sizes):
        num = np.zeros((nres, s))
        for k in range(s):
            h = 1e-6
            pp = [p.copy() for p in params]
            pm = [p.copy() for p in params]
            pp[b][k] += h
            pm[b][k] -= h
            num[:, k] = (ev(pp, False)[0] - ev(pm, False)[0]) / (2 * h)
        np.testing.assert_allclose(J[b].reshape(nres, s), num, atol=1e-6 * max(1, abs(num).max()))


def test_jacobians():
    P2, P3, SN, BR = cost_classes()
    rng = np.random.default_rng(3)

    def q():
        v = rng.normal(size=4)
        return v / np.linalg.norm(v)

    A = rng.normal(size=(6, 6))
    S = np.linalg.cholesky(A @ A.T + 6 * np.eye(6)).T
    _check(P3(np.r_[rng.normal(size=3), q()], S),
           [rng.normal(size=3), q(), rng.normal(size=3), q()], [3, 4, 3, 4], 6)
    _check(P2(rng.normal(size=3), S[:3, :3]), [rng.normal(size=3), rng.normal(size=3)], [3, 3], 3)
    cam = np.r_[rng.normal(size=3) * 0.3, 0.1, 0.2, -5, 500, -0.1, 0.01]
    _check(SN(np.array([10.0, -20.0])), [cam, rng.normal(size=3)], [9, 3], 2)
    _check(BR(np.array([3.0, 4.0]), np.array([0.3, 5.0]), np.array([0.05, 0.1])),
           [rng.normal(size=3)], [3], 2)
