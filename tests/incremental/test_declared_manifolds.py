"""The incremental smoother on a manifold declared with ``@fgopt.manifold`` (Unit3), unchanged:
its estimate and marginals equal the batch solution's."""

import numpy as np

import fgopt
from fgopt import SO3, key
from fgopt.noise import Isotropic
from fgopt.symbolic import V2, Rot3, Unit3


@fgopt.factor
def unit3_between_incremental(a: Unit3, b: Unit3, b_R_a: Rot3) -> V2:
    return b.local(Unit3(b_R_a * a.point3()))


def _rotation_between(a: np.ndarray, b: np.ndarray):
    axis = np.cross(a, b)
    return SO3.from_axis_angle(axis / np.linalg.norm(axis),
                               np.arctan2(np.linalg.norm(axis), a @ b))


def test_unit3_stream_matches_batch():
    """Directions arriving one at a time (links to the previous and the third previous one, a
    prior on the first): with full relinearization the smoother's estimate equals the batch LM
    solution to 1e-6, and its marginal of a direction is the block of H^-1 at its linearization
    point (as for the built-in groups, tests/incremental/test_update_api.py)."""
    U = Unit3.Value
    rng = np.random.default_rng(2)
    truth = [U(rng.normal(size=3)) for _ in range(9)]
    noise = Isotropic.sigma(2, 0.01)
    isam = fgopt.IncrementalSmoother(fgopt.IncrementalParams(relinearize_threshold=0.0))
    batch_graph, batch_values = fgopt.FactorGraph(), fgopt.Variables()
    for i, t in enumerate(truth):
        graph, values = fgopt.FactorGraph(), fgopt.Variables()
        if i == 0:
            graph.add(fgopt.PriorFactor(key("u", 0), t, noise))
        for j in (i - 1, i - 3):
            if j >= 0:
                measured = _rotation_between(truth[j].to_storage(), t.to_storage()) \
                    * SO3.exp(0.005 * rng.normal(size=3))
                graph.add(unit3_between_incremental(key("u", j), key("u", i), measured,
                                                    loss=noise))
        start = t.retract(0.05 * rng.normal(size=2))
        values.add(key("u", i), start)
        batch_values.add(key("u", i), start)
        for f in graph.factors:
            batch_graph.add(f)
        isam.update(graph, values)
    for _ in range(3):
        isam.update(fgopt.FactorGraph(), fgopt.Variables())
    batch = fgopt.optimize(batch_graph, batch_values)
    assert batch.success
    estimate = isam.estimate()
    for i in range(len(truth)):
        got = estimate.at(key("u", i))
        assert type(got) is U
        np.testing.assert_allclose(got.to_storage(), batch.values.at(key("u", i)).to_storage(),
                                   atol=1e-6)
    lp = isam.linearization_point()
    ref = fgopt.marginals(None, graph=batch_graph, values=lp, linear_solver="dense")
    for k in (key("u", 0), key("u", 5), key("u", 8)):
        np.testing.assert_allclose(isam.marginal(k), ref[k], rtol=1e-9, atol=1e-14)
