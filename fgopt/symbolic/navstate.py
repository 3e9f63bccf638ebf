"""Symbolic :class:`NavState` (twin of ``fgopt.navigation.NavState``), for ``@fgopt.factor``.

Storage ``[qx, qy, qz, qw, px, py, pz, vx, vy, vz]``; tangent ``[rotation, position, velocity]``.
The group is SE_2(3): ``a * b = (Ra Rb, Ra pb + pa, Ra vb + va)``, ``Exp([w, rho, nu]) =
(Exp(w), V(w) rho, V(w) nu)`` with SE(3)'s ``V``. ``retract`` / ``local`` are GTSAM's chart
``(R Exp(dR), p + R dP, v + R dV)``, which equals ``x * Exp(d)`` to first order, so the tangent
Jacobians derived from ``storage_D_tangent`` (``x * Exp_1(d)``) are those of the chart the
optimizer uses. Variables of this type are ``fgopt.navigation.NavState`` values (registered as
its numeric twin when ``fgopt.navigation`` is imported).
"""

from __future__ import annotations

from typing import Any

from .lie import LieGroupBase, as_vector
from .rot import Rot3


def _s():
    from . import _sym

    return _sym


def _eps(epsilon: Any):
    return _s().epsilon if epsilon is None else _s().as_expr(epsilon)


class NavState(LieGroupBase):
    """Attitude ``world_R_body``, position and velocity (world frame); see the module docstring.

    ``retract`` moves the velocity along the body axes (GTSAM's chart ``v + R dV``):

    >>> from fgopt.symbolic import NavState, Rot3, V3
    >>> x = NavState(Rot3.from_angle_axis(np.pi / 2, [0, 0, 1]), V3(1, 2, 3), V3(0.5, 0, 0))
    >>> y = x.retract([0, 0, 0, 0, 0, 0, 1.0, 0, 0], epsilon=0)    # +1 m/s along body x
    >>> [round(float(c), 6) for c in y.velocity()], NavState.dim()
    ([0.5, 1.0, 0.0], 9)
    """

    __slots__ = ("R", "p", "v")
    _DIM = 9
    _STORAGE_DIM = 10
    _IDENTITY = (0, 0, 0, 1, 0, 0, 0, 0, 0, 0)

    def __init__(self, R: Rot3 | None = None, p: Any = None, v: Any = None):
        from .matrix import V3

        self.R = Rot3() if R is None else R
        self.p = V3() if p is None else as_vector(p, 3, "NavState position")
        self.v = V3() if v is None else as_vector(v, 3, "NavState velocity")

    @classmethod
    def from_storage(cls, data: Any) -> NavState:
        from .rot import _flat

        flat = _flat(data, 10, "NavState.from_storage")
        return cls(Rot3(flat[:4]), flat[4:7], flat[7:10])

    def to_storage(self) -> list:
        return self.R.to_storage() + list(self.p) + list(self.v)

    @classmethod
    def from_pose_velocity(cls, pose: Any, velocity: Any) -> NavState:
        return cls(pose.R, pose.t, velocity)

    def attitude(self) -> Rot3:
        return self.R

    def position(self):
        return self.p

    def velocity(self):
        return self.v

    def body_velocity(self):
        """``R^T v``."""
        return self.R.inverse().act(self.v)

    def pose(self):
        from .pose import Pose3

        return Pose3(self.R, self.p)

    # ---------------------------------------------------------------- group SE_2(3)
    def compose(self, other: NavState) -> NavState:
        return NavState(self.R.compose(other.R), self.R.act(other.p) + self.p,
                        self.R.act(other.v) + self.v)

    def inverse(self) -> NavState:
        r_inv = self.R.inverse()
        return NavState(r_inv, -r_inv.act(self.p), -r_inv.act(self.v))

    def act(self, point: Any):
        raise TypeError("a NavState does not act on points; use state.pose() * point")

    def matrix(self):
        """The 5x5 matrix ``[[R, p, v], [0, 1, 0], [0, 0, 1]]``."""
        from .matrix import Matrix

        r = self.R.matrix()
        rows = [[r[i, 0], r[i, 1], r[i, 2], self.p[i], self.v[i]] for i in range(3)]
        return Matrix.shaped(5, 5)(rows + [[0, 0, 0, 1, 0], [0, 0, 0, 0, 1]])

    @classmethod
    def exp(cls, v: Any, epsilon: Any = None) -> NavState:
        sp = _s().sp
        xi = list(as_vector(v, 9, "NavState.exp"))
        w = as_vector(xi[:3], 3, "")
        te = sp.sqrt(w.squared_norm() + _eps(epsilon))
        b = 2 * sp.sin(te / 2) ** 2 / te**2
        c = (te - sp.sin(te)) / te**3

        def V(u):
            u = as_vector(u, 3, "")
            wu = w.cross(u)
            return u + b * wu + c * w.cross(wu)

        return cls(Rot3.exp(w, epsilon), V(xi[3:6]), V(xi[6:9]))

    def log(self, epsilon: Any = None):
        from .matrix import V9

        sp = _s().sp
        w = self.R.log(epsilon)
        te = sp.sqrt(w.squared_norm() + _eps(epsilon))
        h = te / 2
        c = (1 - h * sp.cos(h) / sp.sin(h)) / te**2

        def V_inv(u):
            wu = w.cross(u)
            return u - wu / 2 + c * w.cross(wu)

        return V9(list(w) + list(V_inv(self.p)) + list(V_inv(self.v)))

    # ---------------------------------------------------------------- chart (GTSAM's)
    def retract(self, v: Any, epsilon: Any = None) -> NavState:
        """``(R Exp(dR), p + R dP, v + R dV)``."""
        d = list(as_vector(v, 9, "NavState.retract"))
        return NavState(self.R.compose(Rot3.exp(d[:3], epsilon)), self.p + self.R.act(d[3:6]),
                        self.v + self.R.act(d[6:9]))

    def local(self, other: NavState, epsilon: Any = None):
        """``[Log(R^T Ro), R^T (po - p), R^T (vo - v)]``."""
        from .matrix import V9

        r_inv = self.R.inverse()
        w = r_inv.compose(other.R).log(epsilon)
        return V9(list(w) + list(r_inv.act(other.p - self.p)) + list(r_inv.act(other.v - self.v)))

    local_coordinates = local

    @classmethod
    def _exp_first_order(cls, v: Any) -> NavState:
        xi = list(as_vector(v, 9, "NavState tangent"))
        return cls(Rot3._exp_first_order(xi[:3]), xi[3:6], xi[6:9])

    def tangent_D_storage(self):
        sp = _s().sp
        out = sp.zeros(9, 10)
        out[:3, :4] = self.R.tangent_D_storage()
        rt = self.R.matrix().mat.T
        out[3:6, 4:7] = rt
        out[6:9, 7:10] = rt
        return out
