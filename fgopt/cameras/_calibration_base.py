"""What every camera calibration model shares: the :class:`Calibration` base (storage,
vector-space manifold, GTSAM accessors, batched ``uncalibrate`` / ``calibrate``), its manifold
traits and batch kinds, and the point-array check. The models themselves are in
:mod:`fgopt.cameras.calibration`; their math in :mod:`fgopt.cameras._calib_kernels`.
"""

from __future__ import annotations

import inspect
from typing import Any, ClassVar

import numpy as np

from .._jit import specialize
from ..errors import CalibrationError, CheiralityError, DimensionMismatchError, NonFiniteError
from ..manifolds.base import BatchKind, register
from . import _calib_kernels as CK
from .._checks import float_array, is_count, is_positive, number

#: Default pixel tolerance and iteration limit of the iterative ``calibrate``.
CALIBRATE_TOL = 1e-9
CALIBRATE_MAX_ITERATIONS = 20


def as_points2(values: Any, what: str) -> tuple[np.ndarray, bool]:
    """``(n, 2)`` float array of ``values`` (one ``(2,)`` point or many), and whether it was one."""
    a = float_array(values, what, "a (2,) point or an (n, 2) array of numbers")
    single = a.ndim == 1
    a = np.ascontiguousarray(a.reshape(1, -1) if single else a)
    if a.ndim != 2 or a.shape[1] != 2:
        raise DimensionMismatchError(f"{what}: expected a (2,) point or an (n, 2) array, got "
                                     f"shape {np.shape(values)}")
    if not np.all(np.isfinite(a)):
        i = int(np.nonzero(~np.all(np.isfinite(a), axis=1))[0][0])
        raise NonFiniteError(f"{what}: point {i} has a NaN or inf: {a[i]}")
    return a, single


