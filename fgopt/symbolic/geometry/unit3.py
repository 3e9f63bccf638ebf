"""``Unit3``: directions in R^3 (the 2-sphere S^2) with GTSAM's chart, declared with
``@fgopt.manifold``."""

from __future__ import annotations

from ..declare import manifold
from ..functions import Abs, atan2, cos, sin, where
from ..matrix import V3, Matrix

M32 = Matrix.shaped(3, 2)


def best_axis(p: V3) -> V3:
    """GTSAM's choice of helper axis: the coordinate axis of the smallest ``|p_i|`` (ties go to
    x, then y), as a 0/1 vector (a branchless select)."""
    ax, ay, az = Abs(p[0]), Abs(p[1]), Abs(p[2])
    hx = where((ax <= ay) & (ax <= az), 1, 0)
    hy = (1 - hx) * where((ay <= ax) & (ay <= az), 1, 0)
    return V3(hx, hy, 1 - hx - hy)


@manifold
class Unit3:
    """A direction in R^3 (a point of S^2), GTSAM's ``Unit3``.

    Storage: the unit vector ``p = [x, y, z]``. Tangent: coordinates ``v`` (2) in the basis
    ``B(p) = [b1, b2]`` of the plane orthogonal to ``p``, GTSAM's basis: ``b1 = p x a / |p x a|``
    with ``a`` the coordinate axis of the smallest ``|p_i|``, ``b2 = p x b1``.

    ``retract(p, v) = cos|xi| p + sin|xi| / |xi| xi`` with ``xi = B(p) v`` (a step along the
    great circle, then normalized; GTSAM's ``Unit3::retract``). ``local(p, q) = theta /
    sin(theta) B(p)^T q`` with ``theta`` the angle between ``p`` and ``q`` (GTSAM's
    ``localCoordinates``; antipodal ``q`` has no unique answer). ``B`` jumps where the smallest
    component changes, as GTSAM's does, so tangent coordinates are only comparable at one point.

    Example:

    >>> n = fgopt.Unit3([0.0, 0.0, 1.0])
    >>> m = n.retract([0.1, 0.0])
    >>> np.round(n.local(m), 6)
    array([0.1, 0. ])

    Example:

    >>> from fgopt.symbolic import Unit3, V3, V1
    >>> @fgopt.factor
    ... def facing(n: Unit3, d: V3) -> V1:
    ...     return V1(n.point3().dot(d) - 1)
    ...
    >>> values = fgopt.Variables().add(key('n', 0), fgopt.Unit3([0.0, 0.0, 1.0]))
    >>> np.round(facing(n=key('n', 0), d=np.array([0.0, 0.0, 1.0])).error(values), 6)
    array([0.])
    """

    storage_dim = 3
    dim = 2

    def identity():
        return V3(0, 0, 1)

    def point3(x) -> V3:
        """The unit vector (GTSAM's ``point3`` / ``unitVector``)."""
        return V3(x[0], x[1], x[2])

    def basis(x) -> M32:
        """``B(p)``, 3x2: an orthonormal basis of the tangent plane (columns b1, b2)."""
        p = x.point3()
        b1 = p.cross(best_axis(p))
        b1 = b1 / b1.norm(0)  # |p x a| >= sqrt(2/3) for a unit p: no epsilon needed
        b2 = p.cross(b1)
        return M32([[b1[0], b2[0]], [b1[1], b2[1]], [b1[2], b2[2]]])

    def retract(x, v):
        p = x.point3()
        xi = x.basis() * v
        theta = xi.norm()  # sqrt(|xi|^2 + epsilon^2): finite sin(theta)/theta at v = 0
        return cos(theta) * p + (sin(theta) / theta) * xi

    def local(x, y):
        p, q = x.point3(), y.point3()
        s = p.cross(q).norm()  # sin(theta), shifted by epsilon: theta / s -> 1 at q = p
        theta = atan2(s, p.dot(q), epsilon=0)
        return (theta / s) * (x.basis().T * q)

    def normalize(x):
        p = x.point3()
        return p / p.norm(0)
