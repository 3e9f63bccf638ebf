"""``triangulate(cameras, measurements, method)``: a landmark from two or more views.

* ``method="dlt"``: the linear DLT on undistorted pixels (GTSAM's ``triangulatePoint3`` with
  ``optimize=false``; same algorithm and rank rule, so the same point);
* ``method="nonlinear"``: the DLT point refined by Levenberg-Marquardt on the reprojection
  error ``0.5 sum_i |project_i(X) - z_i|^2`` (GTSAM's ``optimize=true``, which stops at an
  absolute error decrease of 1.0; fgopt iterates to convergence).

Checks: fewer than two views, a rank-deficient system (``rank < 3`` singular values above
``rank_tol``, e.g. all rays parallel), a point at infinity or a pixel that cannot be undistorted
raise :class:`~fgopt.errors.TriangulationError`; a result at or behind any camera raises
:class:`~fgopt.errors.CheiralityError` naming the view (GTSAM built with
``GTSAM_THROW_CHEIRALITY_EXCEPTION``).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .._jit import specialize
from ..errors import (CalibrationError, CheiralityError, DimensionMismatchError, FgoptError,
                      NonFiniteError, TriangulationError)
from . import _triangulation_kernels as TK
from .._checks import float_array, is_count, is_positive
from .camera import PinholeCamera

METHODS = ("dlt", "nonlinear")
#: ``TK.dlt``'s codes below any rank.
TK_UNDISTORT_FAILED, TK_AT_INFINITY = -1, -2
#: The tolerance and iteration limit ``TK.undistort`` gives ``calibrate``.
_UNDISTORT_TOL, _UNDISTORT_ITERATIONS = 1e-10, 20


def _undistort_failure(cams: list, z: np.ndarray) -> str:
    """Which measurement the DLT kernel could not undistort, and why (found again in Python: the
    kernel reports only that one failed)."""
    for i, c in enumerate(cams):
        try:
            c.calibration().calibrate(z[i], tol=_UNDISTORT_TOL,
                                      max_iterations=_UNDISTORT_ITERATIONS)
        except CalibrationError as e:
            return f"measurement {i} {z[i]} cannot be undistorted: {e}"
    return "a measurement cannot be undistorted (its calibration's calibrate failed)"


def triangulate(cameras: Sequence[PinholeCamera], measurements: Any, method: str = "dlt",
                rank_tol: float = 1e-9, max_iterations: int = 100) -> np.ndarray:
    """World point seen at pixels ``measurements (m, 2)`` by ``cameras`` (``m >= 2``
    :class:`PinholeCamera`, all with the same calibration model; calibrations may differ).

    Args:
        method: ``"dlt"`` or ``"nonlinear"`` (see the module docstring).
        rank_tol: singular values of the DLT system above this count toward its rank (GTSAM's
            ``rank_tol``, in pixel units); > 0, as with 0 rounding noise counts as rank.
        max_iterations: limit of the nonlinear refinement (>= 0).

    Example:

    >>> from fgopt import SE3
    >>> from fgopt.cameras import Cal3_S2, PinholeCamera, triangulate
    >>> K = Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)
    >>> cams = [PinholeCamera(SE3(translation=[x, 0.0, 0.0]), K) for x in (0.0, 1.0)]
    >>> X = np.array([0.5, 0.2, 4.0])
    >>> np.round(triangulate(cams, [c.project(X) for c in cams]), 6)
    array([0.5, 0.2, 4. ])
    """
    if not isinstance(method, str) or method not in METHODS:
        raise FgoptError(f"triangulate: method must be one of {METHODS}, got {method!r}")
    if not is_positive(rank_tol):
        raise FgoptError(f"triangulate: rank_tol must be a finite number > 0, got {rank_tol!r}")
    if not is_count(max_iterations):
        raise FgoptError(f"triangulate: max_iterations must be an integer >= 0, got "
                         f"{max_iterations!r}")
    if isinstance(cameras, (PinholeCamera, str, bytes)) or not hasattr(cameras, "__iter__"):
        raise FgoptError(f"triangulate: cameras must be a sequence of PinholeCamera, got "
                         f"{type(cameras).__name__}")
    cams = list(cameras)
    z = np.ascontiguousarray(float_array(measurements, "triangulate: measurements",
                                         f"a ({len(cams)}, 2) array of numbers"))
    if z.ndim != 2 or z.shape[1] != 2 or z.shape[0] != len(cams):
        raise DimensionMismatchError(
            f"triangulate: measurements must be ({len(cams)}, 2) for {len(cams)} cameras, got "
            f"{z.shape}")
    if len(cams) < 2:
        raise TriangulationError(f"triangulate: needs at least two views, got {len(cams)}")
    bad = ~np.all(np.isfinite(z), axis=1)
    if np.any(bad):
        i = int(np.nonzero(bad)[0][0])
        raise NonFiniteError(f"triangulate: measurement {i} has a NaN or inf: {z[i]}")
    for i, c in enumerate(cams):
        if not isinstance(c, PinholeCamera):
            raise FgoptError(f"triangulate: camera {i} is a {type(c).__name__}, not a "
                             "PinholeCamera")
    model = type(cams[0].calibration())
    if any(type(c.calibration()) is not model for c in cams):
        raise FgoptError("triangulate: all cameras must share one calibration model "
                         f"(camera 0 has {model.__name__})")
    Rs = np.ascontiguousarray([c._R for c in cams])
    ts = np.ascontiguousarray([c.pose().translation() for c in cams])
    ks = np.ascontiguousarray([c.calibration()._data for c in cams])
    X = np.empty(3)
    rank = specialize(TK.dlt, model.MODEL)(Rs, ts, ks, z, float(rank_tol), X)
    if rank == TK_UNDISTORT_FAILED:
        raise TriangulationError(f"triangulate: {_undistort_failure(cams, z)}")
    if rank == TK_AT_INFINITY:
        raise TriangulationError("triangulate: the DLT point is at infinity (parallel rays)")
    if rank < 3:
        raise TriangulationError(
            f"triangulate: the DLT system has rank {rank} < 3 (rank_tol {rank_tol:g}): "
            "the views' rays are (nearly) parallel or coincide")
    view = TK.in_front(Rs, ts, X)
    if view >= 0:
        raise CheiralityError(f"triangulate: the DLT point {X} is at or behind camera {view}")
    if method == "nonlinear":
        specialize(TK.refine, model.MODEL)(Rs, ts, ks, z, X, int(max_iterations))
    return X
