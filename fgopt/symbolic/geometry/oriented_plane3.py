"""``OrientedPlane3``: a plane as unit normal and distance (GTSAM's), declared as a product."""

from __future__ import annotations

from typing import Any

from ..declare import manifold
from ..declare.product import Product
from ..matrix import V4, Scalar
from .unit3 import Unit3


@manifold
class OrientedPlane3(Product(Unit3, Scalar, names=("normal", "distance"))):
    """An oriented plane ``{p : n^T p + d = 0}``, GTSAM's ``OrientedPlane3``.

    Storage ``[nx, ny, nz, d]`` (unit normal, then distance); tangent ``[v (2), dd]``: the
    normal's :class:`~fgopt.symbolic.geometry.unit3.Unit3` coordinates, then the distance.
    ``retract((n, d), [v, dd]) = (n.retract(v), d + dd)`` and ``local`` likewise, as GTSAM's
    ``OrientedPlane3::retract`` / ``localCoordinates`` (the product ``Unit3 x R``).

    >>> plane = fgopt.OrientedPlane3([0.0, 0.0, 1.0, -2.0])    # the plane z = 2, normal +z
    >>> tilted = plane.retract([0.1, 0.0, 0.5])                # tilt the normal, move by 0.5
    >>> np.round(plane.local(tilted), 6), round(float(tilted.to_storage()[3]), 6)
    (array([0.1, 0. , 0.5]), -1.5)
    """

    def plane_coefficients(x) -> V4:
        """``[nx, ny, nz, d]`` (GTSAM's ``planeCoefficients``)."""
        n = x.normal().point3()
        return V4(n[0], n[1], n[2], x.distance())

    def transform(x, pose: Any):
        """The plane in the frame of ``pose`` (a ``Pose3``, world_T_frame): normal ``R^T n``,
        distance ``n . t + d`` (GTSAM's ``OrientedPlane3::transform``)."""
        n = x.normal().point3()
        R, t = pose.rotation(), pose.translation()
        nr = R.inverse() * n
        return OrientedPlane3([nr[0], nr[1], nr[2], n.dot(t) + x.distance()])
