"""``SmartProjectionFactor(pose_keys, measurements, calibration, loss)``: a landmark track whose
point is eliminated inside the factor (GTSAM's ``SmartProjectionPoseFactor``).

The factor's variables are only the poses (``world_T_camera``, z forward) that saw the landmark;
the calibration is a constant shared by the track. At every evaluation the landmark is
triangulated from the current poses (DLT with GTSAM's smart-factor rank tolerance 1.0, or
``triangulation="nonlinear"`` to refine it) and eliminated by the Schur complement, returned as
an ordinary residual / Jacobian pair whose ``J^T J``, ``J^T r`` and ``0.5 |r|^2`` are GTSAM's
Hessian factor and error (see :mod:`fgopt.cameras._smart_kernels`). So a smart factor batches
and solves like any kernel factor: one numba call per track length. Inside the optimizer the
kernel adds its Schur complement blocks to H directly (``FactorKernel.scatter_hessian``: the same
sums from the block-diagonal pose Jacobians; 8 tracks of 8 views: 38 us instead of 42 us for the
residual / Jacobian and 44 us for the dense ``J^T J`` scatter).

Degenerate-track policy (``degenerate=``):

* a track with fewer than two views, or a NaN / inf pixel, is rejected at construction
  (:class:`~fgopt.errors.TriangulationError` / :class:`~fgopt.errors.NonFiniteError` naming the
  factor and index);
* ``"reject"`` (default): when the landmark cannot be triangulated at some estimate (DLT rank
  < 3 -- parallel rays, e.g. pure rotation --, the point behind a view, or its Jacobian
  rank-deficient), the residual is NaN: a trial step that causes it is rejected, and an initial
  estimate that causes it makes ``optimize`` raise naming the factor;
* ``"zero"``: the factor contributes nothing there (zero residual and Jacobian; GTSAM's
  ``ZERO_ON_DEGENERACY``). GTSAM's default ``IGNORE_DEGENERACY`` reports error 0 but still
  linearizes towards a point at infinity; fgopt does not mix the two.

The policy is one of the factor's constants (run-time data of the kernel), so tracks of both
policies share a kernel: one batch, one compile, one small-problem driver.

The noise model is per pixel (2-D, any Gaussian); robust losses are not supported (GTSAM's smart
factors have none either).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, Sequence

import numpy as np

from .._jit import specialize
from ..errors import DimensionMismatchError, FgoptError, NonFiniteError, TriangulationError
from ..factors import FactorKernel
from ..factors.kernel import CompiledCall
from ..noise import NoiseModel, RobustLoss, Unit
from ..key import as_key, key_str
from ..noise._keyword import UNSET, loss_argument
from ..manifolds import SE3
from . import _smart_kernels as SK
from .._checks import float_array, is_positive
from .calibration import Calibration
from .factors import CameraKernelFactor

TRIANGULATION = ("dlt", "nonlinear")
DEGENERATE = ("reject", "zero")
_SOURCE = "hand-written in fgopt/cameras/_smart_kernels.py"
_HINT = ("a smart factor's landmark cannot be triangulated at this estimate (parallel rays, a "
         "point behind a camera, a rank-deficient track, or a pixel its calibration cannot "
         "undistort); fix the initial poses or use degenerate='zero'")


@lru_cache(maxsize=None)
def smart_kernel(model: type[Calibration], num_views: int,
                 triangulation: str = "dlt") -> FactorKernel:
    """Kernel of smart factors with ``num_views`` poses: args ``(SE3,) * m``, constants
    ``(pixels (2m), calibration storage, sqrt information (4, row major), rank tolerance,
    degenerate policy)``, the policy ``0.0`` for ``"reject"`` (NaN where the track is degenerate)
    or ``1.0`` for ``"zero"`` (:class:`SmartProjectionFactor`'s ``degenerate``).

    Example: two cameras 1 m apart; when their pixels disagree by 2 pixels in ``v``, the
    point triangulated inside the kernel leaves 1 pixel in each view:

    >>> from fgopt import SE3
    >>> from fgopt.cameras import Cal3_S2, smart_kernel
    >>> K = Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)
    >>> kernel = smart_kernel(Cal3_S2, 2)
    >>> poses = (SE3().to_storage()[None], SE3(translation=[1.0, 0.0, 0.0]).to_storage()[None])
    >>> consts = np.array([[370.0, 140.0, 120.0, 142.0, *K.to_storage(), 1.0, 0.0, 0.0, 1.0, 1e-9,
    ...                     0.0]])
    >>> round(float(np.linalg.norm(kernel.residual(poses, consts))), 3)   # sqrt(1 + 1)
    1.414
    """
    if triangulation not in TRIANGULATION:
        raise FgoptError(f"triangulation must be one of {TRIANGULATION}, got {triangulation!r}")
    m, s, mid = int(num_views), len(model.PARAMS), model.MODEL
    nc = 2 * m + s + 6
    refine = triangulation == "nonlinear"
    name = f"smart_{model.__name__.lower()}_{m}views"
    batch, hessian = specialize(SK.smart_batch, mid), specialize(SK.smart_hessian_batch, mid)

    def run(args, consts, with_jac):
        if len(args) != m:
            raise DimensionMismatchError(f"{name}: expected {m} pose arrays, got {len(args)}")
        P = np.ascontiguousarray(np.stack([np.asarray(a, dtype=np.float64) for a in args],
                                          axis=1))
        c = np.ascontiguousarray(consts, dtype=np.float64)
        if P.ndim != 3 or P.shape[1:] != (m, 7) or c.shape != (P.shape[0], nc):
            raise DimensionMismatchError(f"{name}: expected poses (n, 7) x {m} and constants "
                                         f"(n, {nc}); got {P.shape}, {c.shape}")
        return batch(P, c, m, s, refine, with_jac)

    return FactorKernel(name, (SE3.batch_kind(),) * m, 2 * m, nc,
                        residual=lambda args, consts: run(args, consts, False)[0],
                        linearize=lambda args, consts: run(args, consts, True),
                        source=_SOURCE, nonfinite_hint=_HINT,
                        recipe=(smart_kernel, (model, m, triangulation)),
                        trusted_linearize=lambda args, consts: batch(
                            np.stack(args, axis=1), consts, m, s, refine, True),
                        # every argument is an SE3 pose: one storage for all
                        scatter_hessian=lambda st, rows, consts, toff, pos, shift, H, g, w, cost:
                        hessian(st[0], rows, consts, m, s, refine, toff, pos, shift, H, g, w,
                                cost),
                        # the same sums from a small-problem driver (fgopt.solvers.small)
                        # (run-time sizes and flags, the model's specialized copy: the
                        # general path's machine code, one compile for every track length;
                        # the degenerate policy is in consts: one driver for both)
                        compiled_call=CompiledCall(
                            SK.__name__, "smart_dense_batch", prefix=f"np.int64({mid}), ",
                            suffix=f", np.int64({m}), np.int64({s}), np.bool_({refine})",
                            hessian=True, specialized=mid))


class SmartProjectionFactor(CameraKernelFactor):
    """A landmark track over camera poses, the landmark eliminated (see the module docstring).

    Args:
        pose_keys: keys of the ``m >= 2`` SE3 poses that observed the landmark.
        measurements: ``(m, 2)`` pixels, one per pose.
        calibration: the shared constant :class:`~fgopt.cameras.Calibration`.
        loss: a 2-D noise model per pixel (``None``: unit); ``noise=`` is a deprecated alias.
        triangulation: ``"dlt"`` (GTSAM's default) or ``"nonlinear"``.
        degenerate: ``"reject"`` or ``"zero"``.
        rank_tol: DLT rank tolerance (GTSAM's smart-factor default 1.0, in pixels), > 0.

    Example:

    >>> scene = fgopt.datasets.sfm_cube(smart=True)
    >>> result = fgopt.optimize(scene.graph, scene.initial)
    >>> result.success
    True
    """

    def __init__(self, pose_keys: Sequence[int], measurements: Any, calibration: Calibration,
                 loss: NoiseModel | None = None, *, triangulation: str = "dlt",
                 degenerate: str = "reject", rank_tol: float = 1.0, noise: Any = UNSET):
        if isinstance(pose_keys, (str, bytes)) or not hasattr(pose_keys, "__iter__"):
            raise FgoptError(f"SmartProjectionFactor: pose_keys must be a list of pose keys, got "
                             f"{pose_keys!r}")
        keys = [as_key(k) for k in pose_keys]
        where = f"SmartProjectionFactor({', '.join(key_str(k) for k in keys)})"
        m = len(keys)
        if m < 2:
            raise TriangulationError(f"{where}: a track needs at least two views, got {m}")
        z = float_array(measurements, f"{where}: measurements", f"an ({m}, 2) array of numbers")
        if z.shape != (m, 2):
            raise DimensionMismatchError(f"{where}: measurements must be ({m}, 2), got {z.shape}")
        bad = ~np.all(np.isfinite(z), axis=1)
        if np.any(bad):
            i = int(np.nonzero(bad)[0][0])
            raise NonFiniteError(f"{where}: measurement {i} (of {key_str(keys[i])}) has a NaN "
                                 f"or inf: {z[i]}")
        if not isinstance(calibration, Calibration):
            raise FgoptError(f"{where}: calibration must be a constant Calibration, got "
                             f"{type(calibration).__name__}")
        noise = loss_argument(loss, noise, where)
        if isinstance(noise, RobustLoss):
            raise FgoptError(f"{where}: robust losses are not supported on smart factors")
        noise = Unit(2) if noise is None else noise
        if not isinstance(noise, NoiseModel) or noise.dim != 2:
            raise DimensionMismatchError(f"{where}: loss must be a 2-D noise model (per pixel)")
        # with 0 the rounding noise of a zero-baseline track counts toward the DLT's rank
        if not is_positive(rank_tol):
            raise FgoptError(f"{where}: rank_tol must be a finite number > 0, got {rank_tol!r}")
        tol = float(rank_tol)
        if degenerate not in DEGENERATE:
            raise FgoptError(f"{where}: degenerate must be one of {DEGENERATE}, got "
                             f"{degenerate!r}")
        self.measured = z.copy()
        self.calibration = calibration
        self.pixel_noise = noise
        self.triangulation = triangulation
        consts = np.concatenate([z.reshape(-1), calibration._data,
                                 np.asarray(noise.sqrt_information).reshape(-1),
                                 [tol, float(degenerate == "zero")]])
        self._rank_tol = tol
        super().__init__(smart_kernel(type(calibration), m, triangulation), keys, consts,
                         Unit(2 * m))

    def point(self, values: Any) -> np.ndarray | None:
        """The landmark triangulated from the poses in ``values``, or ``None`` if degenerate."""
        # _gather checks every value is an SE3, as error() does
        rows = np.ascontiguousarray(np.concatenate(self._gather(values), axis=0))
        X, ok = specialize(SK.smart_point, self.calibration.MODEL)(
            rows, self.calibration._data, np.ascontiguousarray(self.measured), self._rank_tol,
            self.triangulation == "nonlinear")
        return X if ok else None

    def describe(self) -> str:
        keys = ", ".join(key_str(k) for k in self.keys) if hasattr(self, "keys") else "?"
        return f"SmartProjectionFactor({keys})"
