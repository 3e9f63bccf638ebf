"""Projection and stereo factors, batched by hand-written numba kernels.

* ``ProjectionFactor(pose, point, measured, loss, calibration)``: ``e = uv - measured`` with
  ``uv = PinholeCamera(pose, K).project(point)`` (GTSAM's ``GenericProjectionFactor`` when the
  calibration is a constant, ``GeneralSFMFactor2`` when it is a key: self-calibration, then
  ``model=`` names the calibration class). Every calibration model of :mod:`.calibration`.
* ``GeneralSFMFactor(camera, point, measured, loss, model=...)``: the same residual with one
  :class:`~fgopt.cameras.PinholeCamera` variable holding pose and calibration (GTSAM's
  ``GeneralSFMFactor``; the form BAL / Bundler problems are solved in).
* ``StereoFactor(pose, point, measured, loss, calibration)``: ``e = (uL, uR, v) - measured``
  with a ``Cal3_S2Stereo`` (GTSAM's ``GenericStereoFactor<Pose3, Point3>``).

Kernels: one :class:`~fgopt.factors.kernel.FactorKernel` per (model, calibration constant or
variable, cheirality policy), cached, so all such factors in a graph are linearized by one numba
call (:mod:`fgopt.cameras._projection_kernels`). Jacobian columns: pose ``[w, v]`` (right
perturbation), point, then the calibration's tangent.

Cheirality policy (``cheirality=``):

* ``"reject"`` (default): a point at or behind the camera (``p_z <= 0``), or outside a lens
  model's valid region, makes the residual NaN. Inside the optimizer a trial step that does this
  is rejected like any non-finite step (LM raises its damping and tries a shorter step); at the
  initial estimate ``optimize`` raises :class:`~fgopt.errors.NonFiniteError` naming the factor
  (and ``graph.error`` is NaN). Never a silent stand-in residual (GTSAM returns ``2 fx`` with
  zero Jacobians, unless ``throwCheirality``).
* ``"allow"``: project points behind the camera with the same formula (the BAL / Ceres
  convention: their cost counts such observations); only ``p_z = 0`` is undefined. The BAL and
  Bundler readers use it so the Pose3 form reaches the 9-vector form's cost.

Where the residual is NaN, a factor's own ``jacobians(values)`` is NaN too (never a zero
Jacobian passed off as valid), and ``checked_error`` / ``checked_jacobians`` / ``cost`` raise
:class:`~fgopt.errors.NonFiniteError` naming the factor with the optimizer's hint.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from .._jit import specialize
from ..errors import DimensionMismatchError, FgoptError, NonFiniteError
from ..factors import FactorKernel, KernelFactor
from ..key import as_key, key_str
from ..manifolds import SE3
from ..manifolds.base import vector_kind
from ..noise._keyword import UNSET, loss_argument
from ..symbolic.runtime import kernel_array
from . import _projection_kernels as PK
from .._checks import float_array
from .calibration import Cal3_S2Stereo, Calibration

CHEIRALITY = ("reject", "allow")
_SOURCE = "hand-written in fgopt/cameras/_projection_kernels.py"


def nonfinite_hint(reject: bool, lens: bool = True) -> str:
    """Why a projection kernel's residual is NaN, for the optimizer's error: ``reject`` its
    cheirality policy, ``lens`` whether the model has a valid region (not stereo)."""
    region = " or is outside the lens model's valid region" if lens else ""
    if not reject:
        # cheirality='allow' leaves only depth exactly 0 undefined: suggesting it again is wrong
        return (f"a point has depth 0 in its camera (it lies on the plane through the camera "
                f"centre, where even cheirality='allow' cannot project){region}; fix the "
                "initial estimate")
    # worded for graphs a reader built too, where the policy is the reader's
    return (f"a point is at or behind its camera (cheirality){region}; fix the initial "
            "estimate (factors built with cheirality='allow' project such points too)")


def _check_cheirality(cheirality: str) -> bool:
    if cheirality not in CHEIRALITY:
        raise FgoptError(f"cheirality must be one of {CHEIRALITY}, got {cheirality!r}")
    return cheirality == "reject"


def _contiguous(name: str, arrays: tuple, consts: np.ndarray, widths: tuple) -> list:
    if len(arrays) != len(widths) - 1:
        raise DimensionMismatchError(f"{name}: expected {len(widths) - 1} argument arrays, "
                                     f"got {len(arrays)}")
    out = [kernel_array(a) for a in arrays]
    out.append(kernel_array(consts))
    n = out[0].shape[0] if out[0].ndim == 2 else -1
    for a, w in zip(out, widths):
        if a.shape != (n, w):
            raise DimensionMismatchError(
                f"{name}: expected arrays of widths {widths} and {n} rows, got "
                f"{[x.shape for x in out]}")
    return out


@lru_cache(maxsize=None)
def projection_kernel(model: type[Calibration], calibration_variable: bool = False,
                      cheirality: str = "reject") -> FactorKernel:
    """Kernel of ``uv(pose, point, K) - m``: args ``(SE3, R^3[, model])``, constants
    ``m (2)`` then, for a constant calibration, its storage.

    Example: a point 2 m ahead seen 2 pixels left of where it projects (the residual is
    predicted minus measured):

    >>> from fgopt import SE3
    >>> from fgopt.cameras import Cal3_S2, projection_kernel
    >>> K = Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)
    >>> kernel = projection_kernel(Cal3_S2)
    >>> kernel.residual_dim, [kind.name for kind in kernel.arg_kinds], kernel.num_constants
    (2, ['SE3', 'R3'], 7)
    >>> args = (SE3().to_storage()[None], np.array([[0.2, -0.4, 2.0]]))   # n = 1 instance
    >>> res, jac = kernel.linearize(args, np.array([[372.0, 140.0, *K.to_storage()]]))
    >>> res, jac.shape
    (array([[-2.,  0.]]), (1, 2, 9))
    """
    reject = _check_cheirality(cheirality)
    batch, s = specialize(PK.projection_batch, model.MODEL), len(model.PARAMS)
    var = bool(calibration_variable)
    name = (f"projection_{model.__name__.lower()}{'_selfcal' if var else ''}"
            f"{'' if reject else '_allow_behind'}")
    kinds = (SE3.batch_kind(), vector_kind(3)) + ((model.batch_kind(),) if var else ())
    widths = (7, 3, s, 2) if var else (7, 3, 2 + s)

    def run(args, consts, with_jac):
        arrs = _contiguous(name, args, consts, widths)
        if var:
            pose, point, cal, m = arrs
        else:
            pose, point, c = arrs
            m, cal = np.ascontiguousarray(c[:, :2]), np.ascontiguousarray(c[:, 2:])
        return batch(pose, point, cal, m, reject, var, with_jac)

    def trusted(args, consts):
        if var:
            return batch(args[0], args[1], args[2], consts, reject, var, True)
        return batch(args[0], args[1], np.ascontiguousarray(consts[:, 2:]),
                     np.ascontiguousarray(consts[:, :2]), reject, var, True)

    return FactorKernel(name, kinds, 2, 2 if var else 2 + s,
                        residual=lambda args, consts: run(args, consts, False)[0],
                        linearize=lambda args, consts: run(args, consts, True),
                        source=_SOURCE, nonfinite_hint=nonfinite_hint(reject),
                        recipe=(projection_kernel, (model, var, cheirality)),
                        trusted_linearize=trusted)


@lru_cache(maxsize=None)
def camera_projection_kernel(model: type[Calibration], cheirality: str = "reject") -> FactorKernel:
    """Kernel of ``uv(camera, point) - m`` with a :class:`~fgopt.cameras.PinholeCamera`
    variable (pose and calibration in one): args ``(PinholeCamera[model], R^3)``, constants
    ``m (2)``. Jacobian columns: pose ``[w, v]``, calibration, point.

    >>> from fgopt import SE3
    >>> from fgopt.cameras import Cal3_S2, PinholeCamera, camera_projection_kernel
    >>> camera = PinholeCamera(SE3(), Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0))
    >>> kernel = camera_projection_kernel(Cal3_S2)
    >>> [kind.name for kind in kernel.arg_kinds]
    ['PinholeCamera[Cal3_S2]', 'R3']
    >>> args = (camera.to_storage()[None], np.array([[0.2, -0.4, 2.0]]))
    >>> res, jac = kernel.linearize(args, np.array([[372.0, 140.0]]))
    >>> res, jac.shape                                     # 6 pose + 5 calibration + 3 point
    (array([[-2.,  0.]]), (1, 2, 14))
    """
    from .camera import PinholeCamera

    reject = _check_cheirality(cheirality)
    batch, s = specialize(PK.camera_projection_batch, model.MODEL), len(model.PARAMS)
    name = f"camera_projection_{model.__name__.lower()}{'' if reject else '_allow_behind'}"
    kinds = (PinholeCamera.batch_kind_of(model), vector_kind(3))
    widths = (7 + s, 3, 2)

    def run(args, consts, with_jac):
        cam, point, m = _contiguous(name, args, consts, widths)
        return batch(cam, point, m, reject, with_jac)

    return FactorKernel(name, kinds, 2, 2,
                        residual=lambda args, consts: run(args, consts, False)[0],
                        linearize=lambda args, consts: run(args, consts, True),
                        source=_SOURCE, nonfinite_hint=nonfinite_hint(reject),
                        recipe=(camera_projection_kernel, (model, cheirality)),
                        trusted_linearize=lambda args, consts: batch(
                            args[0], args[1], consts, reject, True))


@lru_cache(maxsize=None)
def stereo_kernel(calibration_variable: bool = False, cheirality: str = "reject") -> FactorKernel:
    """Kernel of ``(uL, uR, v)(pose, point, K) - m``: args ``(SE3, R^3[, Cal3_S2Stereo])``,
    constants ``m (3)`` then, for a constant calibration, its 6 numbers.

    >>> from fgopt import SE3
    >>> from fgopt.cameras import Cal3_S2Stereo, stereo_kernel
    >>> K = Cal3_S2Stereo(500.0, 500.0, 0.0, 320.0, 240.0, 0.2)
    >>> kernel = stereo_kernel()
    >>> args = (SE3().to_storage()[None], np.array([[0.2, -0.4, 2.0]]))
    >>> kernel.residual(args, np.array([[370.0, 321.0, 140.0, *K.to_storage()]]))  # uR 1 px off
    array([[ 0., -1.,  0.]])
    """
    reject = _check_cheirality(cheirality)
    var = bool(calibration_variable)
    name = f"stereo{'_selfcal' if var else ''}{'' if reject else '_allow_behind'}"
    kinds = (SE3.batch_kind(), vector_kind(3)) + ((Cal3_S2Stereo.batch_kind(),) if var else ())
    widths = (7, 3, 6, 3) if var else (7, 3, 9)

    def run(args, consts, with_jac):
        arrs = _contiguous(name, args, consts, widths)
        if var:
            pose, point, cal, m = arrs
        else:
            pose, point, c = arrs
            m, cal = np.ascontiguousarray(c[:, :3]), np.ascontiguousarray(c[:, 3:])
        return PK.stereo_batch(pose, point, cal, m, reject, var, with_jac)

    def trusted(args, consts):
        if var:
            return PK.stereo_batch(args[0], args[1], args[2], consts, reject, var, True)
        return PK.stereo_batch(args[0], args[1], np.ascontiguousarray(consts[:, 3:]),
                               np.ascontiguousarray(consts[:, :3]), reject, var, True)

    return FactorKernel(name, kinds, 3, 3 if var else 9,
                        residual=lambda args, consts: run(args, consts, False)[0],
                        linearize=lambda args, consts: run(args, consts, True),
                        source=_SOURCE,
                        nonfinite_hint=nonfinite_hint(reject, lens=False),
                        recipe=(stereo_kernel, (var, cheirality)),
                        trusted_linearize=trusted)


def _is_key(x: Any) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def _measurement(values: Any, n: int, what: str, where: str) -> np.ndarray:
    m = float_array(values, f"{where}: {what}", f"{n} numbers").reshape(-1)
    if m.shape[0] != n:
        raise DimensionMismatchError(f"{where}: {what} needs {n} numbers, got {m.shape[0]}")
    if not np.all(np.isfinite(m)):
        raise NonFiniteError(f"{where}: {what} has a NaN or inf: {m}")
    return m


def _calibration_args(calibration: Any, model: Any, where: str, base: type[Calibration]):
    """``(model class, constant calibration or None, calibration key or None)``."""
    if isinstance(calibration, Calibration):
        if not isinstance(calibration, base):
            raise FgoptError(f"{where}: calibration must be a {base.__name__}, got "
                             f"{type(calibration).__name__}")
        if model is not None and model is not type(calibration):
            raise FgoptError(f"{where}: model={model.__name__} but the calibration is a "
                             f"{type(calibration).__name__}")
        return type(calibration), calibration, None
    if _is_key(calibration):
        if model is None:
            if base is Cal3_S2Stereo:
                model = Cal3_S2Stereo
            else:
                raise FgoptError(f"{where}: the calibration is a key "
                                 f"({key_str(as_key(calibration))}); pass model=<its class> "
                                 "(Cal3_S2, Cal3Bundler, ...)")
        if not (isinstance(model, type) and issubclass(model, base)):
            raise FgoptError(f"{where}: model must be a {base.__name__} class, got {model!r}")
        return model, None, as_key(calibration)
    raise FgoptError(f"{where}: calibration must be a {base.__name__} (constant) or a key "
                     f"(variable), got {type(calibration).__name__}")


def _where(name: str, *keys: Any) -> str:
    try:
        return f"{name}({', '.join(key_str(as_key(k)) for k in keys)})"
    except FgoptError:
        return f"{name}({', '.join(map(repr, keys))})"


class CameraKernelFactor(KernelFactor):
    """A kernel factor whose residual is NaN where it is undefined (a point behind a camera, a
    degenerate smart track). The kernels leave the Jacobian there zero, which the optimizer never
    reads (it rejects the NaN residual first); the per-factor API would pass the zeros on as a
    valid linearization, so it turns them into NaN and its checked errors carry the kernel's hint.
    """

    def jacobians(self, values: Any) -> list[np.ndarray]:
        res, jac = self.kernel.linearize(self._gather(values), self.constants.reshape(1, -1))
        J = np.array(jac[0], dtype=float)
        J[~np.isfinite(res[0])] = np.nan
        return [J[:, o:o + kind.dim] for o, kind in
                zip(self.kernel.arg_offsets, self.kernel.arg_kinds)]

    def checked_error(self, values: Any) -> np.ndarray:
        try:
            return super().checked_error(values)
        except NonFiniteError as e:
            raise self._hinted(e) from None

    def checked_jacobians(self, values: Any) -> list[np.ndarray]:
        try:
            return super().checked_jacobians(values)
        except NonFiniteError as e:
            raise self._hinted(e) from None

    def _hinted(self, e: NonFiniteError) -> NonFiniteError:
        hint = self.kernel.nonfinite_hint
        return type(e)(f"{e}: {hint}") if hint else e


class ProjectionFactor(CameraKernelFactor):
    """``ProjectionFactor(pose, point, measured, loss, calibration)``: a pixel ``measured`` of
    world point ``point`` seen by the camera at ``pose`` (``world_T_camera``, z forward).

    Args:
        pose, point: keys of an :class:`~fgopt.manifolds.SE3` and an R^3 point.
        measured: the pixel ``(u, v)``.
        loss: a 2-D noise model or robust loss (``None``: unit); ``noise=`` is a deprecated
            alias.
        calibration: a :class:`~fgopt.cameras.Calibration` (constant) or a key (variable;
            then ``model`` names its class).
        cheirality: ``"reject"`` or ``"allow"`` (see the module docstring).

    Example:

    >>> from fgopt import SE3
    >>> from fgopt.cameras import Cal3_S2, ProjectionFactor
    >>> from fgopt.noise import Isotropic
    >>> K = Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0)
    >>> f = ProjectionFactor(key('x', 0), key('l', 0), np.array([370.0, 140.0]), Isotropic.sigma(2, 1.0), K)
    >>> values = fgopt.Variables().add(key('x', 0), SE3()).add(key('l', 0), np.array([0.2, -0.4, 2.0]))
    >>> np.round(f.error(values), 6)
    array([0., 0.])
    """

    def __init__(self, pose: int, point: int, measured: Any, loss: Any = None,
                 calibration: Any = None, *, model: type[Calibration] | None = None,
                 cheirality: str = "reject", noise: Any = UNSET):
        where = _where("ProjectionFactor", pose, point)
        loss = loss_argument(loss, noise, where)
        m = _measurement(measured, 2, "the measured pixel", where)
        model, K, kkey = _calibration_args(calibration, model, where, Calibration)
        self.measured = m
        self.calibration = K if K is not None else kkey
        if K is not None:
            super().__init__(projection_kernel(model, False, cheirality), [pose, point],
                             np.concatenate([m, K._data]), loss)
        else:
            super().__init__(projection_kernel(model, True, cheirality), [pose, point, kkey], m,
                             loss)

    def describe(self) -> str:
        keys = ", ".join(key_str(k) for k in self.keys) if hasattr(self, "keys") else "?"
        return f"ProjectionFactor({keys})"


class GeneralSFMFactor(CameraKernelFactor):
    """``GeneralSFMFactor(camera, point, measured, loss)``: a pixel of ``point`` seen by a
    :class:`~fgopt.cameras.PinholeCamera` *variable* (pose and calibration in one, GTSAM's
    ``GeneralSFMFactor``; the BAL / Bundler camera form). ``model`` names the calibration class
    of the camera variable. ``cheirality`` as ProjectionFactor's.

    Example:

    >>> from fgopt import SE3
    >>> from fgopt.cameras import Cal3_S2, GeneralSFMFactor, PinholeCamera
    >>> camera = PinholeCamera(SE3(), Cal3_S2(500.0, 500.0, 0.0, 320.0, 240.0))
    >>> f = GeneralSFMFactor(key('c', 0), key('l', 0), [370.0, 140.0], model=Cal3_S2)
    >>> values = fgopt.Variables().add(key('c', 0), camera).add(key('l', 0), np.array([0.2, -0.4, 2.0]))
    >>> np.round(f.error(values), 6), [J.shape for J in f.jacobians(values)]   # camera: 6 + 5
    (array([0., 0.]), [(2, 11), (2, 3)])
    """

    def __init__(self, camera: int, point: int, measured: Any, loss: Any = None, *,
                 model: type[Calibration] | None = None, cheirality: str = "reject",
                 noise: Any = UNSET):
        where = _where("GeneralSFMFactor", camera, point)
        loss = loss_argument(loss, noise, where)
        m = _measurement(measured, 2, "the measured pixel", where)
        if model is None:
            raise FgoptError(f"{where}: pass model=<the camera variable's calibration class> "
                             "(Cal3Bundler, Cal3_S2, ...)")
        if not (isinstance(model, type) and issubclass(model, Calibration)):
            raise FgoptError(f"{where}: model must be a Calibration class, got {model!r}")
        self.measured = m
        super().__init__(camera_projection_kernel(model, cheirality), [camera, point], m, loss)

    def describe(self) -> str:
        keys = ", ".join(key_str(k) for k in self.keys) if hasattr(self, "keys") else "?"
        return f"GeneralSFMFactor({keys})"


class StereoFactor(CameraKernelFactor):
    """``StereoFactor(pose, point, measured, loss, calibration)``: a rectified stereo
    measurement ``(uL, uR, v)`` of ``point`` from the left camera at ``pose``; ``calibration``
    a :class:`~fgopt.cameras.Cal3_S2Stereo` or a key. ``cheirality`` as ProjectionFactor's.

    Example: a point 2 m ahead of a stereo pair with a 0.2 m baseline:

    >>> from fgopt import SE3
    >>> from fgopt.cameras import Cal3_S2Stereo, StereoFactor
    >>> K = Cal3_S2Stereo(500.0, 500.0, 0.0, 320.0, 240.0, 0.2)
    >>> f = StereoFactor(key('x', 0), key('l', 0), [370.0, 320.0, 140.0], None, K)
    >>> values = fgopt.Variables().add(key('x', 0), SE3()).add(key('l', 0), np.array([0.2, -0.4, 2.0]))
    >>> np.round(f.error(values), 6)                       # (uL, uR, v) predicted - measured
    array([0., 0., 0.])
    """

    def __init__(self, pose: int, point: int, measured: Any, loss: Any = None,
                 calibration: Any = None, *, cheirality: str = "reject", noise: Any = UNSET):
        where = _where("StereoFactor", pose, point)
        loss = loss_argument(loss, noise, where)
        m = _measurement(measured, 3, "the measurement (uL, uR, v)", where)
        _, K, kkey = _calibration_args(calibration, None, where, Cal3_S2Stereo)
        self.measured = m
        self.calibration = K if K is not None else kkey
        if K is not None:
            super().__init__(stereo_kernel(False, cheirality), [pose, point],
                             np.concatenate([m, K._data]), loss)
        else:
            super().__init__(stereo_kernel(True, cheirality), [pose, point, kkey], m, loss)

    def describe(self) -> str:
        keys = ", ".join(key_str(k) for k in self.keys) if hasattr(self, "keys") else "?"
        return f"StereoFactor({keys})"

