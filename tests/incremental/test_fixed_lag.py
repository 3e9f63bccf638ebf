"""Marginalization and the fixed-lag smoother.

* ``marginalize`` leaves a LinearContainerFactor whose information and gradient equal the dense
  Schur complement of the linearized batch system onto the Markov blanket (leaf variables cut
  directly, and variables that first need re-elimination);
* the fixed-lag estimate equals batch Gauss-Newton on the smoother's own factors (window
  factors plus marginal priors); the window, and the arrays behind it, stay bounded;
* LinearContainerFactor: cost = the quadratic, Jacobian = central differences.
"""

import numpy as np
import pytest

import fgopt
from fgopt import (BetweenFactor, FactorGraph, FgoptError, FixedLagSmoother, IncrementalParams,
                   IncrementalSmoother, key)
from fgopt.factors.library.range_bearing import range_bearing_factor
from fgopt.incremental import LinearContainerFactor
from fgopt.manifolds import SE2, SE3
from fgopt.noise import Diagonal
from fgopt.problem import Problem

from ._streams import max_tangent_difference, pose_stream, x


def dense_system(graph, values):
    p = Problem(graph, values)
    st = p.initial_state()
    p.linearize(st)
    H = p.pattern.full(p.H_data).toarray()
    offs = {k: (int(p.pattern.var_offset[v]), int(p.var_dim[v])) for k, v in p._var_of_key.items()}
    return H, p.g.copy(), offs


def schur(H, g, offs, gone, keep):
    idx = lambda ks: np.concatenate([np.arange(offs[k][0], offs[k][0] + offs[k][1]) for k in ks])  # noqa: E731
    m, b = idx(gone), idx(keep)
    S = H[np.ix_(b, b)] - H[np.ix_(b, m)] @ np.linalg.solve(H[np.ix_(m, m)], H[np.ix_(m, b)])
    s = g[b] - H[np.ix_(b, m)] @ np.linalg.solve(H[np.ix_(m, m)], g[m])
    return S, s


def _landmark_problem():
    """Poses x0..x5 and landmarks seen from several of them (a landmark is no leaf)."""
    L = lambda j: key("l", j)  # noqa: E731
    rng = np.random.default_rng(0)
    poses = [SE2.from_xytheta(i, 0.2 * np.sin(i), 0.1 * i) for i in range(6)]
    lms = [np.array([2.0, 3.0]), np.array([4.0, -2.0]), np.array([1.0, -3.0])]
    od, rb = Diagonal.sigmas([0.05, 0.05, 0.02]), Diagonal.sigmas([0.05, 0.02])
    steps = []
    for i in range(6):
        fs = [BetweenFactor(x(i - 1), x(i), poses[i - 1].inverse() * poses[i], od)] if i else \
            [fgopt.PriorFactor(x(0), poses[0], od)]
        vals = {x(i): poses[i] * SE2.exp(rng.normal(0, 0.05, 3))}
        for j in range(3):
            if (i + j) % 2 == 0:
                d = poses[i].inverse().act(lms[j])
                m = np.array([np.hypot(*d), np.arctan2(d[1], d[0])])
                fs.append(range_bearing_factor(pose=x(i), landmark=L(j), loss=rb, measured=m))
                if all(L(j) not in v for _, v in steps) and L(j) not in vals:
                    vals[L(j)] = lms[j] + rng.normal(0, 0.1, 2)
        steps.append((fs, vals))
    return steps


@pytest.mark.parametrize("case", ["chain-leaf", "3d-chain", "landmark-not-leaf"])
def test_marginal_factor_is_the_dense_schur_complement(case):
    """The smoother's factors after marginalization (remaining factors + containers),
    linearized at theta, are the dense Schur complement of the batch system onto the remaining
    variables; the remaining estimate does not move."""
    if case == "landmark-not-leaf":
        steps, gone = _landmark_problem(), [key("l", 0), x(0), x(1)]
    else:
        group = SE3 if case == "3d-chain" else SE2
        steps, gone = pose_stream(group, 14, 11, loop_prob=0.4), [x(0), x(1), x(2)]
    isam = IncrementalSmoother(IncrementalParams(wildfire_threshold=0.0))
    graph = FactorGraph()
    for factors, values in steps:
        isam.update(factors, values)
        graph.extend(factors)
    H, g, offs = dense_system(graph, isam.linearization_point())
    before = isam.estimate()
    lp = isam.linearization_point()
    handles = isam.marginalize(gone)
    assert handles and all(k not in isam for k in gone)
    assert all(isinstance(isam.factor(h), LinearContainerFactor) for h in handles)
    keep = isam.keys()
    S, s = schur(H, g, offs, gone, keep)
    H2, g2, offs2 = dense_system(isam.factors(), fgopt.Variables({k: lp.at(k) for k in keep}))
    perm = np.concatenate([np.arange(offs2[k][0], offs2[k][0] + offs2[k][1]) for k in keep])
    assert np.allclose(H2[np.ix_(perm, perm)], S, rtol=1e-9, atol=1e-9 * np.abs(S).max())
    assert np.allclose(g2[perm], s, rtol=1e-9, atol=1e-9 * max(np.abs(s).max(), 1.0))
    after = isam.estimate()
    for k in after.keys():
        va, vb = before.at(k), after.at(k)
        d = va.local(vb) if hasattr(va, "local") else vb - va
        assert np.abs(d).max() < 1e-9