class Calibration:
    """Base of the calibration models (:mod:`fgopt.cameras.calibration` lists them).

    Every model is a vector-space manifold (it can be a variable); ``PARAMS`` names its storage
    and ``DIM`` is its tangent dimension:

    >>> from fgopt.cameras import Cal3_S2, Cal3Bundler, Calibration
    >>> issubclass(Cal3Bundler, Calibration), Cal3Bundler.PARAMS, Cal3Bundler.DIM
    (True, ('f', 'k1', 'k2', 'u0', 'v0'), 3)
    >>> K = Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)
    >>> K.retract(np.array([10.0, 0.0, 0.0, 0.0, 0.0])).fx()
    510.0
    """

    __slots__ = ("_data",)
    MODEL: ClassVar[int] = -1
    PARAMS: ClassVar[tuple[str, ...]] = ()
    #: Tangent dimension (GTSAM's ``Dim()``); storage is ``len(PARAMS)``.
    DIM: ClassVar[int] = 0
    _kind: ClassVar[BatchKind]

    def __new__(cls, *args: Any, **kwargs: Any):
        # a subclass's explicit GTSAM signature would raise a bare TypeError before __init__
        names, init = cls.PARAMS, cls.__init__
        required = len(names) - len(getattr(init, "__defaults__", None) or ())
        given = set(names[len(args):required]) <= kwargs.keys() <= set(names[len(args):])
        if init is not Calibration.__init__ and not (len(args) <= len(names) and given):
            try:
                inspect.signature(init).bind(None, *args, **kwargs)
            except TypeError as e:
                opt = f"[, {', '.join(names[required:])}]" if required < len(names) else ""
                raise DimensionMismatchError(
                    f"{cls.__name__}({', '.join(names[:required])}{opt}) takes "
                    f"{f'{required} to ' if opt else ''}{len(names)} parameters, got "
                    f"{len(args) + len(kwargs)}: {e}") from None
        return object.__new__(cls)

    def __init__(self, *params: float):
        names = self.PARAMS
        if len(params) != len(names):
            raise DimensionMismatchError(
                f"{type(self).__name__} takes {len(names)} parameters ({', '.join(names)}), "
                f"got {len(params)}")
        try:
            data = np.array(params, dtype=float)
        except (TypeError, ValueError):
            data = None
        # np.array turns None into NaN: report it as what it is, not as "fx is nan"
        if data is None or data.ndim != 1 or any(p is None for p in params):
            name, p = next((n, p) for n, p in zip(names, params) if number(p) is None)
            raise CalibrationError(f"{type(self).__name__}: parameter {name} must be a number, "
                                   f"got {p!r}")
        self._check(data)
        data.setflags(write=False)
        object.__setattr__(self, "_data", data)

    @classmethod
    def _check(cls, data: np.ndarray) -> None:
        bad = ~np.isfinite(data)
        if np.any(bad):
            i = int(np.nonzero(bad)[0][0])
            raise CalibrationError(f"{cls.__name__}: parameter {cls.PARAMS[i]} is {data[i]}")
        for i, name in enumerate(cls.PARAMS):
            if name in ("fx", "fy", "f") and not data[i] > 0.0:
                raise CalibrationError(
                    f"{cls.__name__}: focal length {name} must be positive, got {data[i]:g}")

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable")

    # ------------------------------------------------------------------ storage / manifold
    @classmethod
    def from_storage(cls, data: Any):
        d = np.asarray(data, dtype=float).reshape(-1)
        if d.shape[0] != len(cls.PARAMS):
            raise DimensionMismatchError(
                f"{cls.__name__}.from_storage: expected {len(cls.PARAMS)} numbers "
                f"({', '.join(cls.PARAMS)}), got {d.shape[0]}")
        return cls(*d)

    @classmethod
    def _wrap(cls, row: np.ndarray):
        obj = object.__new__(cls)
        object.__setattr__(obj, "_data", row)
        return obj

    @classmethod
    def batch_kind(cls) -> BatchKind:
        return cls._kind

    @classmethod
    def dim(cls) -> int:
        return cls.DIM

    @classmethod
    def storage_dim(cls) -> int:
        return len(cls.PARAMS)

    def to_storage(self) -> np.ndarray:
        return self._data.copy()

    def vector(self) -> np.ndarray:
        """GTSAM's ``vector()``: the ``dim`` parameters the tangent space moves."""
        return self._data[:self.DIM].copy()

    def retract(self, delta: Any):
        d = np.asarray(delta, dtype=float).reshape(-1)
        if d.shape[0] != self.DIM:
            raise DimensionMismatchError(
                f"{type(self).__name__}.retract: delta must have {self.DIM} entries, got "
                f"{d.shape[0]}")
        data = self._data.copy()
        data[:self.DIM] += d
        return type(self).from_storage(data)

    def local(self, other: Calibration) -> np.ndarray:
        if type(other) is not type(self):
            raise DimensionMismatchError(
                f"{type(self).__name__}.local: other is a {type(other).__name__}")
        return other._data[:self.DIM] - self._data[:self.DIM]

    def equals(self, other: Any, tol: float = 1e-9) -> bool:
        return type(other) is type(self) and bool(np.all(np.abs(self._data - other._data) <= tol))

    # ------------------------------------------------------------------ GTSAM accessors
    def fx(self) -> float:
        return float(self._data[0])

    def fy(self) -> float:
        return float(self._data[1])

    def skew(self) -> float:
        return float(self._data[2])

    def px(self) -> float:
        return float(self._data[3])

    def py(self) -> float:
        return float(self._data[4])

    def principal_point(self) -> np.ndarray:
        return np.array([self.px(), self.py()])

    def K(self) -> np.ndarray:
        """The 3x3 matrix of the linear (pinhole) part."""
        k5 = np.empty(5)
        CK.pinhole_part.python(self.MODEL, self._data, k5)  # five copies: no numba needed
        fx, fy, s, u0, v0 = k5
        return np.array([[fx, s, u0], [0.0, fy, v0], [0.0, 0.0, 1.0]])

    # ------------------------------------------------------------------ projection
    def uncalibrate(self, xy: Any, jacobians: bool = False):
        """Pixels of intrinsic points ``xy`` (``(2,)`` or ``(n, 2)``).

        With ``jacobians=True`` returns ``(uv, uv_D_k, uv_D_xy)`` with shapes ``(.., 2, dim)``
        and ``(.., 2, 2)``. Raises :class:`CheiralityError` where the model is undefined (the
        unified and double-sphere models outside their valid region).
        """
        pts, single = as_points2(xy, f"{type(self).__name__}.uncalibrate")
        uv, Dk, Dp, valid = specialize(CK.uncalibrate_batch, self.MODEL)(
            self._data, pts, bool(jacobians))
        if not np.all(valid):
            i = int(np.nonzero(~valid)[0][0])
            raise CheiralityError(f"{type(self).__name__}.uncalibrate: point {i} {pts[i]} is "
                                  "outside the model's valid region")
        if single:
            uv, Dk, Dp = uv[0], (Dk[0] if jacobians else Dk), (Dp[0] if jacobians else Dp)
        return (uv, Dk, Dp) if jacobians else uv

    def calibrate(self, uv: Any, jacobians: bool = False, tol: float = CALIBRATE_TOL,
                  max_iterations: int = CALIBRATE_MAX_ITERATIONS):
        """Intrinsic points of pixels ``uv`` (``(2,)`` or ``(n, 2)``), the inverse of
        :meth:`uncalibrate`: closed form for the pinhole and double-sphere models, Newton's
        method elsewhere, stopping when the re-projection is within ``tol`` pixels.

        Raises :class:`CalibrationError` naming the point when Newton does not converge in
        ``max_iterations`` or the pixel is outside the model's image; up front for a ``tol`` not
        > 0 or ``max_iterations`` < 0.
        """
        what = f"{type(self).__name__}.calibrate"
        # checked for every model (the closed forms ignore them): same arguments, same errors
        if not is_positive(tol):
            raise CalibrationError(f"{what}: tol must be a finite number of pixels > 0, got "
                                   f"{tol!r}")
        if not is_count(max_iterations):
            raise CalibrationError(f"{what}: max_iterations must be an integer >= 0, got "
                                   f"{max_iterations!r}")
        pts, single = as_points2(uv, what)
        xy, Dk, Dp, status = specialize(CK.calibrate_batch, self.MODEL)(
            self._data, pts, float(tol), int(max_iterations), bool(jacobians))
        bad = status != CK.OK
        if np.any(bad):
            i = int(np.nonzero(bad)[0][0])
            why = ("did not converge to %g pixels in %d iterations" % (tol, max_iterations)
                   if status[i] == CK.NOT_CONVERGED else "is outside the model's image")
            raise CalibrationError(f"{type(self).__name__}.calibrate: pixel {i} {pts[i]} {why}")
        if single:
            xy, Dk, Dp = xy[0], (Dk[0] if jacobians else Dk), (Dp[0] if jacobians else Dp)
        return (xy, Dk, Dp) if jacobians else xy

    def __repr__(self) -> str:
        vals = ", ".join(f"{n}={v:.6g}" for n, v in zip(self.PARAMS, self._data))
        return f"{type(self).__name__}({vals})"

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and bool(np.array_equal(self._data, other._data))

    def __hash__(self) -> int:
        return hash((type(self).__name__, self._data.tobytes()))

    def __reduce__(self):
        return (type(self).from_storage, (self._data.copy(),))


