"""``NavState``: attitude, position and velocity of a body, a manifold value (GTSAM's NavState).

Storage ``[qx, qy, qz, qw, px, py, pz, vx, vy, vz]``: the unit quaternion of ``world_R_body``,
then the body's position and velocity in the world (navigation) frame. Tangent
``[rotation(3), position(3), velocity(3)]``; the optimizer's chart is GTSAM's::

    retract(x, [dR, dP, dV]) = (R Exp(dR), p + R dP, v + R dV)
    local(a, b) = [Log(Ra^T Rb), Ra^T (pb - pa), Ra^T (vb - va)]

``compose`` / ``inverse`` / ``between`` / ``exp`` / ``log`` are those of the group SE_2(3)
(GTSAM's ``NavState::Expmap`` / ``Logmap``), which agree with the chart to first order. The
kernels are in :mod:`fgopt.navigation._navstate_kernels`; values of this class live in one
``(n, 10)`` array in a compiled problem, like the Lie groups.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import ManifoldError
from ..manifolds import SE3, SO3
from ..manifolds.base import BatchKind, register
from ..manifolds.lie import as_float_vector
from ..manifolds.so2 import as_matrix, normalize_unit
from ..symbolic.navstate import NavState as SymbolicNavState
from ..symbolic.ops import register_numeric_twin
from . import _navstate_kernels as K


def _as_so3(attitude: Any) -> SO3:
    if attitude is None:
        return SO3()
    if isinstance(attitude, SO3):
        return attitude
    return SO3.from_matrix(as_matrix(attitude, 3, "NavState attitude"))


class NavState:
    """Attitude ``world_R_body``, position and velocity (in the world frame); see the module
    docstring for storage, tangent and chart. Immutable.

    Example:

    >>> from fgopt import SE3
    >>> from fgopt.navigation import NavState
    >>> x = NavState.from_pose_velocity(SE3(translation=[1.0, 0.0, 0.0]), [0.0, 2.0, 0.0])
    >>> x.position(), x.velocity()
    (array([1., 0., 0.]), array([0., 2., 0.]))
    >>> np.round(x.local(x.retract(np.arange(9) * 0.01)), 6)
    array([0.  , 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08])
    """

    __slots__ = ("_buf", "_data")
    _DIM = K.DIM
    _STORAGE_DIM = K.STORAGE_DIM
    _kind: BatchKind | None = None

    def __init__(self, attitude: SO3 | Any = None, position: Any = (0.0, 0.0, 0.0),
                 velocity: Any = (0.0, 0.0, 0.0)):
        """``attitude``: an :class:`~fgopt.manifolds.SO3` or a 3x3 rotation matrix."""
        data = np.empty(K.STORAGE_DIM)
        data[:4] = _as_so3(attitude).to_storage()
        data[4:7] = as_float_vector(position, 3, "NavState position")
        data[7:10] = as_float_vector(velocity, 3, "NavState velocity")
        self._set(data)

    # ---------------------------------------------------------------- construction
    def _set(self, data: np.ndarray) -> None:
        # an owned array, read-only like a stored value's: one numba type for both
        data.flags.writeable = False
        object.__setattr__(self, "_buf", data)
        object.__setattr__(self, "_data", data)

    @classmethod
    def _wrap(cls, data: np.ndarray) -> NavState:
        obj = object.__new__(cls)
        obj._set(data)
        return obj

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("NavState values are immutable")

    @classmethod
    def from_pose_velocity(cls, pose: SE3, velocity: Any) -> NavState:
        """GTSAM's ``NavState(pose, v)``: ``velocity`` in the world frame."""
        if not isinstance(pose, SE3):
            raise ManifoldError(f"NavState.from_pose_velocity: expected an SE3, got "
                                f"{type(pose).__name__}")
        s = pose.to_storage()
        return cls(SO3._wrap(s[:4].copy()), s[4:7], velocity)

    @classmethod
    def from_storage(cls, data: Any) -> NavState:
        arr = as_float_vector(data, K.STORAGE_DIM, "NavState.from_storage")
        normalize_unit(arr[:4], "NavState")
        return cls._wrap(arr)

    def to_storage(self) -> np.ndarray:
        return self._data.copy()

    @classmethod
    def identity(cls) -> NavState:
        return cls()

    @classmethod
    def random(cls, rng: Any = None) -> NavState:
        rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        return cls(SO3.random(rng), rng.normal(size=3), rng.normal(size=3))

    @classmethod
    def dim(cls) -> int:
        return K.DIM

    @classmethod
    def storage_dim(cls) -> int:
        return K.STORAGE_DIM

    @classmethod
    def batch_kind(cls) -> BatchKind:
        assert cls._kind is not None
        return cls._kind

    # ---------------------------------------------------------------- accessors
    def attitude(self) -> SO3:
        """``world_R_body``."""
        return SO3._wrap(self._data[:4].copy())

    def rotation(self) -> np.ndarray:
        """``world_R_body`` as a 3x3 matrix (GTSAM's ``R()``)."""
        return self.attitude().matrix()

    def position(self) -> np.ndarray:
        return self._data[4:7].copy()

    def velocity(self) -> np.ndarray:
        """Velocity in the world frame."""
        return self._data[7:10].copy()

    def body_velocity(self) -> np.ndarray:
        """Velocity in the body frame, ``R^T v``."""
        return self.rotation().T @ self._data[7:10]

    def pose(self) -> SE3:
        return SE3._wrap(self._data[:7].copy())

    def matrix(self) -> np.ndarray:
        """The 5x5 SE_2(3) matrix ``[[R, p, v], [0, 1, 0], [0, 0, 1]]``."""
        m = np.eye(5)
        m[:3, :3] = self.rotation()
        m[:3, 3] = self._data[4:7]
        m[:3, 4] = self._data[7:10]
        return m

    # ---------------------------------------------------------------- chart
    def retract(self, delta: Any) -> NavState:
        """``(R Exp(dR), p + R dP, v + R dV)`` for ``delta = [dR, dP, dV]``."""
        d = as_float_vector(delta, K.DIM, "NavState.retract")
        out = np.empty(K.STORAGE_DIM)
        K.navstate_retract(self._buf, d, out, np.empty(4))
        return self._wrap(out)

    def local(self, other: NavState) -> np.ndarray:
        """``[Log(R^T Ro), R^T (po - p), R^T (vo - v)]``: ``self.retract(self.local(o)) == o``."""
        self._check(other, "local")
        out = np.empty(K.DIM)
        K.navstate_local(self._buf, other._buf, out, np.empty(4))
        return out

    local_coordinates = local

    # ---------------------------------------------------------------- group SE_2(3)
    def compose(self, other: NavState) -> NavState:
        self._check(other, "compose")
        out = np.empty(K.STORAGE_DIM)
        K.navstate_compose(self._buf, other._buf, out)
        return self._wrap(out)

    def inverse(self) -> NavState:
        out = np.empty(K.STORAGE_DIM)
        K.navstate_inverse(self._buf, out)
        return self._wrap(out)

    def between(self, other: NavState) -> NavState:
        """``self^-1 * other``."""
        return self.inverse().compose(other)

    @classmethod
    def exp(cls, xi: Any) -> NavState:
        """SE_2(3) exponential (GTSAM's ``NavState::Expmap``)."""
        v = as_float_vector(xi, K.DIM, "NavState.exp")
        out = np.empty(K.STORAGE_DIM)
        K.navstate_exp(v, out)
        return cls._wrap(out)

    def log(self) -> np.ndarray:
        """SE_2(3) logarithm (GTSAM's ``NavState::Logmap``); rotation angle in [0, pi]."""
        out = np.empty(K.DIM)
        K.navstate_log(self._buf, out)
        return out

    def __mul__(self, other: Any) -> NavState:
        if isinstance(other, NavState):
            return self.compose(other)
        return NotImplemented

    # ---------------------------------------------------------------- python protocol
    def _check(self, other: Any, op: str) -> None:
        if not isinstance(other, NavState):
            raise ManifoldError(f"NavState.{op}: expected a NavState, got {type(other).__name__}")

    def equals(self, other: Any, tol: float = 1e-9) -> bool:
        if not isinstance(other, NavState):
            return False
        return bool(np.max(np.abs(self.matrix() - other.matrix())) <= tol)

    def __reduce__(self):
        return (NavState.from_storage, (self._data.copy(),))

    def __copy__(self):
        return self

    def __deepcopy__(self, memo: dict):
        return self

    def __repr__(self) -> str:
        (qw, qx, qy, qz) = self.attitude().quaternion()
        p, v = self._data[4:7], self._data[7:10]
        return (f"NavState(p=[{p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}], "
                f"v=[{v[0]:.3f}, {v[1]:.3f}, {v[2]:.3f}], "
                f"q=[w={qw:.3f}, x={qx:.3f}, y={qy:.3f}, z={qz:.3f}])")


