"""Update semantics: factor removal, keys in any order, every factor type, marginals, and
atomic refusal of bad input (the smoother's state is unchanged, checked against a twin)."""

import numpy as np
import pytest

import fgopt
from fgopt import (BetweenFactor, FactorGraph, FgoptError, IncrementalParams,
                   IncrementalSmoother, PriorFactor, key)
from fgopt.errors import (DuplicateKeyError, KeyNotFoundError, ManifoldError, NonFiniteError,
                          NotPositiveDefiniteError)
from fgopt.factors import NumericalFactor
from fgopt.factors.library.range_bearing import range_bearing_factor, range_factor
from fgopt.manifolds import SE2
from fgopt.noise import Diagonal, Huber

from ._streams import max_tangent_difference, pose_stream, x

EXACT = dict(relinearize_threshold=0.0, relinearize_skip=1, wildfire_threshold=0.0,
             extra_steps=8)


def converged(graph, values):
    return fgopt.optimize(graph, values, method="gn", max_iterations=30, relative_tolerance=0.0,
                          absolute_tolerance=0.0, gradient_tolerance=1e-13,
                          step_tolerance=1e-15).values


def test_removing_a_factor_equals_solving_without_it():
    """A wrong loop closure added then removed: the estimate equals batch GN without it (and
    the linear system stays exact in between)."""
    steps = pose_stream(SE2, 20, 3, loop_prob=0.4)
    isam = IncrementalSmoother(IncrementalParams(**EXACT))
    graph = FactorGraph()
    for factors, values in steps[:12]:
        isam.update(factors, values)
        graph.extend(factors)
    bad = BetweenFactor(x(2), x(10), SE2.from_xytheta(5.0, -3.0, 2.0), Diagonal.sigmas([0.05] * 3))
    r = isam.update([bad])
    isam.update(steps[12][0], steps[12][1], remove=r.new_factor_indices)
    graph.extend(steps[12][0])
    assert max_tangent_difference(isam.estimate(), converged(graph, isam.estimate())) < 1e-8
    for factors, values in steps[13:]:
        isam.update(factors, values)
        graph.extend(factors)
    assert len(isam.factors()) == len(graph)
    assert max_tangent_difference(isam.estimate(), converged(graph, isam.estimate())) < 1e-8


def test_removing_the_last_factor_of_a_variable_drops_it():
    """As GTSAM: a variable left without factors leaves the smoother (reported)."""
    isam = IncrementalSmoother()
    steps = pose_stream(SE2, 6, 4, loop_prob=0.0)
    handles = [isam.update(f, v).new_factor_indices for f, v in steps]
    r = isam.update(remove=handles[5])
    assert r.removed_keys == [x(5)] and x(5) not in isam and len(isam) == 5
    r = isam.update(steps[5][0], steps[5][1])      # the key can come back
    assert x(5) in isam


def test_keys_in_any_order_and_every_factor_type():
    """Landmarks before poses, Python factors, generated factors, robust losses: the converged
    estimate equals batch Gauss-Newton on the same graph."""
    class PythonPrior(NumericalFactor):
        def __init__(self, k, value, noise):
            super().__init__([k], 3, noise)
            self.value = value

        def error(self, values):
            return self.value.local(values.at(self.keys[0]))

    L = lambda j: key("l", j)  # noqa: E731
    rb = Diagonal.sigmas([0.05, 0.01])
    od = Diagonal.sigmas([0.05, 0.05, 0.02])
    isam = IncrementalSmoother(IncrementalParams(**EXACT))
    graph = FactorGraph()
    poses = [SE2.from_xytheta(i, 0.1 * i, 0.05 * i) for i in range(6)]
    lms = [np.array([2.0, 3.0]), np.array([4.0, -2.0])]

    def obs(i, j):
        d = poses[i].inverse().act(lms[j])
        return np.array([np.hypot(*d), np.arctan2(d[1], d[0])])

    batches = [
        ([PythonPrior(x(0), poses[0], od), range_bearing_factor(pose=x(0), landmark=L(0),
                                                                 measured=obs(0, 0), loss=rb)],
         {L(0): lms[0] + 0.3, x(0): poses[0]}),
        ([range_bearing_factor(pose=x(1), landmark=L(1), measured=obs(1, 1), loss=rb),
          BetweenFactor(x(0), x(1), poses[0].inverse() * poses[1], Huber(1.0, od)),
          range_bearing_factor(pose=x(1), landmark=L(0), measured=obs(1, 0), loss=rb)],
         {L(1): lms[1] - 0.2, x(1): poses[1] * SE2.from_xytheta(0.1, 0.1, 0.05)}),
    ]
    for i in range(2, 6):
        batches.append(([BetweenFactor(x(i - 1), x(i), poses[i - 1].inverse() * poses[i], od),
                         range_bearing_factor(pose=x(i), landmark=L(i % 2), measured=obs(i, i % 2),
                                              loss=Huber(2.0, rb))],
                        {x(i): poses[i] * SE2.from_xytheta(-0.1, 0.05, 0.03)}))
    for factors, values in batches:
        isam.update(factors, values)
        graph.extend(factors)
        assert max_tangent_difference(isam.estimate(), converged(graph, isam.estimate())) < 1e-8
    assert isam.cost() == pytest.approx(graph.error(isam.estimate()), rel=1e-12)


