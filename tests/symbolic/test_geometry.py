"""The shipped declared manifolds (Unit3, OrientedPlane3, SE23) against independent numeric
implementations written here, and against GTSAM where it has the same type."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm, logm

import fgopt
from fgopt.key import key
from fgopt.manifolds import SE3, SO3
from fgopt.symbolic import V2, OrientedPlane3, Pose3, Rot3, SE23, Unit3, check_manifold

from tests.symbolic._helpers import assert_jacobian_matches_fd


# ------------------------------------------------------------------ independent Unit3 (numpy)
def np_basis(p: np.ndarray) -> np.ndarray:
    """GTSAM's tangent basis of S^2 at p: helper axis of the smallest |p_i|, two crosses."""
    a = np.abs(p)
    axis = np.eye(3)[0 if a[0] <= a[1] and a[0] <= a[2] else 1 if a[1] <= a[2] else 2]
    b1 = np.cross(p, axis)
    b1 /= np.linalg.norm(b1)
    return np.column_stack([b1, np.cross(p, b1)])


def np_retract(p: np.ndarray, v: np.ndarray) -> np.ndarray:
    xi = np_basis(p) @ v
    t = np.linalg.norm(xi)
    q = np.cos(t) * p + (np.sin(t) / t if t > 0 else 1.0) * xi
    return q / np.linalg.norm(q)


