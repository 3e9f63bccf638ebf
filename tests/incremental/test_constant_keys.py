"""``IncrementalSmoother.update(..., constant=[keys])``: localizing against a fixed map. The
constant keys never enter the smoother's system, keep their values bit for bit through every
later update, and the estimate equals ``fgopt.optimize(constant=...)`` on the same graph; bad
constant keys raise FgoptError and leave the smoother unchanged."""

import numpy as np
import pytest

import fgopt
from fgopt import FactorGraph, IncrementalParams, IncrementalSmoother, PriorFactor, key
from fgopt.errors import FgoptError, KeyNotFoundError
from fgopt.manifolds import SE2
from fgopt.noise import Diagonal

from ._streams import max_tangent_difference
from .test_update_api import EXACT


def _m3500(data_file, n):
    """The factors of M3500 among its first ``n`` poses, by their later pose, and the file's
    initial values."""
    graph, init = fgopt.io.read(data_file("pose2d/input_M3500_g2o.g2o"))
    by_pose: dict = {}
    for b in graph.batches:
        for r in range(len(b)):
            i, j = (int(k) & ((1 << 56) - 1) for k in b.keys[r])
            if max(i, j) < n:
                by_pose.setdefault(max(i, j), []).append(b.factor(r))
    return by_pose, init


def test_localizing_against_a_constant_map_matches_batch_constant(data_file):
    """M3500 (real): poses 0-199 solved in batch form the map; poses 200-299 arrive one at a
    time (odometry and loop closures, many into the map) with the map held constant. The map
    keys are not variables of the smoother (len counts the free poses only), their values come
    back bit for bit after every update, and the final estimate equals fgopt.optimize with the
    same keys constant on the whole graph (converged, to 1e-6 in the tangent space)."""
    by_pose, init = _m3500(data_file, 300)
    prior = PriorFactor(key("x", 0), init.at(key("x", 0)), Diagonal.sigmas([1e-3] * 3))
    map_graph = FactorGraph([prior] + [f for p in range(200) for f in by_pose.get(p, [])])
    map_values = fgopt.optimize(map_graph, fgopt.Variables(
        {key("x", p): init.at(key("x", p)) for p in range(200)})).values
    map_keys = [key("x", p) for p in range(200)]
    stored = {k: map_values.at(k) for k in map_keys}
    isam = IncrementalSmoother(IncrementalParams(**EXACT))
    graph = FactorGraph()
    values = fgopt.Variables()
    for p in range(200, 300):
        fs = by_pose[p]
        odo = next(f for f in fs if f.keys == (key("x", p - 1), key("x", p)))
        prev = stored[key("x", p - 1)] if p == 200 else isam.estimate(key("x", p - 1))
        new = {key("x", p): prev * SE2.from_storage(odo.constants)}
        values.add(key("x", p), new[key("x", p)])
        if p == 200:
            new.update(stored)
            isam.update(fs, new, constant=map_keys)
        else:
            isam.update(fs, new)
        graph.extend(fs)
        assert len(isam) == p - 199
        assert isam.estimate(key("x", 17)) is stored[key("x", 17)]
    est = isam.estimate()
    for k in map_keys:
        assert est.at(k).to_storage().tobytes() == stored[k].to_storage().tobytes()
    used = {k for f in graph for k in f.keys}
    for k, x in stored.items():
        if k in used:
            values.add(k, x)
    batch = fgopt.optimize(graph, values, constant=[k for k in map_keys if k in used], relative_tolerance=1e-14,
                           absolute_tolerance=0.0, max_iterations=200)
    assert max_tangent_difference(fgopt.Variables({k: est.at(k) for k in batch.values}),
                                  batch.values) < 1e-6
    assert graph.error(est) == pytest.approx(batch.final_cost, rel=1e-9)


def test_bad_constant_keys_raise_and_change_nothing():
    """A constant key missing from new_values (not a variable), or already a variable of the
    smoother, raises FgoptError naming it; the smoother is unchanged (same estimate, size and
    update count), and a later constant key cannot come back in new_values. A factor whose
    keys are all constant, or a Python factor over a constant key, is refused by name."""
    from fgopt import BetweenFactor
    from fgopt.factors import NumericalFactor

    sig = Diagonal.sigmas([0.1] * 3)
    isam = IncrementalSmoother()
    a, b, c = key("x", 0), key("x", 1), key("m", 0)
    isam.update([PriorFactor(a, SE2(), sig)], {a: SE2()})
    before = (len(isam), isam.estimate(a).to_storage().copy(), repr(isam))
    with pytest.raises(KeyNotFoundError, match="m0"):
        isam.update([BetweenFactor(a, b, SE2(), sig)], {b: SE2()}, constant=[c])
    with pytest.raises(FgoptError, match="x0 is already in the smoother"):
        isam.update([BetweenFactor(a, b, SE2(), sig)], {b: SE2()}, constant=[a])
    with pytest.raises(FgoptError, match="every key"):
        isam.update([PriorFactor(c, SE2(), sig)], {c: SE2()}, constant=[c])
    class Python(NumericalFactor):
        def error(self, values):
            return np.asarray(values.at(self.keys[0]).local(values.at(self.keys[1])))

    py = Python([b, c], 3, sig)
    with pytest.raises(FgoptError, match="only kernel factors"):
        isam.update([py], {b: SE2(), c: SE2()}, constant=[c])
    assert (len(isam), isam.estimate(a).to_storage().tolist(), repr(isam)) == \
        (before[0], before[1].tolist(), before[2])
    m = SE2.from_xytheta(1.0, 2.0, 0.3)
    isam.update([BetweenFactor(c, b, SE2(), sig), BetweenFactor(a, b, SE2(), sig)],
                {b: SE2(), c: m}, constant=[c])
    assert isam.estimate(c) is m and c not in isam
    with pytest.raises(FgoptError, match="m0"):
        isam.update([BetweenFactor(c, b, SE2(), sig)], {c: SE2()})
