"""Shape-specialized scatter kernels (``fgopt._scatter_fixed``) compute exactly what the generic
``scatter_batch`` computes, for every noise / loss / arity case, and the problem uses them."""

import numpy as np
import pytest

from fgopt import _assembly as asm
from fgopt import _scatter_fixed as sf
from fgopt.noise.models import loss_code_and_param
from fgopt.noise import Huber


def _case(rng, n, m, dims, unit):
    k, D = len(dims), sum(dims)
    res = rng.normal(size=(n, m))
    jac = rng.normal(size=(n, m, D))
    R = np.triu(rng.normal(size=(n, m, m))) + 3 * np.eye(m)
    sqrt_info = np.eye(m)[None] if unit else R
    toff = rng.integers(0, 50, size=(n, k)).astype(np.int64)
    pos = np.full((n, k, k), -1, dtype=np.int64)
    for i in range(n):
        for p in range(k):
            for q in range(k):
                stored = p == q or (p > q) == bool((i + p + q) % 2)  # either orientation
                if stored:
                    pos[i, p, q] = rng.integers(0, 200)
    col_shift = rng.integers(0, 40, size=60).astype(np.int64)
    return res, jac, sqrt_info, toff, pos, col_shift


@pytest.mark.parametrize("dims", [(3,), (3, 3), (6, 6), (9, 3), (2, 3, 1), (6, 3, 6, 3, 6)])
@pytest.mark.parametrize("unit", [True, False])
@pytest.mark.parametrize("robust", [False, True])
def test_specialized_equals_generic(dims, unit, robust):
    """Same H, g, cost and weights (to rounding) as the generic kernel."""
    rng = np.random.default_rng(len(dims) * 7 + sum(dims))
    n, m = 80, 2 + len(dims)
    res, jac, sqrt_info, toff, pos, col_shift = _case(rng, n, m, dims, unit)
    code, param, shape = loss_code_and_param(Huber(1.0) if robust else None)
    fixed = sf.scatter_kernel(m, dims, unit, n)
    assert fixed is not None
    out = []
    for generic in (True, False):
        H, g, w = np.zeros(300), np.zeros(60), np.zeros(n)
        if generic:
            offs = np.concatenate([[0], np.cumsum(dims)[:-1]]).astype(np.int64)
            c = asm.scatter_batch(res, jac, sqrt_info, unit, code, param, shape,
                                  np.array(dims, np.int64), offs, toff, pos, col_shift, H, g, w,
                                  0.5)
        else:
            c = fixed(res, jac, sqrt_info, code, param, shape, toff, pos, col_shift, H, g, w,
                      0.5)
        out.append((c, H, g, w))
    (c0, H0, g0, w0), (c1, H1, g1, w1) = out
    assert c1 == pytest.approx(c0, rel=1e-12)
    assert np.allclose(H1, H0, rtol=1e-12, atol=1e-12)
    assert np.allclose(g1, g0, rtol=1e-12, atol=1e-12)
    assert np.array_equal(w1, w0)


def test_small_or_wide_batches_keep_the_generic_kernel():
    """Small batches and batches of many arguments are not specialized (wide residuals allow
    up to ``MAX_ARGS_WIDE`` arguments)."""
    assert sf.scatter_kernel(3, (3, 3), True, sf.MIN_FACTORS - 1) is None
    assert sf.scatter_kernel(2, (6,) * (sf.MAX_ARGS + 1), True, 1000) is None
    assert sf.scatter_kernel(9, (3,) * (sf.MAX_ARGS_WIDE + 1), True, 1000) is None


def test_problem_linearization_is_unchanged(monkeypatch):
    """A pose graph linearizes to the same H and g with and without specialization (batches
    assembled by numba: above ``NUMPY_MAX_BATCH``, or once the NumPy twin budget is spent)."""
    import fgopt
    from fgopt.datasets import manhattan_2d
    from fgopt.problem import Problem

    d = manhattan_2d(1200, seed=4)
    out = []
    for enabled in (False, True):
        monkeypatch.setattr(sf, "ENABLED", enabled)
        p = Problem(d.graph, d.initial)
        cost = p.linearize(p.initial_state())
        out.append((cost, p.H_data.copy(), p.g.copy(), p))
    assert out[1][0] == pytest.approx(out[0][0], rel=1e-12)
    assert np.allclose(out[1][1], out[0][1], rtol=1e-12, atol=1e-9)
    assert np.allclose(out[1][2], out[0][2], rtol=1e-12, atol=1e-9)
    assert any(f is not None for b in out[1][3].batches for f in b.fixed.values())
    r = fgopt.optimize(d.graph, d.initial)
    assert r.success
