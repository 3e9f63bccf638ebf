"""Generated library factors: same residuals as the hand-written kernels, FD-exact Jacobians.

Every generated factor's Jacobian is checked against central differences (the manifolds' own
retract) to 1e-6 relative at random points and near rotation singularities (angle 0, tiny
angles, close to pi).
"""

from __future__ import annotations

import numpy as np
import pytest

from fgopt.factors.library import range_bearing as rb
from fgopt.factors.library import reprojection as rp
from fgopt.factors.library.generated import (
    generated_between_kernel,
    generated_prior_kernel,
)
from fgopt.key import key
from fgopt.manifolds import SE2, SE3, SO2, SO3, vector_kind

from ._helpers import assert_jacobian_matches_fd

GROUPS = [SO2, SE2, SO3, SE3]
ANGLES = [None, None, 0.0, 1e-9, 1e-6, np.pi - 1e-4, np.pi - 1e-6]  # None: random


def _with_rotation_angle(G, angle, rng):
    """A random element of G whose rotation angle is ``angle`` (random if None)."""
    if angle is None:
        return G.random(rng)
    v = rng.normal(size=G.dim())
    if G in (SO2, SE2):
        v[0] = angle * rng.choice([-1.0, 1.0])
    else:
        axis = rng.normal(size=3)
        v[:3] = angle * axis / np.linalg.norm(axis)
    return G.exp(v)


def _rows(*values):
    return tuple(np.array([v.to_storage()]) for v in values)


@pytest.mark.parametrize("G", GROUPS, ids=lambda g: g.__name__)
def test_between_prior_match_hand_written_and_fd(G):
    lie = pytest.importorskip("fgopt.factors.library.lie_kernels")
    kind = G.batch_kind()
    kb, kp = generated_between_kernel(kind), generated_prior_kernel(kind)
    hb, hp = lie.between_kernel(kind), lie.prior_kernel(kind)
    rng = np.random.default_rng(11)
    for angle in ANGLES:
        a, m = G.random(rng), G.random(rng)
        b = a.compose(m).compose(_with_rotation_angle(G, angle, rng))  # residual angle = angle
        (sa, sb), cm = _rows(a, b), np.array([m.to_storage()])
        r_gen, j_gen = kb.linearize((sa, sb), cm)
        r_hand, j_hand = hb.linearize((sa, sb), cm)
        np.testing.assert_allclose(r_gen, r_hand, atol=1e-9)
        np.testing.assert_allclose(j_gen, j_hand, atol=1e-7)
        assert_jacobian_matches_fd(kb, (sa, sb), cm)
        x = m.compose(_with_rotation_angle(G, angle, rng))
        np.testing.assert_allclose(kp.residual(_rows(x), cm), hp.residual(_rows(x), cm), atol=1e-9)
        assert_jacobian_matches_fd(kp, _rows(x), cm)


def test_vector_between_prior():
    kind = vector_kind(3)
    kb, kp = generated_between_kernel(kind), generated_prior_kernel(kind)
    a, b, m = np.ones((1, 3)), np.arange(3.0).reshape(1, 3), np.full((1, 3), 0.5)
    res, jac = kb.linearize((a, b), m)
    np.testing.assert_allclose(res, (b - a) - m)
    np.testing.assert_allclose(jac[0], np.hstack([-np.eye(3), np.eye(3)]))
    np.testing.assert_allclose(kp.residual((b,), m), b - m)


def _bal_camera(rng, r_norm=None):
    r = rng.normal(size=3) * 0.3
    if r_norm is not None:
        r = r / np.linalg.norm(r) * r_norm if r_norm > 0 else np.zeros(3)
    t = rng.normal(size=3) * 0.2 + np.array([0.0, 0.0, -5.0])
    return np.concatenate([r, t, [500.0 + rng.normal() * 10, -1e-7 * 3, 2e-13]])


