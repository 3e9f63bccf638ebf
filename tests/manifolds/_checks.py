"""Shared helpers of the Lie group tests: group list, special angles, hat, numerical Jacobians.

Load with :func:`load_checks` (by file path, under a unique module name) so it cannot collide with
other test folders' helpers under pytest's default ``prepend`` import mode.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgopt.manifolds import SE2, SE3, SO2, SO3, Sim3, ops_for

GROUPS = (SO2, SE2, SO3, SE3, Sim3)
over_groups = pytest.mark.parametrize("G", GROUPS, ids=lambda G: G.__name__)

#: Rotation angles where Exp / Log / Jacobians have removable singularities or wrap around.
SPECIAL_ANGLES = (0.0, 1e-12, 1e-8, 1e-4, 0.099, 0.101, 0.3, 2.0,
                  math.pi - 1e-4, math.pi - 1e-9, math.pi)


def rotation_part(G, v: np.ndarray) -> np.ndarray:
    return v[:1] if G in (SO2, SE2) else v[:3]


def random_tangent(G, rng: np.random.Generator, angle: float | None = None,
                   scale: float = 1.0) -> np.ndarray:
    """A tangent vector of G; with ``angle``, its rotation part has exactly that norm."""
    v = rng.normal(size=G.dim()) * scale
    if angle is not None:
        if G in (SO2, SE2):
            v[0] = angle * (1.0 if rng.random() < 0.5 else -1.0)
        else:
            axis = rng.normal(size=3)
            v[:3] = axis / np.linalg.norm(axis) * angle
    if G is Sim3:
        v[6] *= 0.5
    return v


def hat(G, v: np.ndarray) -> np.ndarray:
    """The Lie algebra matrix of tangent vector v (so that Exp(v) = expm(hat(v)))."""
    v = np.asarray(v, dtype=float)
    if G is SO2:
        return np.array([[0.0, -v[0]], [v[0], 0.0]])
    if G is SE2:
        return np.array([[0.0, -v[0], v[1]], [v[0], 0.0, v[2]], [0.0, 0.0, 0.0]])
    w = v[:3]
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if G is SO3:
        return W
    m = np.zeros((4, 4))
    m[:3, :3] = W + (v[6] * np.eye(3) if G is Sim3 else 0.0)
    m[:3, 3] = v[3:6]
    return m


def assert_same(a, b, tol: float = 1e-9) -> None:
    assert a.equals(b, tol), f"{a!r} != {b!r}"


def numerical_jacobian(fn, args: list, i: int, h: float = 1e-5) -> np.ndarray:
    """Central differences of vector-valued fn(*args) w.r.t. args[i] along retract(+-h e_k)."""
    x = args[i]
    ops = ops_for(x)
    d = ops.dim(x)
    cols = []
    for k in range(d):
        dx = np.zeros(d)
        dx[k] = h
        plus, minus = list(args), list(args)
        plus[i] = ops.retract(x, dx)
        minus[i] = ops.retract(x, -dx)
        cols.append((np.asarray(fn(*plus)) - np.asarray(fn(*minus))) / (2.0 * h))
    return np.stack(cols, axis=-1)


def assert_jacobian_close(analytic: np.ndarray, numeric: np.ndarray, rtol: float = 1e-6) -> None:
    scale = max(1.0, float(np.max(np.abs(numeric))))
    err = float(np.max(np.abs(analytic - numeric)))
    assert err <= rtol * scale, f"Jacobian mismatch {err:.3g} (scale {scale:.3g}):\n" \
                                f"{analytic}\nvs numerical\n{numeric}"