def np_local(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    c = float(np.clip(p @ q, -1.0, 1.0))
    s = math.sqrt(max(1.0 - c * c, 0.0))
    k = math.acos(c) / s if s > 1e-15 else 1.0
    return k * (np_basis(p).T @ (q - c * p))


def _directions(rng: np.random.Generator) -> list[np.ndarray]:
    out = [v / np.linalg.norm(v) for v in rng.normal(size=(20, 3))]
    out += [np.array([1.0, 1.0, 1.0]) / math.sqrt(3), np.array([0.0, 0.0, 1.0]),
            np.array([1.0, 0.0, 0.0]), np.array([0.6, -0.6, 0.52915026])]  # ties of |p_i|
    return out


def test_unit3_matches_numpy_and_gtsam():
    """Unit3 basis, retract and local equal an independent numpy version and gtsam.Unit3."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(0)
    for p in _directions(rng):
        u = Unit3.Value(p)
        g = gtsam.Unit3(p)
        np.testing.assert_allclose(u.basis(), np_basis(u.to_storage()), atol=1e-14)
        np.testing.assert_allclose(u.basis(), g.basis(), atol=1e-14)
        for v in (rng.normal(size=2) * s for s in (1e-9, 0.1, 1.0, 3.0)):
            r = u.retract(v)
            np.testing.assert_allclose(r.to_storage(), np_retract(u.to_storage(), v), atol=1e-13)
            np.testing.assert_allclose(r.to_storage(), g.retract(v).point3(), atol=1e-13)
            q = Unit3.Value(rng.normal(size=3))
            np.testing.assert_allclose(u.local(q), np_local(u.to_storage(), q.to_storage()),
                                       atol=1e-11)
            np.testing.assert_allclose(u.local(q), g.localCoordinates(gtsam.Unit3(
                q.to_storage())), atol=1e-11)
        np.testing.assert_allclose(u.local(u), [0.0, 0.0], atol=1e-15)
        np.testing.assert_allclose(u.point3(), g.point3(), atol=1e-15)


def test_unit3_factor_jacobians():
    """Generated Unit3 factor Jacobians match central differences through Unit3's retract:
    far apart, nearly equal (local near 0) and at the helper-axis ties (except a residual in
    the basis of a direction at a tie, which jumps there as GTSAM's does)."""
    @fgopt.factor
    def direction_between(a: Unit3, b: Unit3, b_R_a: Rot3) -> V2:
        """Angle between b and the rotated a, in b's tangent basis."""
        return b.local(Unit3(b_R_a * a.point3()))

    rng = np.random.default_rng(1)
    prior = fgopt.PriorFactor(key("u", 0), Unit3.Value([0, 0, 1.0]))
    f = direction_between(key("u", 1), key("u", 2), SO3())
    def at_tie(u) -> bool:  # B(u) jumps there: a residual in u's basis has no derivative
        a = np.sort(np.abs(u.to_storage()))
        return a[1] - a[0] < 1e-3

    for p in _directions(rng):
        a = Unit3.Value(p)
        for b in (Unit3.Value(rng.normal(size=3)), a.retract([1e-7, -2e-7]), a):
            R = SO3.random(rng)
            args = (a.to_storage()[None], b.to_storage()[None])
            if not at_tie(b):
                assert_jacobian_matches_fd(f.kernel, args, R.to_storage()[None], rtol=1e-5)
            assert_jacobian_matches_fd(prior.kernel, args[:1], b.to_storage()[None], rtol=1e-5)


@pytest.mark.parametrize("name", ["Unit3", "OrientedPlane3", "SE23"])
def test_check_manifold_passes(name):
    """check_manifold passes on each shipped manifold (round trips, derived Jacobians,
    normalization, batched = per-value) and prints a table naming every check."""
    import fgopt.symbolic as S

    report = check_manifold(getattr(S, name))
    assert report.ok, str(report)
    text = str(report)
    assert "all checks passed" in text and "storage_D_tangent" in text and "normalize" in text
    assert check_manifold(getattr(fgopt, name)()).ok  # a numeric value works too


# ------------------------------------------------------------------ OrientedPlane3 (GTSAM)
def test_oriented_plane3_matches_gtsam():
    """OrientedPlane3 retract, local, coefficients and transform equal gtsam.OrientedPlane3."""
    gtsam = pytest.importorskip("gtsam")
    rng = np.random.default_rng(2)
    for _ in range(10):
        c = np.concatenate([rng.normal(size=3), [rng.normal() * 3]])
        c[:3] /= np.linalg.norm(c[:3])
        p, g = OrientedPlane3.Value(c), gtsam.OrientedPlane3(c)
        np.testing.assert_allclose(p.plane_coefficients(), g.planeCoefficients(), atol=1e-15)
        v = rng.normal(size=3)
        np.testing.assert_allclose(p.retract(v).plane_coefficients(),
                                   g.retract(v).planeCoefficients(), atol=1e-13)
        q = OrientedPlane3.Value(np.concatenate([rng.normal(size=3), [rng.normal()]]))
        np.testing.assert_allclose(p.local(q), g.localCoordinates(
            gtsam.OrientedPlane3(q.plane_coefficients())), atol=1e-11)
        assert isinstance(p.normal(), Unit3.Value) and p.distance() == pytest.approx(c[3])
    assert repr(OrientedPlane3.Value()) == "OrientedPlane3(normal=Unit3([0., 0., 1.]), distance=0)"

    # transform (a symbolic method) in a factor: the plane seen from a pose, vs GTSAM
    @fgopt.factor
    def plane_in_frame(plane: OrientedPlane3, pose: Pose3, measured: OrientedPlane3):
        """GTSAM's OrientedPlane3Factor residual: measured.local(plane.transform(pose))."""
        return measured.local(plane.transform(pose))

    pose = SE3.exp(rng.normal(size=6))
    c = np.array([0.3, -0.5, 0.8, 1.5])
    c[:3] /= np.linalg.norm(c[:3])
    gp = gtsam.OrientedPlane3(c).transform(gtsam.Pose3(pose.matrix()))
    f = plane_in_frame(key("p", 0), key("x", 0), OrientedPlane3.Value(gp.planeCoefficients()))
    vals = fgopt.Variables({key("p", 0): OrientedPlane3.Value(c), key("x", 0): pose})
    np.testing.assert_allclose(f.error(vals), np.zeros(3), atol=1e-12)
    args = (vals.at(key("p", 0)).to_storage()[None], pose.to_storage()[None])
    assert_jacobian_matches_fd(f.kernel, args, f.constants[None], rtol=1e-5)


# ------------------------------------------------------------------ SE23 (5x5 matrices)
def hat9(xi: np.ndarray) -> np.ndarray:
    w, a, b = xi[:3], xi[3:6], xi[6:]
    m = np.zeros((5, 5))
    m[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    m[:3, 3], m[:3, 4] = a, b
    return m


def vee9(m: np.ndarray) -> np.ndarray:
    return np.concatenate([[m[2, 1], m[0, 2], m[1, 0]], m[:3, 3], m[:3, 4]])


def mat5(x) -> np.ndarray:
    m = np.eye(5)
    m[:3, :3] = x.rotation().matrix()
    m[:3, 3], m[:3, 4] = x.velocity(), x.position()
    return m


def _tangent(rng, angle: float) -> np.ndarray:
    xi = rng.normal(size=9)
    w = rng.normal(size=3)
    xi[:3] = w / np.linalg.norm(w) * angle
    return xi


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.5, 2.0, math.pi - 1e-4])
def test_se23_matches_matrix_exponential(angle):
    """SE23 retract = X expm(hat(xi)), local = vee(logm(X^-1 Y)) on 5x5 matrices, at rotation
    angles from 0 to near pi."""
    rng = np.random.default_rng(3)
    for _ in range(3):
        x = SE23.Value().retract(rng.normal(size=9))
        xi = _tangent(rng, angle)
        y = x.retract(xi)
        np.testing.assert_allclose(mat5(y), mat5(x) @ expm(hat9(xi)), atol=1e-11)
        back = vee9(np.real(logm(np.linalg.solve(mat5(x), mat5(y)))))
        np.testing.assert_allclose(x.local(y), back, atol=1e-8)
        np.testing.assert_allclose(x.local(y), xi, atol=1e-8)


@pytest.mark.parametrize("angle", [0.0, 1e-8, 0.3, math.pi - 1e-3])
def test_se23_factor_jacobians(angle):
    """Generated SE23 prior and between (a declared group) Jacobians match central differences
    at rotation angles near 0 and near pi."""
    rng = np.random.default_rng(4)
    x = SE23.Value().retract(rng.normal(size=9))
    m = SE23.Value().retract(rng.normal(size=9))
    y = x.retract(_tangent(rng, angle))
    prior = fgopt.PriorFactor(key("x", 0), m.retract(_tangent(rng, angle)))
    between = fgopt.BetweenFactor(key("x", 0), key("x", 1), m)
    assert_jacobian_matches_fd(prior.kernel, (y.to_storage()[None],), prior.constants[None],
                               rtol=1e-5)
    assert_jacobian_matches_fd(between.kernel, (x.to_storage()[None], y.to_storage()[None]),
                               between.constants[None], rtol=1e-5)
    # the between residual is GTSAM's Log(m^-1 x^-1 y), here with 5x5 matrices
    vals = fgopt.Variables({key("x", 0): x, key("x", 1): y})
    want = vee9(np.real(logm(np.linalg.inv(mat5(m)) @ np.linalg.solve(mat5(x), mat5(y)))))
    if angle < 3.0:
        np.testing.assert_allclose(between.error(vals), want, atol=1e-7)


def test_se23_accessors_and_repr():
    """SE23 accessors give SO3 and arrays; repr shows them; numeric compose through local."""
    x = SE23.Value(np.array([0, 0, 0, 1, 1, 2, 3, 4, 5, 6.0]))
    assert isinstance(x.rotation(), SO3)
    np.testing.assert_allclose(x.velocity(), [1, 2, 3])
    np.testing.assert_allclose(x.position(), [4, 5, 6])
    assert repr(x).startswith("SE23(rotation=SO3(qw=1.000") and "position=[4., 5., 6.]" in repr(x)
    assert SE23.is_group() and not Unit3.is_group()
    with pytest.raises(fgopt.FgoptError, match="declares no compose"):
        fgopt.BetweenFactor(key("u", 0), key("u", 1), Unit3.Value())
