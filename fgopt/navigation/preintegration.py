"""IMU preintegration: ``PreintegratedImu`` (9x9 covariance) and ``PreintegratedCombinedImu``
(15x15, with the bias random walk), GTSAM's ``PreintegratedImuMeasurements`` /
``PreintegratedCombinedMeasurements`` with on-manifold preintegration (Forster et al., "On-Manifold
Preintegration for Real-Time Visual-Inertial Odometry", T-RO 2017; GTSAM's
``ManifoldPreintegration``).

``integrate(accel, gyro, dt)`` takes one sample or arrays of samples (``(n, 3)``, ``(n, 3)``,
``dt`` scalar or ``(n,)``) and runs one numba loop over them
(:mod:`fgopt.navigation._preint_kernels`). Samples are checked first, all of them: a non-finite
or wrongly shaped sample, or a non-positive ``dt``, raises an :class:`~fgopt.errors.FgoptError`
naming the sample index, and nothing is integrated (the update is atomic).

Between samples ``i`` and ``j`` the preintegrated deltas, in body frame ``i``, are
``delta_R = R_i^T R_j``, ``delta_p``, ``delta_v`` (gravity and initial velocity removed); a
change of the bias from ``bias_hat`` is applied to first order through ``bias_jacobian`` (9x6,
rows ``[theta, p, v]``, columns ``[accelerometer, gyroscope]``). ``covariance`` is in GTSAM's
``preintMeasCov`` order ``[rotation, position, velocity]`` (then ``[bias_acc, bias_gyro]`` for
the combined one); ``residual_covariance`` is the IMU factor's noise (GTSAM's
``residualCovariance``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import DimensionMismatchError, FgoptError, NonFiniteError, NotPositiveDefiniteError
from ..manifolds import SO3
from . import _imu_kernels as IK
from . import _preint_kernels as PK
from .bias import ImuBias
from .navstate import NavState
from .params import PreintegrationParams


def _samples(accel: Any, gyro: Any, dt: Any, who: str) -> tuple:
    """Validate samples; ``(acc (n, 3), gyro (n, 3), dt (n,))`` C-contiguous float64."""
    try:
        a = np.array(accel, dtype=np.float64)
        w = np.array(gyro, dtype=np.float64)
        d = np.array(dt, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DimensionMismatchError(f"{who}: samples must be numbers: {exc}") from exc
    if a.ndim == 1:
        a = a.reshape(1, -1)
    if w.ndim == 1:
        w = w.reshape(1, -1)
    if a.ndim != 2 or a.shape[1] != 3:
        raise DimensionMismatchError(f"{who}: accel must have shape (3,) or (n, 3), got "
                                     f"{np.shape(accel)}")
    if w.ndim != 2 or w.shape[1] != 3:
        raise DimensionMismatchError(f"{who}: gyro must have shape (3,) or (n, 3), got "
                                     f"{np.shape(gyro)}")
    n = a.shape[0]
    if w.shape[0] != n:
        raise DimensionMismatchError(f"{who}: {n} accelerometer samples but {w.shape[0]} "
                                     f"gyroscope samples (sample {min(n, w.shape[0])} has no "
                                     "partner)")
    if d.ndim == 0:
        d = np.full(n, float(d))
    if d.ndim != 1 or d.shape[0] != n:
        raise DimensionMismatchError(f"{who}: dt must be a number or have shape ({n},), got "
                                     f"shape {np.shape(dt)}")
    for name, arr in (("accelerometer", a), ("gyroscope", w)):
        bad = ~np.all(np.isfinite(arr), axis=1)
        if np.any(bad):
            i = int(np.argmax(bad))
            raise NonFiniteError(f"{who}: sample {i} has a non-finite {name} value "
                                 f"{arr[i].tolist()}; nothing was integrated")
    bad = ~(d > 0.0) | ~np.isfinite(d)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise FgoptError(f"{who}: sample {i} has dt = {float(d[i])!r}; dt must be positive and "
                         "finite; nothing was integrated")
    return np.ascontiguousarray(a), np.ascontiguousarray(w), np.ascontiguousarray(d)


class PreintegratedImu:
    """GTSAM's ``PreintegratedImuMeasurements`` (on-manifold); see the module docstring.

    One second at 100 Hz of a level body yawing at 0.1 rad/s (the accelerometer reads the
    specific force, +g up in ``make_u``'s z-up frame); ``integrate`` takes ``(n, 3)`` samples and
    a scalar or ``(n,)`` dt, ``predict`` gives the NavState at the last sample:

    >>> from fgopt import SE3
    >>> from fgopt.navigation import ImuBias, NavState, PreintegratedImu, PreintegrationParams
    >>> pim = PreintegratedImu(PreintegrationParams.make_u(9.81), ImuBias())
    >>> accel, gyro = np.tile([0.0, 0.0, 9.81], (100, 1)), np.tile([0.0, 0.0, 0.1], (100, 1))
    >>> pim = pim.integrate(accel, gyro, 0.01)
    >>> round(pim.delta_t, 9), np.round(pim.delta_R.log(), 9)
    (1.0, array([0. , 0. , 0.1]))
    >>> x1 = pim.predict(NavState.from_pose_velocity(SE3(), [1.0, 0.0, 0.0]), ImuBias())
    >>> np.round(x1.position(), 9) + 0.0, np.round(x1.velocity(), 9) + 0.0
    (array([1., 0., 0.]), array([1., 0., 0.]))
    """

    _COMBINED = False

    def __init__(self, params: PreintegrationParams, bias: ImuBias | Any = None):
        if not isinstance(params, PreintegrationParams):
            raise FgoptError(f"{type(self).__name__}: params must be PreintegrationParams, got "
                             f"{type(params).__name__}")
        self.params = params
        p = params
        self._acc_cov = np.array(p.accelerometer_covariance)
        self._gyro_cov = np.array(p.gyroscope_covariance)
        self._int_cov = np.array(p.integration_covariance)
        self._bias_acc_cov = np.zeros((3, 3))
        self._bias_gyro_cov = np.zeros((3, 3))
        if self._COMBINED:
            for name in ("bias_acc_covariance", "bias_omega_covariance"):
                m = getattr(p, name)
                if m is None or float(np.min(np.linalg.eigvalsh(m))) <= 0.0:
                    raise NotPositiveDefiniteError(
                        f"{type(self).__name__}: params.{name} must be positive definite (set "
                        "bias_acc_rw_sigma / bias_gyro_rw_sigma > 0 in make_u / make_d)")
            self._bias_acc_cov = np.array(p.bias_acc_covariance)
            self._bias_gyro_cov = np.array(p.bias_omega_covariance)
        self._has_sensor = p.body_P_sensor is not None
        if self._has_sensor:
            self._bRs = p.body_P_sensor.rotation().matrix()
            self._arm = p.body_P_sensor.translation()
        else:
            self._bRs, self._arm = np.eye(3), np.zeros(3)
        self._has_arm = bool(np.any(self._arm != 0.0))
        self._omega = (np.zeros(3) if p.omega_coriolis is None
                       else np.array(p.omega_coriolis))
        self.reset(bias)

    # ------------------------------------------------------------------ integration
    def reset(self, bias: ImuBias | Any = None) -> None:
        """Clear the integration (GTSAM's ``resetIntegration``); with ``bias``, also set the
        linearization bias (``resetIntegrationAndSetBias``)."""
        if bias is not None or not hasattr(self, "_bias_hat"):
            self._bias_hat = ImuBias.as_vector(bias, f"{type(self).__name__} bias")
        self._x = PK.initial_state()
        n = 15 if self._COMBINED else 9
        self._P = np.zeros((n, n))

    def integrate(self, accel: Any, gyro: Any, dt: Any) -> PreintegratedImu:
        """Integrate one sample (``accel (3,)``, ``gyro (3,)``, ``dt``) or ``n`` samples
        (``(n, 3)``, ``(n, 3)``, ``dt`` scalar or ``(n,)``): specific force (m/s^2) and angular
        rate (rad/s) in the sensor frame, each held for its ``dt`` seconds. Atomic."""
        a, w, d = _samples(accel, gyro, dt, f"{type(self).__name__}.integrate")
        if a.shape[0] == 0:
            return self
        x, P = self._x.copy(), self._P.copy()
        PK.integrate(x, P, a, w, d, self._bias_hat, self._acc_cov, self._gyro_cov,
                     self._int_cov, self._bias_acc_cov, self._bias_gyro_cov, self._bRs,
                     self._arm, self._has_sensor, self._has_arm, self._COMBINED)
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):  # pragma: no cover
            raise NonFiniteError(f"{type(self).__name__}.integrate: the integration overflowed "
                                 "(samples too large?); nothing was integrated")
        self._x, self._P = x, P
        return self

    integrate_measurement = integrate  # GTSAM's name

    # ------------------------------------------------------------------ results
    @property
    def bias_hat(self) -> ImuBias:
        """The bias the samples were corrected with."""
        return ImuBias.from_vector(self._bias_hat)

    @property
    def delta_t(self) -> float:
        return float(self._x[PK.T_])

    @property
    def delta_R(self) -> SO3:
        """Preintegrated rotation ``R_i^T R_j`` (bias ``bias_hat``)."""
        return SO3.from_matrix(self.delta_R_matrix)

    @property
    def delta_R_matrix(self) -> np.ndarray:
        return self._x[PK.R_:PK.R_ + 9].reshape(3, 3).copy()

    @property
    def delta_p(self) -> np.ndarray:
        return self._x[PK.P_:PK.P_ + 3].copy()

    @property
    def delta_v(self) -> np.ndarray:
        return self._x[PK.V_:PK.V_ + 3].copy()

    @property
    def delta_X(self) -> NavState:
        """The deltas as a NavState (GTSAM's ``deltaXij``)."""
        return NavState(self.delta_R, self.delta_p, self.delta_v)

    @property
    def covariance(self) -> np.ndarray:
        """GTSAM's ``preintMeasCov``: 9x9 ``[rotation, position, velocity]`` (15x15 with the
        biases for the combined preintegration)."""
        return self._P.copy()

    @property
    def residual_covariance(self) -> np.ndarray:
        """:meth:`residual_covariance_at` the attitude predicted from the identity."""
        return self.residual_covariance_at(None)

    def residual_covariance_at(self, predicted_attitude: SO3 | Any = None) -> np.ndarray:
        """Covariance of the IMU factor's residual (GTSAM's ``residualCovarianceAt``).

        The preintegration chart is the factor's, except that with Coriolis (``omega``) the
        prediction ``v^ = ... - omega x p^`` couples velocity to position: ``J P J^T`` with
        ``J = [[I, 0, 0], [0, I, 0], [0, -hat(R^T omega), I]]`` at the predicted attitude ``R``
        (default ``Exp(-omega T) delta_R``, i.e. from ``R_i = I``, as GTSAM's
        ``residualCovariance``). For the combined factor the bias residual is ``b_i - b_j``
        while ``covariance`` propagates the drift ``b_j - b_i``: those cross blocks flip sign.
        """
        P = self._P.copy()
        if np.any(self._omega != 0.0):
            if predicted_attitude is None:
                R = SO3.exp(-self._omega * self.delta_t).matrix() @ self.delta_R_matrix
            elif isinstance(predicted_attitude, SO3):
                R = predicted_attitude.matrix()
            else:
                R = SO3.from_matrix(predicted_attitude).matrix()
            u = R.T @ self._omega
            J = np.eye(P.shape[0])
            J[6:9, 3:6] = -np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]],
                                     [-u[1], u[0], 0.0]])
            P = J @ P @ J.T
        if self._COMBINED:
            P[:9, 9:] *= -1.0
            P[9:, :9] *= -1.0
        return 0.5 * (P + P.T)

    @property
    def bias_jacobian(self) -> np.ndarray:
        """``d [theta, p, v] / d [b_acc, b_gyro]`` (9x6) at ``bias_hat``."""
        x = self._x
        J = np.zeros((9, 6))
        J[0:3, 3:6] = x[PK.JRW:PK.JRW + 9].reshape(3, 3)
        J[3:6, 0:3] = x[PK.JPA:PK.JPA + 9].reshape(3, 3)
        J[3:6, 3:6] = x[PK.JPW:PK.JPW + 9].reshape(3, 3)
        J[6:9, 0:3] = x[PK.JVA:PK.JVA + 9].reshape(3, 3)
        J[6:9, 3:6] = x[PK.JVW:PK.JVW + 9].reshape(3, 3)
        return J

    def bias_corrected_delta(self, bias: ImuBias | Any) -> np.ndarray:
        """``[Log(delta_R Exp(JRw db_w)), delta_p + ..., delta_v + ...]`` for ``db = bias -
        bias_hat`` (GTSAM's ``biasCorrectedDelta``)."""
        db = ImuBias.as_vector(bias) - self._bias_hat
        J = self.bias_jacobian
        corr = self.delta_R_matrix @ SO3.exp(J[0:3, 3:6] @ db[3:]).matrix()
        out = np.empty(9)
        out[:3] = SO3.from_matrix(corr).log()
        out[3:] = self._x[PK.P_:PK.P_ + 6] + J[3:9] @ db
        return out

    def constants(self) -> np.ndarray:
        """The kernel constants row of an IMU factor built from this preintegration."""
        p = self.params
        return IK.pack_constants(self._x, self._bias_hat, p.n_gravity, self._omega,
                                 p.error_mode == "logmap")

    def predict(self, state: NavState, bias: ImuBias | Any) -> NavState:
        """The state at the last sample from ``state`` at the first one, with ``bias`` (first-
        order bias correction, gravity, Coriolis): GTSAM's ``predict``."""
        if not isinstance(state, NavState):
            raise FgoptError(f"{type(self).__name__}.predict: state must be a NavState, got "
                             f"{type(state).__name__} (NavState.from_pose_velocity(pose, v))")
        s = state.to_storage()
        b = ImuBias.as_vector(bias, f"{type(self).__name__}.predict bias")
        R, p, v = IK.predict_state(s[:7], s[7:10].copy(), b, self.constants())
        return NavState(SO3.from_matrix(R), p, v)

    def copy(self) -> PreintegratedImu:
        out = object.__new__(type(self))
        out.__dict__.update(self.__dict__)
        out._x, out._P = self._x.copy(), self._P.copy()
        return out

    def __repr__(self) -> str:
        w, x, y, z = self.delta_R.quaternion()
        dp, dv = self.delta_p, self.delta_v
        return (f"{type(self).__name__}(delta_t={self.delta_t:.6g}, "
                f"delta_R=[w={w:.4f}, x={x:.4f}, y={y:.4f}, z={z:.4f}], "
                f"delta_p=[{dp[0]:.4g}, {dp[1]:.4g}, {dp[2]:.4g}], "
                f"delta_v=[{dv[0]:.4g}, {dv[1]:.4g}, {dv[2]:.4g}], bias_hat={self.bias_hat!r})")


class PreintegratedCombinedImu(PreintegratedImu):
    """GTSAM's ``PreintegratedCombinedMeasurements``: as :class:`PreintegratedImu`, with the
    15x15 ``covariance`` of ``[rotation, position, velocity, bias_acc, bias_gyro]`` that adds the
    bias random walk (``params.bias_acc_covariance`` / ``bias_omega_covariance``, required).

    Example: one second at rest; the bias block of the covariance grows by the random walk's
    covariance times the time:

    >>> from fgopt.navigation import ImuBias, PreintegratedCombinedImu, PreintegrationParams
    >>> params = PreintegrationParams.make_u(9.81, bias_acc_covariance=1e-4 * np.eye(3),
    ...                                      bias_omega_covariance=1e-6 * np.eye(3))
    >>> pim = PreintegratedCombinedImu(params, ImuBias())
    >>> pim = pim.integrate(np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.01)
    >>> pim.covariance.shape, np.round(np.diag(pim.covariance)[9:], 8)
    ((15, 15), array([1.e-04, 1.e-04, 1.e-04, 1.e-06, 1.e-06, 1.e-06]))
    """

    _COMBINED = True