def test_fixed_lag_equals_batch_on_its_own_factors():
    """Window factors + marginal priors, relinearized to convergence == batch GN on them."""
    params = IncrementalParams(relinearize_threshold=0.0, relinearize_skip=1,
                               wildfire_threshold=0.0, extra_steps=8)
    fl = FixedLagSmoother(6.0, params)
    for i, (factors, values) in enumerate(pose_stream(SE2, 30, 12, loop_prob=0.0)):
        r = fl.update(factors, values, {k: float(i) for k in values})
        if i > 7:
            assert r.marginalized_keys == [x(i - 7)]
        est = fl.estimate()
        ref = fgopt.optimize(fl.factors(), est, method="gn", max_iterations=20,
                             relative_tolerance=0.0, absolute_tolerance=0.0,
                             gradient_tolerance=1e-13, step_tolerance=1e-15).values
        assert max_tangent_difference(est, ref) < 1e-8
        assert len(fl) <= 7 and sorted(fl.keys()) == [x(j) for j in range(max(0, i - 6), i + 1)]


def test_window_and_memory_stay_bounded():
    """A long run with lag 10: the arrays and pools stop growing once the window is full."""
    fl = FixedLagSmoother(10.0)
    steps = pose_stream(SE2, 400, 13, loop_prob=0.0)
    sizes = []
    for i, (factors, values) in enumerate(steps):
        fl.update(factors, values, {k: float(i) for k in values})
        if i in (150, 399):
            t = fl.smoother._tree
            sizes.append((t.VI.shape[1], t.FI.shape[1], t.CI.shape[1], t.cnpool.shape[0],
                          t.cvpool.shape[0], t.hpool.shape[0], t.ADJ.shape[1],
                          len(fl.smoother._facs.slot_of_handle), len(fl._heap)))
    assert sizes[0] == sizes[1]
    assert len(fl) == 11


def test_timestamp_errors_leave_the_smoother_unchanged():
    fl = FixedLagSmoother(5.0)
    (f0, v0), (f1, v1) = pose_stream(SE2, 2, 14)
    fl.update(f0, v0, {x(0): 0.0})
    for stamps, what in (({}, "x1"), ({x(1): 1.0, key("q", 1): 1.0}, "q1"),
                         ({x(1): float("nan")}, "x1")):
        with pytest.raises(FgoptError, match=what):
            fl.update(f1, v1, stamps)
        assert fl.keys() == [x(0)] and fl.timestamps() == {x(0): 0.0}
    with pytest.raises(FgoptError, match="lag"):
        FixedLagSmoother(-1.0)


def test_linear_container_factor_cost_and_jacobian():
    """0.5 |e|^2 = 0.5 dx^T H dx + g^T dx + const, and Jacobians match central differences
    away from the linearization point."""
    rng = np.random.default_rng(3)
    x0 = [SE2.from_xytheta(1.0, 2.0, 0.3), np.array([0.5, -1.0])]
    A = rng.normal(size=(5, 5))
    H, g = A @ A.T + np.eye(5), rng.normal(size=5)
    f = LinearContainerFactor([x(0), key("l", 0)], x0, H, g)
    at = fgopt.Variables({x(0): x0[0] * SE2.from_xytheta(0.2, -0.1, 0.4),
                          key("l", 0): x0[1] + np.array([0.3, 0.2])})
    dx = f.local(at)
    const = 0.5 * g @ np.linalg.solve(H, g)
    assert 0.5 * f.error(at) @ f.error(at) == pytest.approx(0.5 * dx @ H @ dx + g @ dx + const)
    from fgopt.factors import numerical_jacobians

    for J, Jn in zip(f.jacobians(at), numerical_jacobians(f.error, at, f.keys, 1e-6)):
        assert np.allclose(J, Jn, atol=1e-7)
    base = fgopt.Variables({x(0): x0[0], key("l", 0): x0[1]})
    assert np.allclose(np.concatenate(f.jacobians(base), axis=1).T @ f.error(base), g)