class _CalibrationOps:
    """Manifold traits of every :class:`Calibration` (registered once for the base class)."""

    def dim(self, x: Any) -> int:
        return x.DIM

    def storage_dim(self, x: Any) -> int:
        return len(x.PARAMS)

    def to_storage(self, x: Any) -> np.ndarray:
        return x.to_storage()

    def from_storage(self, like: Any, data: np.ndarray) -> Any:
        return type(like).from_storage(data)

    def retract(self, x: Any, delta: np.ndarray) -> Any:
        return x.retract(delta)

    def local(self, x: Any, y: Any) -> np.ndarray:
        return x.local(y)

    def batch_kind(self, x: Any) -> BatchKind:
        return type(x)._kind


def _make_kind(cls: type[Calibration]) -> BatchKind:
    n = len(cls.PARAMS)
    partial = cls.DIM < n  # Cal3Bundler: u0, v0 ride along unchanged
    return BatchKind(
        name=cls.__name__, dim=cls.DIM, storage_dim=n,
        retract=CK.bundler_retract if partial else CK.vector_retract,
        local=CK.bundler_local if partial else CK.vector_local,
        # optimizer output is taken as is (finite by the solvers' contract): an estimate whose
        # focal length crossed zero is returned, not turned into an error after the solve
        from_storage=lambda row, cls=cls: cls._wrap(_frozen(row)),
        to_storage=lambda x, cls=cls: _storage_of(cls, x),
        wrap=cls._wrap)


def _frozen(row: Any) -> np.ndarray:
    out = np.array(row, dtype=float)
    out.setflags(write=False)
    return out


def _storage_of(cls: type[Calibration], x: Any) -> np.ndarray:
    if type(x) is not cls:
        raise DimensionMismatchError(f"{cls.__name__} storage requested for a {type(x).__name__}")
    return x.to_storage()


def register_models(models: tuple[type[Calibration], ...]) -> None:
    """Give each model class its batch kind (the base class's manifold traits serve them all)."""
    for cls in models:
        cls._kind = _make_kind(cls)


register(Calibration, _CalibrationOps())
