"""IMU and GPS factors (GTSAM's ``ImuFactor``, ``CombinedImuFactor``, ``GPSFactor``), batched.

Variables: SE(3) poses (``world_T_body``), 3-vector world-frame velocities and 6-vector biases
``[accelerometer, gyroscope]`` (:class:`~fgopt.navigation.ImuBias` values or plain arrays). Every
factor of one type shares one numba kernel (:mod:`fgopt.navigation._imu_kernels`), so the
compiled problem linearizes all IMU factors of a graph in one call. Noise models come from the
preintegration covariance in the residual's chart (GTSAM's ``residualCovariance``).

``evaluate_error(*values, pim)`` (classmethod) is GTSAM's ``evaluateError``: the unwhitened
residual at the given values, with the bias as its 6-vector.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np

from ..errors import (DimensionMismatchError, FgoptError, ManifoldError, NonFiniteError,
                      NotPositiveDefiniteError)
from ..factors import FactorKernel, KernelFactor
from ..key import Key, key_str
from ..manifolds import SE3
from ..manifolds.base import vector_kind
from ..noise import Gaussian
from ..noise._keyword import UNSET, loss_argument
from ..symbolic.runtime import kernel_array
from . import _imu_kernels as IK
from .bias import ImuBias
from .preintegration import PreintegratedCombinedImu, PreintegratedImu

_SOURCE = "hand-written in fgopt/navigation/_imu_kernels.py"


def _prepared(name: str, args: tuple, consts: np.ndarray, dims: tuple, nconst: int) -> list:
    if len(args) != len(dims):
        raise DimensionMismatchError(f"{name}: expected {len(dims)} argument arrays, got "
                                     f"{len(args)}")
    c = kernel_array(consts)
    n = c.shape[0] if c.ndim == 2 else -1
    arrs = [kernel_array(a) for a in args]
    if c.shape != (n, nconst) or any(a.shape != (n, d) for a, d in zip(arrs, dims)):
        raise DimensionMismatchError(
            f"{name}: expected argument arrays {[(n, d) for d in dims]} and constants "
            f"({n}, {nconst}); got {[a.shape for a in arrs]} and {c.shape}")
    return arrs + [c]


@cache
def imu_kernel() -> FactorKernel:
    """The kernel of :class:`ImuFactor`: args (pose_i, vel_i, pose_j, vel_j, bias_i)."""
    dims = (7, 3, 7, 3, 6)

    def run(args, consts, with_jac):
        return IK.imu_batch(*_prepared("imu_factor", args, consts, dims, IK.PIM_CONSTANTS),
                            with_jac)

    se3, r3, r6 = SE3.batch_kind(), vector_kind(3), vector_kind(6)
    return FactorKernel("imu_factor", (se3, r3, se3, r3, r6), 9, IK.PIM_CONSTANTS,
                        residual=lambda args, consts: run(args, consts, False)[0],
                        linearize=lambda args, consts: run(args, consts, True), source=_SOURCE,
                        recipe=(imu_kernel, ()),
                        trusted_linearize=lambda args, consts: IK.imu_batch(*args, consts, True))


@cache
def combined_imu_kernel() -> FactorKernel:
    """The kernel of :class:`CombinedImuFactor`: args (pose_i, vel_i, pose_j, vel_j, bias_i,
    bias_j)."""
    dims = (7, 3, 7, 3, 6, 6)

    def run(args, consts, with_jac):
        return IK.combined_batch(
            *_prepared("combined_imu_factor", args, consts, dims, IK.PIM_CONSTANTS), with_jac)

    se3, r3, r6 = SE3.batch_kind(), vector_kind(3), vector_kind(6)
    return FactorKernel("combined_imu_factor", (se3, r3, se3, r3, r6, r6), 15, IK.PIM_CONSTANTS,
                        residual=lambda args, consts: run(args, consts, False)[0],
                        linearize=lambda args, consts: run(args, consts, True), source=_SOURCE,
                        recipe=(combined_imu_kernel, ()),
                        trusted_linearize=lambda args, consts: IK.combined_batch(*args, consts,
                                                                                 True))


@cache
def gps_kernel() -> FactorKernel:
    """The kernel of :class:`GpsFactor`: arg (pose,), constants ``[position, lever_arm]``."""

    def run(args, consts, with_jac):
        return IK.gps_batch(*_prepared("gps_factor", args, consts, (7,), 6), with_jac)

    return FactorKernel("gps_factor", (SE3.batch_kind(),), 3, 6,
                        residual=lambda args, consts: run(args, consts, False)[0],
                        linearize=lambda args, consts: run(args, consts, True), source=_SOURCE,
                        recipe=(gps_kernel, ()),
                        trusted_linearize=lambda args, consts: IK.gps_batch(args[0], consts, True))


def _pim_noise(pim: PreintegratedImu, who: str, keys: tuple, predicted_attitude: Any) -> Gaussian:
    if pim.delta_t <= 0.0:
        raise FgoptError(f"{who}({', '.join(key_str(Key(k)) for k in keys)}): the "
                         "preintegration is empty; integrate IMU samples first")
    try:
        return Gaussian.from_covariance(pim.residual_covariance_at(predicted_attitude))
    except NotPositiveDefiniteError as exc:
        raise NotPositiveDefiniteError(
            f"{who}({', '.join(key_str(Key(k)) for k in keys)}): the preintegrated covariance "
            f"is not positive definite ({exc}); check the IMU noise parameters") from None


def _storages(values: tuple, kinds: tuple, names: tuple, who: str) -> tuple:
    """Numeric values (SE3 poses, vectors, ImuBias) as ``(1, s)`` storage rows."""
    rows = []
    for v, kind, name in zip(values, kinds, names):
        if kind is SE3.batch_kind():
            if not isinstance(v, SE3):
                raise ManifoldError(f"{who}: {name} must be an fgopt SE3, got {type(v).__name__}")
            rows.append(v.to_storage().reshape(1, -1))
        else:
            what = f"{who}: {name}"
            vec = ImuBias.as_vector(v, what) if kind.dim == 6 else \
                np.asarray(v, dtype=float).reshape(-1)
            if vec.shape[0] != kind.dim:
                raise DimensionMismatchError(f"{what} needs {kind.dim} numbers, got "
                                             f"{vec.shape[0]}")
            rows.append(vec.reshape(1, -1))
    return tuple(rows)


class ImuFactor(KernelFactor):
    """``ImuFactor(pose_i, vel_i, pose_j, vel_j, bias_i, pim, predicted_attitude=None)``: the
    preintegrated IMU samples between states i and j (GTSAM's 5-variable ImuFactor). 9 residuals
    ``[rotation, position, velocity]`` in the chart of ``pim.params.error_mode``; noise
    ``pim.residual_covariance_at(predicted_attitude)`` (the attitude matters only with Coriolis,
    as GTSAM's constructor argument).

    Example:

    >>> from fgopt.navigation import ImuBias, ImuFactor, PreintegratedImu, PreintegrationParams
    >>> pim = PreintegratedImu(PreintegrationParams.make_u(9.81), ImuBias())
    >>> pim = pim.integrate(np.tile([0.0, 0.0, 9.81], (10, 1)), np.zeros((10, 3)), 0.01)
    >>> f = ImuFactor(key('x', 0), key('v', 0), key('x', 1), key('v', 1), key('b', 0), pim)
    >>> f.keys
    (x0, v0, x1, v1, b0)
    """

    _NAMES = ("pose_i", "vel_i", "pose_j", "vel_j", "bias_i")

    def __init__(self, pose_i: int, vel_i: int, pose_j: int, vel_j: int, bias_i: int,
                 pim: PreintegratedImu, predicted_attitude: Any = None):
        keys = (pose_i, vel_i, pose_j, vel_j, bias_i)
        self._check_pim(pim, keys)
        self.preintegrated = pim.copy()
        super().__init__(imu_kernel(), keys, pim.constants(),
                         _pim_noise(pim, type(self).__name__, keys, predicted_attitude))

    @classmethod
    def _check_pim(cls, pim: Any, keys: tuple) -> None:
        if not isinstance(pim, PreintegratedImu) or isinstance(pim, PreintegratedCombinedImu):
            raise FgoptError(f"{cls.__name__}: pim must be a PreintegratedImu, got "
                             f"{type(pim).__name__}")

    @classmethod
    def evaluate_error(cls, pose_i: SE3, vel_i: Any, pose_j: SE3, vel_j: Any, bias_i: Any,
                       pim: PreintegratedImu) -> np.ndarray:
        """The unwhitened residual (GTSAM's ``evaluateError``) at these values."""
        cls._check_pim(pim, ())
        kernel = imu_kernel()
        args = _storages((pose_i, vel_i, pose_j, vel_j, bias_i), kernel.arg_kinds, cls._NAMES,
                         f"{cls.__name__}.evaluate_error")
        return kernel.residual(args, pim.constants().reshape(1, -1))[0].copy()

    def describe(self) -> str:
        keys = ", ".join(key_str(k) for k in self.keys) if hasattr(self, "keys") else "?"
        return f"{type(self).__name__}({keys})"


class CombinedImuFactor(ImuFactor):
    """``CombinedImuFactor(pose_i, vel_i, pose_j, vel_j, bias_i, bias_j, pim)``: as
    :class:`ImuFactor` plus the bias random walk ``bias_i - bias_j`` (GTSAM's sign); 15
    residuals with the
    15x15 covariance of a :class:`PreintegratedCombinedImu`.

    Example: one second at rest; the state is consistent, only the bias moved:

    >>> from fgopt import SE3
    >>> from fgopt.navigation import (CombinedImuFactor, ImuBias, PreintegratedCombinedImu,
    ...                               PreintegrationParams)
    >>> params = PreintegrationParams.make_u(9.81, bias_acc_rw_sigma=0.01, bias_gyro_rw_sigma=0.001)
    >>> pim = PreintegratedCombinedImu(params, ImuBias())
    >>> pim = pim.integrate(np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.01)
    >>> f = CombinedImuFactor(key('x', 0), key('v', 0), key('x', 1), key('v', 1), key('b', 0),
    ...                       key('b', 1), pim)
    >>> values = fgopt.Variables({key('x', 0): SE3(), key('v', 0): np.zeros(3), key('x', 1): SE3(),
    ...                           key('v', 1): np.zeros(3), key('b', 0): ImuBias(),
    ...                           key('b', 1): ImuBias([0.01, 0.0, 0.0], [0.0, 0.0, 0.0])})
    >>> e = np.round(f.error(values), 9) + 0.0
    >>> e[:9], e[9:]                            # [rotation, position, velocity], bias_i - bias_j
    (array([0., 0., 0., 0., 0., 0., 0., 0., 0.]), array([-0.01,  0.  ,  0.  ,  0.  ,  0.  ,  0.  ]))
    """

    _NAMES = ("pose_i", "vel_i", "pose_j", "vel_j", "bias_i", "bias_j")

    def __init__(self, pose_i: int, vel_i: int, pose_j: int, vel_j: int, bias_i: int,
                 bias_j: int, pim: PreintegratedCombinedImu, predicted_attitude: Any = None):
        keys = (pose_i, vel_i, pose_j, vel_j, bias_i, bias_j)
        self._check_pim(pim, keys)
        self.preintegrated = pim.copy()
        KernelFactor.__init__(self, combined_imu_kernel(), keys, pim.constants(),
                              _pim_noise(pim, type(self).__name__, keys, predicted_attitude))

    @classmethod
    def _check_pim(cls, pim: Any, keys: tuple) -> None:
        if not isinstance(pim, PreintegratedCombinedImu):
            raise FgoptError(f"{cls.__name__}: pim must be a PreintegratedCombinedImu, got "
                             f"{type(pim).__name__}")

    @classmethod
    def evaluate_error(cls, pose_i: SE3, vel_i: Any, pose_j: SE3, vel_j: Any, bias_i: Any,
                       bias_j: Any, pim: PreintegratedCombinedImu) -> np.ndarray:
        """The unwhitened 15-residual (GTSAM's ``evaluateError``) at these values."""
        cls._check_pim(pim, ())
        kernel = combined_imu_kernel()
        args = _storages((pose_i, vel_i, pose_j, vel_j, bias_i, bias_j), kernel.arg_kinds,
                         cls._NAMES, f"{cls.__name__}.evaluate_error")
        return kernel.residual(args, pim.constants().reshape(1, -1))[0].copy()


class GpsFactor(KernelFactor):
    """``GpsFactor(pose, position, loss, lever_arm=None)``: a position fix of the antenna at
    ``lever_arm`` (body frame; default the body origin), GTSAM's ``GPSFactor`` /
    ``GPSFactorArm``: residual ``t + R lever_arm - position`` (3 rows, world frame).

    Example:

    >>> from fgopt import SE3
    >>> from fgopt.navigation import GpsFactor
    >>> from fgopt.noise import Isotropic
    >>> f = GpsFactor(key('x', 0), [1.0, 2.0, 3.0], Isotropic.sigma(3, 1.0), lever_arm=[0.0, 0.0, 0.5])
    >>> np.round(f.error(fgopt.Variables().add(key('x', 0), SE3(translation=[1.0, 2.0, 2.5]))), 6)
    array([0., 0., 0.])
    """

    def __init__(self, pose: int, position: Any, loss: Any = None, lever_arm: Any = None, *,
                 noise: Any = UNSET):
        loss = loss_argument(loss, noise, "GpsFactor")
        if loss is None:
            raise FgoptError("GpsFactor: pass the position's noise model as loss= (3-D)")
        super().__init__(gps_kernel(), (pose,), self._constants(position, lever_arm), loss)

    @staticmethod
    def _constants(position: Any, lever_arm: Any) -> np.ndarray:
        c = np.zeros(6)
        m = np.asarray(position, dtype=float).reshape(-1)
        if m.shape[0] != 3:
            raise DimensionMismatchError(f"GpsFactor: position needs 3 numbers, got {m.shape[0]}")
        if not np.all(np.isfinite(m)):
            raise NonFiniteError(f"GpsFactor: position has a NaN or inf: {m}")
        c[:3] = m
        if lever_arm is not None:
            arm = np.asarray(lever_arm, dtype=float).reshape(-1)
            if arm.shape[0] != 3:
                raise DimensionMismatchError(f"GpsFactor: lever_arm needs 3 numbers, got "
                                             f"{arm.shape[0]}")
            if not np.all(np.isfinite(arm)):
                raise NonFiniteError(f"GpsFactor: lever_arm has a NaN or inf: {arm}")
            c[3:] = arm
        return c

    @property
    def position(self) -> np.ndarray:
        return self.constants[:3].copy()

    @property
    def lever_arm(self) -> np.ndarray:
        return self.constants[3:].copy()

    @classmethod
    def evaluate_error(cls, pose: SE3, position: Any, lever_arm: Any = None) -> np.ndarray:
        """``t + R lever_arm - position`` (GTSAM's ``evaluateError``)."""
        if not isinstance(pose, SE3):
            raise ManifoldError(f"GpsFactor.evaluate_error: pose must be an fgopt SE3, got "
                                f"{type(pose).__name__}")
        c = cls._constants(position, lever_arm)
        return gps_kernel().residual((pose.to_storage().reshape(1, -1),), c.reshape(1, -1))[0]

    def describe(self) -> str:
        return f"GpsFactor({key_str(self.keys[0])})" if hasattr(self, "keys") else "GpsFactor"
