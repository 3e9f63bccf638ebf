"""Symbolic rotations: :class:`Rot2` and :class:`Rot3` (twins of ``fgopt.manifolds.SO2/SO3``).

Singularities are handled without branches (SymForce paper, Sec. VI): ``Rot3.exp`` uses
``theta = sqrt(|w|^2 + epsilon^2)``; ``Rot3.log`` uses ``n = sqrt(|xyz|^2 + epsilon^2)`` and
``2 atan2(n, |w|) / n``, which is finite and smooth at the identity and accurate up to angle pi;
the double cover (``q ~ -q``) is resolved by ``sign_no_zero(w)``. In both the epsilon-shifted
norm only enters through factors that vanish with the rotation vector, so values *and* first
derivatives are exact to rounding at angle 0.
"""

from __future__ import annotations

from typing import Any

from ..errors import DimensionMismatchError

from .lie import LieGroupBase, as_vector


def _s():
    from . import _sym

    return _sym


def _eps(epsilon: Any):
    return _s().epsilon if epsilon is None else _s().as_expr(epsilon)


def _flat(data: Any, n: int, what: str) -> list:
    from .matrix import _flatten

    flat = _flatten(data)
    if len(flat) != n:
        raise DimensionMismatchError(f"{what}: expected {n} storage entries, got {len(flat)}")
    return [_s().as_expr(v) for v in flat]


class Rot2(LieGroupBase):
    """A planar rotation. Storage ``[cos, sin]``; tangent ``[theta]``; ``Exp(t) = (cos t, sin t)``.

    ``Log`` is ``atan2(sin, cos)`` in (-pi, pi]. ``rot * p`` rotates a ``V2``.

    >>> from fgopt.symbolic import Rot2, V2
    >>> R = Rot2.from_angle(np.pi / 2)
    >>> [round(float(c), 6) for c in R * V2(1, 0)]          # x axis -> y axis
    [0.0, 1.0]
    >>> round(float((R * R).log(epsilon=0)[0]), 6)           # 90 + 90 degrees
    3.141593
    """

    __slots__ = ("c", "s")
    _DIM = 1
    _STORAGE_DIM = 2
    _IDENTITY = (1, 0)

    def __init__(self, c: Any = 1, s: Any = 0):
        self.c, self.s = _s().as_expr(c), _s().as_expr(s)

    @classmethod
    def from_storage(cls, data: Any) -> Rot2:
        c, s = _flat(data, 2, "Rot2.from_storage")
        return cls(c, s)

    def to_storage(self) -> list:
        return [self.c, self.s]

    @classmethod
    def from_angle(cls, theta: Any) -> Rot2:
        sp = _s().sp
        theta = _s().as_expr(theta)
        return cls(sp.cos(theta), sp.sin(theta))

    def angle(self):
        """``atan2(sin, cos)`` (a scalar expression)."""
        return _s().sp.atan2(self.s, self.c)

    def compose(self, other: Rot2) -> Rot2:
        return Rot2(self.c * other.c - self.s * other.s, self.s * other.c + self.c * other.s)

    def inverse(self) -> Rot2:
        return Rot2(self.c, -self.s)

    def matrix(self):
        from .matrix import M22

        return M22([[self.c, -self.s], [self.s, self.c]])

    to_rotation_matrix = matrix

    def act(self, point: Any):
        from .matrix import V2

        p = as_vector(point, 2, "Rot2 * point")
        return V2(self.c * p[0] - self.s * p[1], self.s * p[0] + self.c * p[1])

    @classmethod
    def exp(cls, v: Any, epsilon: Any = None) -> Rot2:
        return cls.from_angle(as_vector(v, 1, "Rot2.exp")[0])

    def log(self, epsilon: Any = None):
        from .matrix import V1

        return V1(self.angle())

    @classmethod
    def _exp_first_order(cls, v: Any) -> Rot2:
        return cls(1, as_vector(v, 1, "Rot2 tangent")[0])

    def tangent_D_storage(self):
        return _s().sp.Matrix([[-self.s, self.c]])