@pytest.mark.parametrize("r_norm", [None, 0.0, 1e-9, 1e-4])
def test_bal_reprojection(r_norm):
    rng = np.random.default_rng(3)
    f = rp.bal_reprojection(key("c", 0), key("p", 1), np.array([10.0, -20.0]))
    k = f.kernel
    for _ in range(3):
        cam = _bal_camera(rng, r_norm)
        pt = rng.normal(size=3)
        args = (cam.reshape(1, 9), pt.reshape(1, 3))
        consts = f.constants.reshape(1, -1)
        # reference: the BAL model written with numpy (Rodrigues via scipy)
        from scipy.spatial.transform import Rotation

        P = Rotation.from_rotvec(cam[:3]).apply(pt) + cam[3:6]
        p = -P[:2] / P[2]
        r2 = p @ p
        u = cam[6] * (1 + cam[7] * r2 + cam[8] * r2 * r2) * p - consts[0]
        np.testing.assert_allclose(k.residual(args, consts)[0], u, rtol=1e-12, atol=1e-9)
        assert_jacobian_matches_fd(k, args, consts)
        try:
            from fgopt.factors.library.bal_kernel import bal_kernel
        except ImportError:
            continue
        r_h, j_h = bal_kernel().linearize(args, consts)
        r_g, j_g = k.linearize(args, consts)
        np.testing.assert_allclose(r_g, r_h, atol=1e-9)
        np.testing.assert_allclose(j_g, j_h, rtol=1e-7, atol=1e-6)


def test_pinhole_projection():
    rng = np.random.default_rng(4)
    f = rp.pinhole_projection(key("x", 0), key("l", 0), np.array([500.0, 510.0, 320.0, 240.0]),
                              np.array([300.0, 200.0]))
    for angle in (None, 0.0, 1e-8):
        pose = _with_rotation_angle(SE3, angle, rng)
        pt = pose * np.array([0.3, -0.2, 4.0])  # in front of the camera
        args = (np.array([pose.to_storage()]), pt.reshape(1, 3))
        consts = f.constants.reshape(1, -1)
        pc = pose.inverse() * pt
        want = np.array([500 * pc[0] / pc[2] + 320, 510 * pc[1] / pc[2] + 240]) - [300, 200]
        np.testing.assert_allclose(f.kernel.residual(args, consts)[0], want, atol=1e-9)
        assert_jacobian_matches_fd(f.kernel, args, consts)


@pytest.mark.parametrize("name", ["range_factor", "bearing_factor", "range_bearing_factor",
                                  "range_factor_3d", "bearing_factor_3d"])
def test_range_bearing(name):
    rng = np.random.default_rng(5)
    ftype = getattr(rb, name)
    three_d = name.endswith("3d")
    G, dim = (SE3, 3) if three_d else (SE2, 2)
    for angle in (None, 0.0, np.pi - 1e-5):
        pose = _with_rotation_angle(G, angle, rng)
        land = pose * (rng.normal(size=dim) + 2.0)
        d = pose.inverse() * land
        if name == "bearing_factor_3d":
            measured = d / np.linalg.norm(d)
        elif name == "range_bearing_factor":
            measured = np.array([np.linalg.norm(d), np.arctan2(d[1], d[0])])
        elif name == "bearing_factor":
            measured = float(np.arctan2(d[1], d[0]))
        else:
            measured = float(np.linalg.norm(d))
        f = ftype(key("x", 0), key("l", 0), measured)
        args = (np.array([pose.to_storage()]), land.reshape(1, dim))
        consts = f.constants.reshape(1, -1)
        np.testing.assert_allclose(f.kernel.residual(args, consts)[0], 0.0, atol=1e-9)
        assert_jacobian_matches_fd(f.kernel, args, consts)
    if name == "bearing_factor":  # the wrapped angle: no jump across pi
        f = ftype(key("x", 0), key("l", 0), np.pi - 0.01)
        r = f.kernel.residual((np.array([[1.0, 0, 0, 0]]), np.array([[-1.0, -0.01]])),
                              f.constants.reshape(1, -1))
        assert abs(r[0, 0] - 0.02) < 1e-4  # not -2 pi + 0.02
