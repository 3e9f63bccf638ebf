"""The numba kernels: batched loops equal the value classes; Jacobians, ad, phi, Sim3's W."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from fgopt.manifolds import SE3, SO3, Sim3
from fgopt.manifolds import _kernels as K


def _load_checks():
    name = "fgopt_tests_manifold_checks"
    if name not in sys.modules:
        path = Path(__file__).resolve().parents[1] / "manifolds" / "_checks.py"
        spec = importlib.util.spec_from_file_location(name, path)
        sys.modules[name] = module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    return sys.modules[name]


C = _load_checks()
over_groups = C.over_groups
seeds = st.integers(0, 2**32 - 1)
angles = st.sampled_from(C.SPECIAL_ANGLES)
fast = settings(max_examples=25, deadline=None)


def _rows(G, values):
    return np.array([v.to_storage() for v in values]).reshape(len(values), G.storage_dim())


@over_groups
class TestBatched:
    @settings(max_examples=10, deadline=None)
    @given(seed=seeds, n=st.sampled_from([0, 1, 7]))
    def test_batched_equal_per_element(self, G, seed, n):
        rng = np.random.default_rng(seed)
        gid = G._GID
        a = [G.random(rng) for _ in range(n)]
        b = [G.random(rng) for _ in range(n)]
        d = np.array([C.random_tangent(G, rng, rng.choice(C.SPECIAL_ANGLES)) for _ in range(n)])
        d = d.reshape(n, G.dim())
        A, B = _rows(G, a), _rows(G, b)
        A, B = A.reshape(n, G.storage_dim()), B.reshape(n, G.storage_dim())
        exact = {"rtol": 0, "atol": 0}
        kind = G.batch_kind()
        np.testing.assert_allclose(kind.retract(A, d), _rows(G, [
            x.retract(v) for x, v in zip(a, d)]).reshape(A.shape), **exact)
        np.testing.assert_allclose(kind.local(A, B), np.array([
            x.local(y) for x, y in zip(a, b)]).reshape(d.shape), **exact)
        np.testing.assert_allclose(K.batch_retract(gid, A, d), kind.retract(A, d), **exact)
        # the compiled loop alone (the incremental smoother's entry for contiguous rows)
        np.testing.assert_allclose(kind.retract.compiled(A, d), kind.retract(A, d), **exact)
        np.testing.assert_allclose(K.batch_local(gid, A, B), kind.local(A, B), **exact)

    def test_retract_rows_in_place_equals_the_batched_retract(self, G):
        """``retract_rows`` (the incremental smoother's gather-retract-scatter) writes, bit for
        bit, what the batched retract returns, in the selected rows only, also in place and
        with ``delta`` wider than the tangent dim."""
        rng = np.random.default_rng(11)
        n, gid, kind = 9, G._GID, G.batch_kind()
        X = _rows(G, [G.random(rng) for _ in range(n)])
        wide = np.zeros((n, G.dim() + 2))
        wide[:, :G.dim()] = [C.random_tangent(G, rng, rng.choice(C.SPECIAL_ANGLES))
                             for _ in range(n)]
        wide[:, G.dim():] = np.nan   # never read
        rows = np.array([7, 2, 4], np.int64)
        expect = kind.retract.compiled(X[rows], np.ascontiguousarray(wide[rows, :G.dim()]))
        out = np.full_like(X, -5.0)
        K.retract_rows(gid)(X, wide, rows, out)
        np.testing.assert_array_equal(out[rows], expect)
        others = np.setdiff1d(np.arange(n), rows)
        assert np.all(out[others] == -5.0)
        Y = X.copy()
        K.retract_rows(gid)(Y, wide, rows, Y)
        np.testing.assert_array_equal(Y[rows], expect)
        np.testing.assert_array_equal(Y[others], X[others])

    def test_wrap_all_builds_what_wrap_builds_row_by_row(self, G):
        # the bulk constructor behind result values and Variables' bulk rows
        rng = np.random.default_rng(5)
        values = [G.random(rng) for _ in range(9)]
        rows = _rows(G, values)
        rows.flags.writeable = False
        kind = G.batch_kind()
        made = kind.wrap_all(rows)
        assert len(made) == 9 and kind.wrap_all(rows[:0]) == []
        for x, y, row in zip(made, values, rows):
            assert type(x) is G
            np.testing.assert_array_equal(x.to_storage(), y.to_storage())
            assert not x._data.flags.writeable and np.shares_memory(x._data, row)
            np.testing.assert_array_equal(x.log(), kind.wrap(row).log())

    def test_batched_accepts_strided_rows(self, G):
        rng = np.random.default_rng(3)
        A = _rows(G, [G.random(rng) for _ in range(6)])
        D = rng.normal(size=(6, G.dim())) * 0.1
        kind = G.batch_kind()
        np.testing.assert_array_equal(kind.retract(A[::2], D[::2]), kind.retract(A, D)[::2])


@over_groups
class TestJacobians:
    @fast
    @given(seed=seeds, angle=angles)
    def test_jr_closed_form_matches_phi_of_ad(self, G, seed, angle):
        v = C.random_tangent(G, np.random.default_rng(seed), angle)
        d = G.dim()
        ad, jr, jrn, jri = (np.zeros((d, d)) for _ in range(4))
        K.lie_ad(G._GID, v, ad)
        K.lie_jr(G._GID, v, jr)
        K.jr_from_ad(ad, jrn)
        np.testing.assert_allclose(jr, jrn, atol=1e-12 * max(1.0, np.abs(jrn).max()))
        K.lie_jrinv(G._GID, v, jri)
        np.testing.assert_allclose(jri @ jr, np.eye(d), atol=1e-10 * max(1, np.abs(jri).max()))

    @fast
    @given(seed=seeds, angle=angles)
    def test_jr_definition_by_finite_differences(self, G, seed, angle):
        # Exp(v + d) = Exp(v) Exp(Jr(v) d)  =>  Jr = d/dd Log(Exp(v)^-1 Exp(v + d)).
        angle = min(angle, 3.0)  # Log(Exp(v)^-1 Exp(v + d)) is smooth; keep v + d below pi
        v = C.random_tangent(G, np.random.default_rng(seed), angle)
        x = G.exp(v)
        num = C.numerical_jacobian(lambda u: x.local(G.exp(u)), [v], 0)
        jr = np.zeros((G.dim(), G.dim()))
        K.lie_jr(G._GID, v, jr)
        C.assert_jacobian_close(jr, num)

    @fast
    @given(seed=seeds)
    def test_ad_is_the_bracket(self, G, seed):
        rng = np.random.default_rng(seed)
        a, b = C.random_tangent(G, rng), C.random_tangent(G, rng)
        ad = np.zeros((G.dim(), G.dim()))
        K.lie_ad(G._GID, a, ad)
        ha, hb = C.hat(G, a), C.hat(G, b)
        np.testing.assert_allclose(C.hat(G, ad @ b), ha @ hb - hb @ ha, atol=1e-12)


class TestHelpers:
    def test_phi_matrix_and_invert(self):
        rng = np.random.default_rng(0)
        for scale in (0.0, 1e-6, 0.3, 4.0, 60.0):
            a = rng.normal(size=(5, 5)) * scale / 5.0
            big = np.zeros((10, 10))
            big[:5, :5], big[:5, 5:] = a, np.eye(5)
            expected = scipy.linalg.expm(big)[:5, 5:]  # phi(a) from the augmented exponential
            out, inv = np.empty((5, 5)), np.empty((5, 5))
            K.phi_matrix(a, out)
            np.testing.assert_allclose(out, expected, rtol=1e-10, atol=1e-13)
            if scale < 10.0:  # phi of the largest one is too ill-conditioned to invert well
                K.invert(out, inv)
                np.testing.assert_allclose(inv @ out, np.eye(5), atol=1e-10)

    @settings(max_examples=25, deadline=None)
    @given(seed=seeds)
    def test_quaternion_helpers(self, seed):
        rng = np.random.default_rng(seed)
        a, b = SO3.random(rng), SO3.random(rng)
        out = np.empty(4)
        K.quat_mul(a.to_storage(), b.to_storage(), out)
        assert SO3(out).equals(a * b, 1e-14)
        p, r = rng.normal(size=3), np.empty(3)
        K.quat_rotate(a.to_storage(), p, r)
        np.testing.assert_allclose(r, a.matrix() @ p, atol=1e-14)
        K.quat_rotate(a.to_storage(), p, r, -1.0)
        np.testing.assert_allclose(r, a.matrix().T @ p, atol=1e-14)

    @pytest.mark.parametrize("lam", [0.0, 1e-12, 1e-6, 1e-5 * (1 - 1e-9), 1e-5 * (1 + 1e-9),
                                     -0.3, 0.49999, 0.50001, -0.7, 3.0, -12.0])
    @pytest.mark.parametrize("theta", [0.0, 1e-12, 1e-7, 1e-3 * (1 - 1e-9), 1e-3 * (1 + 1e-9),
                                       0.3, 2.5, math.pi - 1e-9, math.pi])
    def test_sim3_exp_matches_expm_at_limits(self, lam, theta):
        rng = np.random.default_rng(int(1e6 * (lam + 13) + 1e3 * theta))
        v = C.random_tangent(Sim3, rng, theta)
        v[6] = lam
        expected = scipy.linalg.expm(C.hat(Sim3, v))
        got = Sim3.exp(v).matrix()
        np.testing.assert_allclose(got, expected, rtol=0, atol=2e-13 * np.abs(expected).max())
        np.testing.assert_allclose(Sim3.exp(v).log(), v, atol=1e-10)

    def test_se3_q_small_angle_branch_is_continuous(self):
        rng = np.random.default_rng(1)
        w = rng.normal(size=3)
        w /= np.linalg.norm(w)
        p = rng.normal(size=3)
        qs = []
        for t in (0.1 * (1 - 1e-9), 0.1 * (1 + 1e-9)):
            out = np.empty((3, 3))
            K.se3_q(*(t * w), *p, out, 0, 0)
            qs.append(out)
        np.testing.assert_allclose(qs[0], qs[1], atol=1e-13)

    def test_group_tables(self):
        for gid, G in enumerate(C.GROUPS):
            assert G._GID == gid and K.GROUP_NAMES[gid] == G.__name__
            assert (K.STORAGE_DIMS[gid], K.TANGENT_DIMS[gid]) == (G.storage_dim(), G.dim())
            assert (K.storage_dim(gid), K.tangent_dim(gid)) == (G.storage_dim(), G.dim())
        assert SE3.batch_kind().retract is K.se3_retract_batch


def test_group_operations_keep_python_mode_once_their_dispatcher_is_cached(monkeypatch):
    """A group operation goes straight to its numba dispatcher once built (a cached lookup),
    with the same result as the entry, and still runs the pure-Python kernel inside
    ``python_mode``."""
    from fgopt import _jit
    from fgopt.manifolds import SE2, lie

    a, b = SE2.from_xytheta(1.0, 2.0, 0.3), SE2.from_xytheta(-0.5, 0.2, 2.9)
    monkeypatch.setattr(lie, "_element_ops", [lie.PYTHON_ELEMENT_OPS])  # numba from now on
    expect = a * b
    d = lie._DISPATCHERS.get((K.lie_compose, SE2._GID))
    assert d is not None and d is _jit.specialize(K.lie_compose, SE2._GID)._dispatcher
    np.testing.assert_array_equal((a * b).to_storage(), expect.to_storage())
    calls = []
    monkeypatch.setitem(lie._DISPATCHERS, (K.lie_compose, SE2._GID),
                        lambda *args: calls.append(1))
    a * b
    assert calls == [1]  # the cached dispatcher is what runs
    with _jit.python_mode():
        got = a * b
    assert calls == [1] and np.array_equal(got.to_storage(), expect.to_storage())