class Rot3(LieGroupBase):
    """A 3-D rotation. Storage: quaternion ``[qx, qy, qz, qw]``; tangent: rotation vector.

    ``Exp(w)`` rotates by ``|w|`` about ``w / |w|``; ``Log`` returns the shortest rotation vector
    (angle in [0, pi]). ``rot * p`` rotates a ``V3``. Operations assume a unit quaternion,
    except ``log`` which is invariant to the quaternion's scale.

    Example:

    >>> from fgopt.symbolic import Rot3, V3, generate
    >>> def rotate(R: Rot3, v: V3) -> V3:
    ...     return R * v
    ...
    >>> f = generate(rotate, which=['R'])
    >>> value, J = f(fgopt.SO3.from_rotvec([0.0, 0.0, np.pi / 2]), np.array([1.0, 0.0, 0.0]))
    >>> np.round(value, 6), J.shape
    (array([0., 1., 0.]), (3, 3))
    """

    __slots__ = ("q",)
    _DIM = 3
    _STORAGE_DIM = 4
    _IDENTITY = (0, 0, 0, 1)

    def __init__(self, q: Any = None):
        self.q = [_s().as_expr(v) for v in self._IDENTITY] if q is None \
            else _flat(q, 4, "Rot3 quaternion [qx, qy, qz, qw]")

    @classmethod
    def from_storage(cls, data: Any) -> Rot3:
        return cls(data)

    def to_storage(self) -> list:
        return list(self.q)

    @classmethod
    def from_angle_axis(cls, angle: Any, axis: Any) -> Rot3:
        """Rotation by ``angle`` about the unit vector ``axis``."""
        sp = _s().sp
        a = as_vector(axis, 3, "Rot3.from_angle_axis")
        h = _s().as_expr(angle) / 2
        return cls([sp.sin(h) * a[0], sp.sin(h) * a[1], sp.sin(h) * a[2], sp.cos(h)])

    def compose(self, other: Rot3) -> Rot3:
        x1, y1, z1, w1 = self.q
        x2, y2, z2, w2 = other.q
        return Rot3([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
                     w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2])

    def inverse(self) -> Rot3:
        x, y, z, w = self.q
        return Rot3([-x, -y, -z, w])

    def matrix(self):
        from .matrix import M33

        x, y, z, w = self.q
        x2, y2, z2 = 2 * x * x, 2 * y * y, 2 * z * z
        xy, xz, yz, xw, yw, zw = 2 * x * y, 2 * x * z, 2 * y * z, 2 * x * w, 2 * y * w, 2 * z * w
        return M33([[1 - y2 - z2, xy - zw, xz + yw],
                    [xy + zw, 1 - x2 - z2, yz - xw],
                    [xz - yw, yz + xw, 1 - x2 - y2]])

    to_rotation_matrix = matrix

    def act(self, point: Any):
        return self.matrix() * as_vector(point, 3, "Rot3 * point")

    @classmethod
    def exp(cls, v: Any, epsilon: Any = None) -> Rot3:
        """``q = [sin(t/2) w / t, cos(t/2)]``, ``t = sqrt(|w|^2 + epsilon^2)``."""
        sp = _s().sp
        w = as_vector(v, 3, "Rot3.exp")
        theta = sp.sqrt(w.squared_norm() + _eps(epsilon) ** 2)
        k = sp.sin(theta / 2) / theta
        return cls([k * w[0], k * w[1], k * w[2], sp.cos(theta / 2)])

    def log(self, epsilon: Any = None):
        """``2 atan2(n, |w|) / n * snz(w) * xyz``, ``n = sqrt(|xyz|^2 + epsilon^2)``."""
        from .matrix import V3

        s = _s()
        x, y, z, w = self.q
        sw = s.snz(w)
        n = s.sp.sqrt(x * x + y * y + z * z + _eps(epsilon) ** 2)
        k = 2 * s.sp.atan2(n, w * sw) / n * sw
        return V3(k * x, k * y, k * z)

    @classmethod
    def _exp_first_order(cls, v: Any) -> Rot3:
        w = as_vector(v, 3, "Rot3 tangent")
        return cls([w[0] / 2, w[1] / 2, w[2] / 2, 1])

    def tangent_D_storage(self):
        """``4 * storage_D_tangent()^T`` (its columns are orthogonal with norm 1/2)."""
        return 4 * self.storage_D_tangent().T