class NavStateOps:
    """:class:`~fgopt.manifolds.base.ManifoldOps` traits of :class:`NavState`."""

    def __init__(self) -> None:
        self.kind = BatchKind(name="NavState", dim=K.DIM, storage_dim=K.STORAGE_DIM,
                              retract=K.navstate_retract_batch, local=K.navstate_local_batch,
                              from_storage=NavState.from_storage, to_storage=self.to_storage,
                              wrap=NavState._wrap)

    def dim(self, x: Any) -> int:
        return K.DIM

    def storage_dim(self, x: Any) -> int:
        return K.STORAGE_DIM

    def to_storage(self, x: Any) -> np.ndarray:
        if not isinstance(x, NavState):
            raise ManifoldError(f"NavState storage requested for a {type(x).__name__} value")
        return x.to_storage()

    def from_storage(self, like: Any, data: np.ndarray) -> NavState:
        return NavState.from_storage(data)

    def retract(self, x: Any, delta: np.ndarray) -> NavState:
        return x.retract(delta)

    def local(self, x: Any, y: Any) -> np.ndarray:
        return x.local(y)

    def batch_kind(self, x: Any) -> BatchKind:
        return self.kind


_OPS = NavStateOps()
NavState._kind = _OPS.kind
register(NavState, _OPS)
register_numeric_twin(SymbolicNavState, NavState)
