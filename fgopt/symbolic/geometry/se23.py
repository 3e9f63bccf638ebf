"""``SE23``: extended poses SE_2(3) (rotation, velocity, position), declared with
``@fgopt.manifold``: the group of Barrau and Bonnabel's invariant EKF."""

from __future__ import annotations

from typing import Any

from ..declare import manifold
from ..matrix import V3, V9
from ..rot import Rot3


def _s():
    from .. import _sym

    return _sym


def _v_apply(w: V3, u: V3, epsilon: Any) -> V3:
    """``V(w) u = u + B w x u + C w x (w x u)``, ``B = (1 - cos t)/t^2``, ``C = (t - sin t)/t^3``,
    evaluated at ``t = sqrt(|w|^2 + epsilon)`` like ``Pose3.exp`` (smooth in ``t^2``)."""
    sp = _s().sp
    te = sp.sqrt(w.squared_norm() + epsilon)
    b = 2 * sp.sin(te / 2) ** 2 / te**2
    c = (te - sp.sin(te)) / te**3
    wu = w.cross(u)
    return u + b * wu + c * w.cross(wu)


def _v_inverse_apply(w: V3, u: V3, epsilon: Any) -> V3:
    """``V(w)^-1 u = u - w x u / 2 + (1 - (t/2) cot(t/2)) / t^2 w x (w x u)``."""
    sp = _s().sp
    te = sp.sqrt(w.squared_norm() + epsilon)
    h = te / 2
    c = (1 - h * sp.cos(h) / sp.sin(h)) / te**2
    wu = w.cross(u)
    return u - wu / 2 + c * w.cross(wu)


def se23_exp(xi: Any) -> list:
    """Storage of ``Exp([w, a, b]) = (Exp(w), V(w) a, V(w) b)``."""
    eps = _s().epsilon
    w, a, b = V3(list(xi)[0:3]), V3(list(xi)[3:6]), V3(list(xi)[6:9])
    return Rot3.exp(w).to_storage() + list(_v_apply(w, a, eps)) + list(_v_apply(w, b, eps))


@manifold
class SE23:
    """An extended pose ``(R, v, p)``: attitude, velocity and position (SE_2(3)).

    Storage ``[qx, qy, qz, qw, vx, vy, vz, px, py, pz]``; tangent ``[w, a, b]`` (rotation,
    velocity, position; 9). The group acts as the 5x5 matrix ``[[R, v, p], [0, 1, 0], [0, 0,
    1]]``: ``(R1, v1, p1) (R2, v2, p2) = (R1 R2, R1 v2 + v1, R1 p2 + p1)``. ``retract(x, xi) =
    x Exp(xi)`` and ``local(x, y) = Log(x^-1 y)`` with the true group exponential
    ``Exp([w, a, b]) = (Exp(w), V(w) a, V(w) b)``, ``V`` the left Jacobian of SO(3) (as in
    ``Pose3``), so ``retract`` couples rotation with velocity and position (unlike the product
    ``SO(3) x R^3 x R^3``).

    Turning 90 degrees about z while gaining 1 m/s along x gives the velocity ``V(w) a``:

    >>> x = fgopt.SE23()                                  # R = I, v = p = 0
    >>> y = x.retract([0, 0, np.pi / 2, 1.0, 0, 0, 0, 0, 0])
    >>> np.round(y.to_storage()[4:7], 6)                  # 2 / pi in x and y
    array([0.63662, 0.63662, 0.     ])
    >>> np.allclose(x.local(y), [0, 0, np.pi / 2, 1.0, 0, 0, 0, 0, 0])
    True
    """

    storage_dim = 10
    dim = 9
    fields = ("rotation", "velocity", "position")

    def identity():
        return [0, 0, 0, 1, 0, 0, 0, 0, 0, 0]

    def rotation(x) -> Rot3:
        return Rot3(x.to_storage()[0:4])

    def velocity(x) -> V3:
        return x[4:7]

    def position(x) -> V3:
        return x[7:10]

    def compose(x, y):
        R1, R2 = x.rotation(), y.rotation()
        return type(x)(R1.compose(R2).to_storage() + list(R1 * y.velocity() + x.velocity())
                       + list(R1 * y.position() + x.position()))

    def inverse(x):
        Ri = x.rotation().inverse()
        return type(x)(Ri.to_storage() + list(-(Ri * x.velocity())) + list(-(Ri * x.position())))

    def retract(x, xi):
        return x.compose(type(x)(se23_exp(xi))).to_storage()

    def local(x, y):
        d = x.inverse().compose(y)
        eps = _s().epsilon
        w = d.rotation().log()
        return V9(list(w) + list(_v_inverse_apply(w, d.velocity(), eps))
                  + list(_v_inverse_apply(w, d.position(), eps)))

    def normalize(x):
        q = x[0:4]
        return list(q / q.norm(0)) + x.to_storage()[4:10]
