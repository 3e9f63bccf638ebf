"""Symbolic poses: :class:`Pose2` and :class:`Pose3` (twins of ``fgopt.manifolds.SE2/SE3``).

Both use the true SE(n) exponential (not the SO(n) x R^n product), rotation first in the
tangent. The ``V`` matrices of Exp / Log have coefficients that are *even* functions of the
rotation angle with removable singularities at 0 (``sin t / t``, ``(1 - cos t) / t^2``,
``(t - sin t) / t^3``, ``(t/2) cot(t/2)``, ...). They are evaluated at
``t_e = sqrt(t^2 + epsilon)``: the value changes by ``O(epsilon)`` (these functions are smooth
in ``t^2``), and the first derivative, whose SymPy form has ``O(u / t_e)`` rounding error
(``u`` = unit roundoff), stays accurate to about ``u / sqrt(epsilon) ~ 5e-9`` even for tiny
nonzero angles, where an ``epsilon^2`` shift would lose all digits.
"""

from __future__ import annotations

from typing import Any

from .lie import LieGroupBase, as_vector
from .rot import Rot2, Rot3


def _s():
    from . import _sym

    return _sym


def _eps(epsilon: Any):
    return _s().epsilon if epsilon is None else _s().as_expr(epsilon)


def _split(data: Any, n_rot: int, n: int, what: str):
    from .rot import _flat

    flat = _flat(data, n, what)
    return flat[:n_rot], flat[n_rot:]


class Pose2(LieGroupBase):
    """A planar pose ``p -> R p + t``. Storage ``[cos, sin, x, y]``; tangent ``[theta, vx, vy]``.

    ``Exp([t, v]) = (R(t), V(t) v)``, ``V = [[sin t/t, -(1 - cos t)/t], [(1 - cos t)/t, sin t/t]]``;
    ``Log`` is its inverse, ``V^-1 = [[a, t/2], [-t/2, a]]`` with ``a = (t/2) cot(t/2)``.

    Example:

    >>> from fgopt.symbolic import Pose2, V2
    >>> @fgopt.factor
    ... def landmark_in_body(pose: Pose2, landmark: V2, measured: V2) -> V2:
    ...     return pose.inverse() * landmark - measured
    ...
    >>> values = fgopt.Variables().add(key('x', 0), fgopt.SE2.from_xytheta(1.0, 0.0, 0.0)).add(key('l', 0), np.array([3.0, 1.0]))
    >>> f = landmark_in_body(pose=key('x', 0), landmark=key('l', 0), measured=np.array([2.0, 1.0]))
    >>> np.round(f.error(values), 6)
    array([0., 0.])
    """

    __slots__ = ("R", "t")
    _DIM = 3
    _STORAGE_DIM = 4
    _IDENTITY = (1, 0, 0, 0)

    def __init__(self, R: Rot2 | None = None, t: Any = None):
        from .matrix import V2

        self.R = Rot2() if R is None else R
        self.t = V2() if t is None else as_vector(t, 2, "Pose2 translation")

    @classmethod
    def from_storage(cls, data: Any) -> Pose2:
        r, t = _split(data, 2, 4, "Pose2.from_storage")
        return cls(Rot2(*r), t)

    def to_storage(self) -> list:
        return self.R.to_storage() + list(self.t)

    @classmethod
    def from_xytheta(cls, x: Any, y: Any, theta: Any) -> Pose2:
        return cls(Rot2.from_angle(theta), [x, y])

    def rotation(self) -> Rot2:
        return self.R

    def translation(self):
        return self.t

    position = translation

    def compose(self, other: Pose2) -> Pose2:
        return Pose2(self.R.compose(other.R), self.R.act(other.t) + self.t)

    def inverse(self) -> Pose2:
        r_inv = self.R.inverse()
        return Pose2(r_inv, -r_inv.act(self.t))

    def act(self, point: Any):
        return self.R.act(point) + self.t

    def matrix(self):
        from .matrix import M33

        c, s = self.R.c, self.R.s
        return M33([[c, -s, self.t[0]], [s, c, self.t[1]], [0, 0, 1]])

    @classmethod
    def exp(cls, v: Any, epsilon: Any = None) -> Pose2:
        sp = _s().sp
        v = as_vector(v, 3, "Pose2.exp")
        theta = v[0]
        te = sp.sqrt(theta**2 + _eps(epsilon))
        a = sp.sin(te) / te  # sin t / t
        b = theta * 2 * sp.sin(te / 2) ** 2 / te**2  # (1 - cos t) / t
        return cls(Rot2.from_angle(theta), [a * v[1] - b * v[2], b * v[1] + a * v[2]])

    def log(self, epsilon: Any = None):
        from .matrix import V3

        sp = _s().sp
        theta = self.R.angle()
        te = sp.sqrt(theta**2 + _eps(epsilon))
        h = te / 2
        a = h * sp.cos(h) / sp.sin(h)  # (t/2) cot(t/2)
        x, y = self.t[0], self.t[1]
        return V3(theta, a * x + theta / 2 * y, -theta / 2 * x + a * y)

    @classmethod
    def _exp_first_order(cls, v: Any) -> Pose2:
        v = as_vector(v, 3, "Pose2 tangent")
        return cls(Rot2(1, v[0]), [v[1], v[2]])

    def tangent_D_storage(self):
        sp = _s().sp
        c, s = self.R.c, self.R.s
        return sp.Matrix([[-s, c, 0, 0], [0, 0, c, s], [0, 0, -s, c]])