def test_marginal_equals_batch_marginal():
    """marginal(key) from the Bayes tree == the block of H^-1 at the linearization point."""
    isam = IncrementalSmoother(IncrementalParams(wildfire_threshold=0.0))
    graph = FactorGraph()
    for factors, values in pose_stream(SE2, 30, 6):
        isam.update(factors, values)
        graph.extend(factors)
    lp = isam.linearization_point()
    ref = fgopt.marginals(None, graph=graph, values=lp, linear_solver="dense")
    for k in (x(0), x(7), x(29)):
        assert np.allclose(isam.marginal(k), ref[k], rtol=1e-9, atol=1e-14)


# ------------------------------------------------------------------ bad input
def _twins():
    """Two smoothers fed the same prefix of a stream, and the rest of it."""
    steps = pose_stream(SE2, 16, 8)
    a, b = IncrementalSmoother(), IncrementalSmoother()
    handles = []
    for factors, values in steps[:9]:
        handles += a.update(factors, values).new_factor_indices
        b.update(factors, values)
    return a, b, steps[9:], handles


def _same_state(a, b):
    ea, eb = a.estimate(), b.estimate()
    assert ea.keys() == eb.keys() and max_tangent_difference(ea, eb) == 0.0
    la, lb = a.linearization_point(), b.linearization_point()
    assert max_tangent_difference(la, lb) == 0.0
    assert len(a.factors()) == len(b.factors()) and a.keys() == b.keys()
    assert np.array_equal(a.marginal(x(8)), b.marginal(x(8)))


BAD_CASES = {
    "unknown key": (lambda s, h: ([BetweenFactor(x(8), key("y", 3), SE2(),
                                                 Diagonal.sigmas([1.0] * 3))], {}, ()),
                    KeyNotFoundError, "y3"),
    # found while the update's own factors are added: what was added before is rolled back
    "unknown key after new factors": (
        lambda s, h: (s[0][0] + [BetweenFactor(x(8), key("y", 3), SE2(),
                                               Diagonal.sigmas([1.0] * 3))], s[0][1], ()),
        KeyNotFoundError, "y3"),
    "wrong manifold after new factors": (
        lambda s, h: (s[0][0] + [PriorFactor(x(8), np.zeros(2), Diagonal.sigmas([1.0] * 2))],
                      s[0][1], ()),
        ManifoldError, "x8"),
    "known key in new_values": (lambda s, h: (s[0][0], {**s[0][1], x(4): SE2()}, ()),
                                DuplicateKeyError, "x4"),
    "removing a missing factor": (lambda s, h: (s[0][0], s[0][1], [h[-1] + 100]),
                                  FgoptError, str(10 ** 9)),
    "new variable without factor": (lambda s, h: (s[0][0], {**s[0][1], key("z", 1): SE2()},
                                                  ()), NotPositiveDefiniteError, "z1"),
    "unconstrained new variable": (
        lambda s, h: (s[0][0] + [range_factor(pose=x(8), landmark=key("l", 4), measured=2.0)],
                      {**s[0][1], key("l", 4): np.array([1.0, 1.0])}, ()),
        NotPositiveDefiniteError, "l4"),
    # non-finite local systems: of the only new factor, of the last batch after another one
    # (both written by the numba update call, which refuses them before changing anything),
    # and of a batch written before the last
    "non-finite linearization": (
        lambda s, h: ([range_factor(pose=x(8), landmark=key("l", 4), measured=2.0)],
                      {key("l", 4): np.array([np.nan, 1.0])}, ()),
        NonFiniteError, "l4"),
    "non-finite linearization after another batch": (
        lambda s, h: (s[0][0] + [range_factor(pose=x(8), landmark=key("l", 4), measured=2.0)],
                      {**s[0][1], key("l", 4): np.array([1.0, np.inf])}, ()),
        NonFiniteError, "l4"),
    "non-finite linearization before another batch": (
        lambda s, h: (s[0][0] + [range_factor(pose=x(8), landmark=key("l", 4), measured=2.0),
                                 PriorFactor(key("l", 5), np.zeros(2),
                                             Diagonal.sigmas([1.0] * 2)),
                                 range_factor(pose=x(8), landmark=key("l", 5), measured=2.0)],
                      {**s[0][1], key("l", 4): np.array([1.0, np.inf]),
                       key("l", 5): np.array([1.0, 1.0])}, ()),
        NonFiniteError, "l4"),
}


