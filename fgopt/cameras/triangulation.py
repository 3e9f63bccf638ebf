"""``triangulate(cameras, measurements, method)``: a landmark from two or more views.

* ``method="dlt"``: the linear DLT on undistorted pixels (GTSAM's ``triangulatePoint3`` with
  ``optimize=false``; same algorithm and rank rule, so the same point);
* ``method="nonlinear"``: the DLT point refined by Levenberg-Marquardt on the reprojection
  error ``0.5 sum_i |project_i(X) - z_i|^2`` (GTSAM's ``optimize=true``, which stops at an
  absolute error decrease of 1.0; fgopt iterates to convergence).

Checks: fewer than two views or a rank-deficient system (``rank < 3`` singular values above
``rank_tol``, e.g. all rays parallel) raise :class:`~fgopt.errors.TriangulationError`; a result
at or behind any camera raises :class:`~fgopt.errors.CheiralityError` naming the view (GTSAM
built with ``GTSAM_THROW_CHEIRALITY_EXCEPTION``).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..errors import (CheiralityError, DimensionMismatchError, FgoptError, NonFiniteError,
                      TriangulationError)
from . import _triangulation_kernels as TK
from .camera import PinholeCamera

METHODS = ("dlt", "nonlinear")


def triangulate(cameras: Sequence[PinholeCamera], measurements: Any, method: str = "dlt",
                rank_tol: float = 1e-9, max_iterations: int = 100) -> np.ndarray:
    """World point seen at pixels ``measurements (m, 2)`` by ``cameras`` (``m >= 2``
    :class:`PinholeCamera`, all with the same calibration model; calibrations may differ).

    Args:
        method: ``"dlt"`` or ``"nonlinear"`` (see the module docstring).
        rank_tol: singular values of the DLT system above this count toward its rank (GTSAM's
            ``rank_tol``, in pixel units).
        max_iterations: limit of the nonlinear refinement.
    """
    if method not in METHODS:
        raise FgoptError(f"triangulate: method must be one of {METHODS}, got {method!r}")
    cams = list(cameras)
    z = np.ascontiguousarray(np.asarray(measurements, dtype=float))
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
    rank = TK.dlt(model.MODEL, Rs, ts, ks, z, float(rank_tol), X)
    if rank == -1:
        raise TriangulationError("triangulate: a measurement cannot be undistorted (calibrate "
                                 "failed)")
    if rank < 3:
        raise TriangulationError(
            f"triangulate: the DLT system has rank {max(rank, 0)} < 3 (rank_tol {rank_tol:g}): "
            "the views' rays are (nearly) parallel or coincide")
    view = TK.in_front(Rs, ts, X)
    if view >= 0:
        raise CheiralityError(f"triangulate: the DLT point {X} is behind camera {view}")
    if method == "nonlinear":
        TK.refine(model.MODEL, Rs, ts, ks, z, X, int(max_iterations))
    return X