class Pose3(LieGroupBase):
    """A 3-D pose ``p -> R p + t``. Storage ``[qx, qy, qz, qw, tx, ty, tz]``; tangent ``[w, v]``.

    ``Exp([w, v]) = (Exp(w), V(w) v)``, ``V = I + B [w]x + C [w]x^2``, ``B = (1 - cos t)/t^2``,
    ``C = (t - sin t)/t^3``; ``Log`` is its inverse,
    ``V^-1 = I - [w]x / 2 + (1 - (t/2) cot(t/2)) / t^2 [w]x^2``.

    Example:

    >>> from fgopt.symbolic import Pose3, V3
    >>> @fgopt.factor
    ... def point_to_point(world_T_body: Pose3, body_point: V3, world_point: V3) -> V3:
    ...     return world_T_body * body_point - world_point
    ...
    >>> values = fgopt.Variables().add(key('x', 0), fgopt.SE3(translation=[1.0, 0.0, 0.0]))
    >>> f = point_to_point(world_T_body=key('x', 0), body_point=np.array([0.0, 1.0, 0.0]), world_point=np.array([1.0, 1.0, 0.0]))
    >>> np.round(f.error(values), 6)
    array([0., 0., 0.])
    """

    __slots__ = ("R", "t")
    _DIM = 6
    _STORAGE_DIM = 7
    _IDENTITY = (0, 0, 0, 1, 0, 0, 0)

    def __init__(self, R: Rot3 | None = None, t: Any = None):
        from .matrix import V3

        self.R = Rot3() if R is None else R
        self.t = V3() if t is None else as_vector(t, 3, "Pose3 translation")

    @classmethod
    def from_storage(cls, data: Any) -> Pose3:
        r, t = _split(data, 4, 7, "Pose3.from_storage")
        return cls(Rot3(r), t)

    def to_storage(self) -> list:
        return self.R.to_storage() + list(self.t)

    def rotation(self) -> Rot3:
        return self.R

    def translation(self):
        return self.t

    position = translation

    def compose(self, other: Pose3) -> Pose3:
        return Pose3(self.R.compose(other.R), self.R.act(other.t) + self.t)

    def inverse(self) -> Pose3:
        r_inv = self.R.inverse()
        return Pose3(r_inv, -r_inv.act(self.t))

    def act(self, point: Any):
        return self.R.act(point) + self.t

    def matrix(self):
        from .matrix import M44

        r = self.R.matrix()
        return M44([[r[0, 0], r[0, 1], r[0, 2], self.t[0]],
                    [r[1, 0], r[1, 1], r[1, 2], self.t[1]],
                    [r[2, 0], r[2, 1], r[2, 2], self.t[2]],
                    [0, 0, 0, 1]])

    @classmethod
    def exp(cls, v: Any, epsilon: Any = None) -> Pose3:
        sp = _s().sp
        xi = as_vector(v, 6, "Pose3.exp")
        w, u = as_vector(list(xi)[:3], 3, ""), as_vector(list(xi)[3:], 3, "")
        te = sp.sqrt(w.squared_norm() + _eps(epsilon))
        b = 2 * sp.sin(te / 2) ** 2 / te**2
        c = (te - sp.sin(te)) / te**3
        wu = w.cross(u)
        return cls(Rot3.exp(w, epsilon), u + b * wu + c * w.cross(wu))

    def log(self, epsilon: Any = None):
        from .matrix import V6

        sp = _s().sp
        w = self.R.log(epsilon)
        te = sp.sqrt(w.squared_norm() + _eps(epsilon))
        h = te / 2
        c = (1 - h * sp.cos(h) / sp.sin(h)) / te**2
        wt = w.cross(self.t)
        v = self.t - wt / 2 + c * w.cross(wt)
        return V6(list(w) + list(v))

    @classmethod
    def _exp_first_order(cls, v: Any) -> Pose3:
        xi = list(as_vector(v, 6, "Pose3 tangent"))
        return cls(Rot3._exp_first_order(xi[:3]), xi[3:])

    def tangent_D_storage(self):
        sp = _s().sp
        out = sp.zeros(6, 7)
        out[:3, :4] = self.R.tangent_D_storage()
        out[3:, 4:] = self.R.matrix().mat.T
        return out
