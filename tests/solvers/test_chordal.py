"""Chordal initialization of pose graphs: independent of the initial guess, near the optimum."""

import numpy as np
import pytest

import fgopt
from fgopt import SE2, SE3, SO3, PriorFactor, key
from fgopt.datasets import grid_3d, manhattan_2d
from fgopt.errors import FgoptError
from fgopt.solvers.chordal import (_rotations_from_storage, _storage_from_rotations,
                                   chordal_initialization)


def _identity_guess(values):
    out = fgopt.Variables()
    for k in values.keys():
        x = values.at(k)
        out.add(k, SE2() if isinstance(x, SE2) else SE3())
    return out


@pytest.mark.parametrize("make", [lambda: manhattan_2d(300, seed=2), lambda: grid_3d(200, seed=2)],
                         ids=["se2", "se3"])
def test_lm_from_chordal_reaches_the_optimum_from_identity(make):
    """Every pose starts at the identity; chordal + LM reaches the cost LM reaches from the
    generator's (odometry) guess, and the chordal estimate itself is already close to it."""
    d = make()
    ref = fgopt.optimize(d.graph, d.initial)
    bad = _identity_guess(d.initial)
    init = chordal_initialization(d.graph, bad)
    assert d.graph.error(init) < 0.01 * d.graph.error(bad)
    r = fgopt.optimize(d.graph, init)
    assert r.final_cost <= ref.final_cost * (1 + 1e-9)
    for k in d.initial.keys():
        assert np.linalg.norm(r.values.at(k).translation() - ref.values.at(k).translation()) < 1e-4


def test_without_a_prior_the_first_pose_is_kept():
    """The gauge: with no prior, the first pose stays where the initial values put it."""
    d = manhattan_2d(100, seed=3)
    graph = fgopt.FactorGraph([f for f in d.graph if len(f.keys) == 2])
    first = d.initial.keys()[0]
    init = d.initial.copy()
    init.update(first, SE2.from_xytheta(5.0, -2.0, 0.7))
    out = chordal_initialization(graph, init)
    assert np.allclose(out.at(first).local(init.at(first)), 0.0, atol=1e-8)


def test_not_a_pose_graph_is_refused():
    graph = fgopt.FactorGraph([PriorFactor(key("x", 0), np.array([1.0, 2.0]))])
    values = fgopt.Variables()
    values.add(key("x", 0), np.zeros(2))
    with pytest.raises(FgoptError, match="pose graph"):
        chordal_initialization(graph, values)


def test_quaternion_round_trip_covers_every_branch():
    """Rotation matrix -> [x, y, z, w] storage agrees with SO3 for rotations near the identity
    and by pi about each axis (each branch of the largest-component choice)."""
    rng = np.random.default_rng(0)
    rots = [SO3.random(rng) for _ in range(50)]
    rots += [SO3.from_axis_angle(np.eye(3)[a], np.pi - 1e-3) for a in range(3)]
    rots += [SO3.from_axis_angle(np.array([1.0, 1.0, 0.0]) / np.sqrt(2), 0.01)]
    R = np.array([r.matrix() for r in rots])
    storage = _storage_from_rotations(R, np.zeros((len(rots), 3)))
    assert np.allclose(_rotations_from_storage(storage, 3), R, atol=1e-12)
    for r, s in zip(rots, storage):
        assert np.allclose(SO3(s[:4]).local(r), 0.0, atol=1e-9)


@pytest.mark.parametrize("name,gtsam_cost", [("pose2d/input_M3500_g2o.g2o", 68.957439134),
                                             ("pose3d/sphere2500.g2o", 675.700964882)])
def test_real_graphs_from_chordal(data_file, name, gtsam_cost):
    """On real graphs LM from the chordal estimate reaches GTSAM's final cost or lower."""
    graph, values = fgopt.io.read(data_file(name), add_prior=True)
    r = fgopt.optimize(graph, chordal_initialization(graph, values))
    assert r.final_cost <= gtsam_cost * (1 + 1e-8)


def test_2d_projection_is_the_nearest_rotation():
    """The closed-form 2D projection equals the SVD projection (U diag(1, det) V^T) on random
    matrices, reflections included, and maps the tie M = [[a, b], [b, -a]] to a rotation."""
    from fgopt.solvers.chordal import _project_to_rotations

    rng = np.random.default_rng(3)
    M = rng.normal(size=(2000, 2, 2))
    U, _, Vt = np.linalg.svd(M)
    U[:, :, -1] *= np.linalg.det(U @ Vt)[:, None]
    np.testing.assert_allclose(_project_to_rotations(M), U @ Vt, atol=1e-12)
    tie = _project_to_rotations(np.array([[[1.0, 2.0], [2.0, -1.0]], np.zeros((2, 2))]))
    np.testing.assert_allclose(tie @ tie.transpose(0, 2, 1), np.broadcast_to(np.eye(2), tie.shape),
                               atol=1e-15)