@pytest.mark.parametrize("case", list(BAD_CASES))
def test_bad_update_raises_and_leaves_state_unchanged(case):
    """The error names the key / factor, the state equals an untouched twin's, and both then
    continue identically."""
    make, exc, name = BAD_CASES[case]
    a, b, rest, handles = _twins()
    factors, values, remove = make(rest, handles)
    if case == "removing a missing factor":
        name = str(handles[-1] + 100)
    with pytest.raises(exc, match=name):
        a.update(factors, values, remove=remove)
    _same_state(a, b)
    for factors, values in rest:
        ra, rb = a.update(factors, values), b.update(factors, values)
        assert ra.new_factor_indices == rb.new_factor_indices
    _same_state(a, b)


def test_bad_types_are_refused():
    """A factor on a variable of the wrong manifold, duplicate removal, a non-factor."""
    isam = IncrementalSmoother()
    r = isam.update([PriorFactor(x(0), SE2(), Diagonal.sigmas([1.0] * 3))], {x(0): SE2()})
    with pytest.raises(FgoptError, match="x0"):
        isam.update([PriorFactor(x(0), np.zeros(2))])
    with pytest.raises(FgoptError, match="twice"):
        isam.update(remove=r.new_factor_indices * 2)
    with pytest.raises(FgoptError, match="Factor"):
        isam.update(["not a factor"])
    assert len(isam.factors()) == 1


def test_relinearization_threshold_per_key_kind():
    """Thresholds by key character / manifold kind: landmarks ('l') never relinearized with an
    infinite threshold, poses with 0 every update; a vector threshold per tangent component."""
    L = lambda j: key("l", j)  # noqa: E731
    od, rb = Diagonal.sigmas([0.05, 0.05, 0.02]), Diagonal.sigmas([0.05, 0.02])
    isam = IncrementalSmoother(IncrementalParams(
        relinearize_skip=1, relinearize_threshold={"x": 0.0, "R2": np.inf}))
    poses = [SE2.from_xytheta(i, 0.0, 0.1 * i) for i in range(5)]
    lm = np.array([2.0, 2.0])
    seen = []
    for i, p in enumerate(poses):
        d = p.inverse().act(lm)
        fs = [range_bearing_factor(pose=x(i), landmark=L(0), loss=rb,
                                   measured=np.array([np.hypot(*d), np.arctan2(d[1], d[0])]))]
        fs.append(BetweenFactor(x(i - 1), x(i), poses[i - 1].inverse() * p, od) if i else
                  PriorFactor(x(0), p, od))
        vals = {x(i): p * SE2.from_xytheta(0.05, 0.0, 0.02)}
        if i == 0:
            vals[L(0)] = lm + 0.3
        seen += list(isam.update(fs, vals).relinearized_keys)
    assert L(0) not in seen and x(0) in seen
    vec = IncrementalSmoother(IncrementalParams(relinearize_threshold={"x": [0.1, 0.2, 0.2]}))
    vec.update([PriorFactor(x(0), SE2(), od)], {x(0): SE2()})
    assert np.array_equal(vec._tree.thr[vec._vars.slot(x(0)), :3], [0.1, 0.2, 0.2])
    bad = IncrementalSmoother(IncrementalParams(relinearize_threshold={"x": [0.1, 0.2]}))
    with pytest.raises(FgoptError, match="x0"):
        bad.update([PriorFactor(x(0), SE2(), od)], {x(0): SE2()})


def test_removing_every_factor_of_a_variable_drops_it():
    """The documented rule for a variable left with no factor: it leaves the smoother (as
    GTSAM's ISAM2 drops unused keys), ``removed_keys`` names it, and the other estimates stay
    as they were."""
    from fgopt import BetweenFactor, PriorFactor, SE2, Variables, key
    from fgopt.incremental import IncrementalSmoother
    from fgopt.noise import Diagonal

    noise = Diagonal.pose2(x=0.1, y=0.1, theta=0.05)
    s = IncrementalSmoother()
    r = s.update([PriorFactor(key("x", 0), SE2.identity(), noise),
                  BetweenFactor(key("x", 0), key("x", 1), SE2.from_xytheta(1, 0, 0), noise),
                  BetweenFactor(key("x", 1), key("x", 2), SE2.from_xytheta(1, 0, 0), noise)],
                 Variables().add(key("x", 0), SE2.identity())
                 .add(key("x", 1), SE2.from_xytheta(1, 0, 0))
                 .add(key("x", 2), SE2.from_xytheta(2, 0, 0)))
    before = s.estimate(key("x", 1))
    dropped = s.update(remove=[r.new_factor_indices[2]])
    assert dropped.removed_keys == [key("x", 2)]
    assert key("x", 2) not in s and len(s) == 2
    assert s.estimate(key("x", 1)).equals(before)
