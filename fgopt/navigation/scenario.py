"""IMU scenarios: true trajectories and the IMU samples they produce (GTSAM's ``Scenario`` /
``ScenarioRunner``), for examples and tests.

A scenario gives the true ``world_T_body(t)``, world velocity and acceleration and body angular
rate at any time ``t`` (seconds). :class:`ScenarioRunner` turns it into what an IMU measures:

    gyro(t)  = omega_b(t) + b_g + n_g,      n_g ~ N(0, gyroscope_covariance / dt)
    accel(t) = R(t)^T (a_n(t) - n_gravity) + b_a + n_a,  n_a ~ N(0, accelerometer_covariance / dt)

(specific force: an accelerometer at rest reads ``-g`` rotated into the body, e.g. ``+9.81`` up
for ``make_u``). The noise densities are the :class:`PreintegrationParams` covariances, so the
samples are noisy exactly as the preintegration assumes.

Example: :class:`ScenarioRunner`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import FgoptError
from ..manifolds import SE3, SO3
from ..manifolds.lie import as_float_vector
from .bias import ImuBias
from .navstate import NavState
from .params import PreintegrationParams
from .preintegration import PreintegratedImu


class _Scenario:
    """What every scenario derives from ``pose``, ``velocity_n``, ``acceleration_n``,
    ``omega_b`` (each a function of ``t``)."""

    def rotation(self, t: float) -> SO3:
        """``world_R_body(t)``."""
        return self.pose(t).rotation()

    def nav_state(self, t: float) -> NavState:
        """The true :class:`NavState` (pose and world velocity) at ``t``."""
        return NavState.from_pose_velocity(self.pose(t), self.velocity_n(t))

    def velocity_b(self, t: float) -> np.ndarray:
        """Velocity in the body frame, ``R^T v_n``."""
        return self.rotation(t).matrix().T @ self.velocity_n(t)

    def acceleration_b(self, t: float) -> np.ndarray:
        """Acceleration in the body frame, ``R^T a_n``."""
        return self.rotation(t).matrix().T @ self.acceleration_n(t)


class ConstantTwistScenario(_Scenario):
    """Constant body angular rate ``omega_b`` and body velocity ``velocity_b`` (rad/s, m/s):
    ``world_T_body(t) = world_T_body0 * Exp([omega_b, velocity_b] t)`` (a helix; a circle when
    ``omega_b`` is perpendicular to ``velocity_b``), GTSAM's ``ConstantTwistScenario``.

    >>> from fgopt.navigation import ConstantTwistScenario
    >>> scenario = ConstantTwistScenario(omega_b=[0, 0, 0.3], velocity_b=[2.0, 0, 0])  # a circle
    >>> np.round(scenario.pose(1.0).translation(), 4)
    array([1.9701, 0.2978, 0.    ])
    >>> np.round(scenario.acceleration_n(0.0), 9)          # centripetal, towards the centre
    array([0. , 0.6, 0. ])
    """

    def __init__(self, omega_b: Any, velocity_b: Any, world_T_body0: SE3 | None = None):
        self._w = as_float_vector(omega_b, 3, "ConstantTwistScenario omega_b")
        self._v = as_float_vector(velocity_b, 3, "ConstantTwistScenario velocity_b")
        self._T0 = SE3() if world_T_body0 is None else world_T_body0
        if not isinstance(self._T0, SE3):
            raise FgoptError("ConstantTwistScenario: world_T_body0 must be an SE3")

    def pose(self, t: float) -> SE3:
        return self._T0 * SE3.exp(np.concatenate([self._w, self._v]) * float(t))

    def omega_b(self, t: float) -> np.ndarray:
        return self._w.copy()

    def velocity_n(self, t: float) -> np.ndarray:
        return self.rotation(t).matrix() @ self._v

    def acceleration_n(self, t: float) -> np.ndarray:
        """Centripetal: ``R(t) (omega_b x velocity_b)``."""
        return self.rotation(t).matrix() @ np.cross(self._w, self._v)


class AcceleratingScenario(_Scenario):
    """Constant world acceleration ``acceleration_n`` from ``position0`` / ``velocity0`` (world
    frame), attitude ``world_R_body0 * Exp(omega_b t)``, GTSAM's ``AcceleratingScenario``.

    >>> from fgopt.navigation import AcceleratingScenario
    >>> scenario = AcceleratingScenario(None, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.2, 0.0])
    >>> scenario.pose(2.0).translation(), scenario.velocity_n(2.0)
    (array([2. , 0.4, 0. ]), array([1. , 0.4, 0. ]))
    """

    def __init__(self, world_R_body0: SO3 | None, position0: Any, velocity0: Any,
                 acceleration_n: Any, omega_b: Any = (0.0, 0.0, 0.0)):
        self._R0 = SO3() if world_R_body0 is None else world_R_body0
        if not isinstance(self._R0, SO3):
            raise FgoptError("AcceleratingScenario: world_R_body0 must be an SO3")
        self._p0 = as_float_vector(position0, 3, "AcceleratingScenario position0")
        self._v0 = as_float_vector(velocity0, 3, "AcceleratingScenario velocity0")
        self._a = as_float_vector(acceleration_n, 3, "AcceleratingScenario acceleration_n")
        self._w = as_float_vector(omega_b, 3, "AcceleratingScenario omega_b")

    def pose(self, t: float) -> SE3:
        t = float(t)
        return SE3(self._R0 * SO3.exp(self._w * t), self._p0 + self._v0 * t + 0.5 * self._a * t * t)

    def omega_b(self, t: float) -> np.ndarray:
        return self._w.copy()

    def velocity_n(self, t: float) -> np.ndarray:
        return self._v0 + self._a * float(t)

    def acceleration_n(self, t: float) -> np.ndarray:
        return self._a.copy()


class ScenarioRunner:
    """IMU samples of a scenario every ``dt`` seconds with the true ``bias`` added and white
    noise from ``params`` (GTSAM's ``ScenarioRunner``); ``rng`` a seed or a NumPy Generator.

    Noisy samples of one second on a circle, preintegrated and predicted from the true start:

    >>> from fgopt.navigation import ConstantTwistScenario, PreintegrationParams, ScenarioRunner
    >>> scenario = ConstantTwistScenario(omega_b=[0, 0, 0.3], velocity_b=[2.0, 0, 0])
    >>> params = PreintegrationParams.make_u(9.81, accel_sigma=0.01, gyro_sigma=1e-3)
    >>> runner = ScenarioRunner(scenario, params, dt=0.01, rng=0)
    >>> pim = runner.integrate(1.0)                 # 100 samples over [0, 1)
    >>> error = runner.predict(pim).pose().translation() - scenario.pose(1.0).translation()
    >>> bool(np.linalg.norm(error) < 0.01)          # metres
    True
    """

    def __init__(self, scenario: _Scenario, params: PreintegrationParams, dt: float = 0.01,
                 bias: ImuBias | None = None, rng: Any = None):
        if not isinstance(params, PreintegrationParams):
            raise FgoptError("ScenarioRunner: params must be a PreintegrationParams")
        if not dt > 0:
            raise FgoptError(f"ScenarioRunner: dt must be > 0 seconds, got {dt!r}")
        self.scenario, self.params, self.dt = scenario, params, float(dt)
        self.bias = ImuBias() if bias is None else bias
        self._rng = np.random.default_rng(rng)
        self._gyro_L = np.linalg.cholesky(np.asarray(params.gyroscope_covariance) / self.dt)
        self._acc_L = np.linalg.cholesky(np.asarray(params.accelerometer_covariance) / self.dt)

    # the true signals, then the measured ones (bias and noise added)
    def actual_angular_velocity(self, t: float) -> np.ndarray:
        return self.scenario.omega_b(t)

    def actual_specific_force(self, t: float) -> np.ndarray:
        """``R^T (a_n - n_gravity)``: what a perfect accelerometer reads."""
        R = self.scenario.rotation(t).matrix()
        return R.T @ (self.scenario.acceleration_n(t) - np.asarray(self.params.n_gravity))

    def measured_angular_velocity(self, t: float) -> np.ndarray:
        """The true rate plus the gyroscope bias and a noise sample."""
        w = self.actual_angular_velocity(t) + self.bias.gyroscope
        return w + self._gyro_L @ self._rng.standard_normal(3)

    def measured_specific_force(self, t: float) -> np.ndarray:
        """The true specific force plus the accelerometer bias and a noise sample."""
        a = self.actual_specific_force(t) + self.bias.accelerometer
        return a + self._acc_L @ self._rng.standard_normal(3)

    def samples(self, duration: float, start: float = 0.0, corrupted: bool = True
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(times (n,), accel (n, 3), gyro (n, 3))`` at ``start + i dt`` for ``n =
        round(duration / dt)`` samples, each held for ``dt`` (what ``integrate`` takes);
        ``corrupted=False``: the true signals (no bias, no noise), as GTSAM's runner."""
        n = int(round(float(duration) / self.dt))
        times = float(start) + self.dt * np.arange(n)
        if corrupted:
            acc = [self.measured_specific_force(t) for t in times]
            gyro = [self.measured_angular_velocity(t) for t in times]
        else:
            acc = [self.actual_specific_force(t) for t in times]
            gyro = [self.actual_angular_velocity(t) for t in times]
        return times, np.array(acc).reshape(n, 3), np.array(gyro).reshape(n, 3)

    def integrate(self, duration: float, bias_estimate: ImuBias | None = None,
                  corrupted: bool = True, start: float = 0.0) -> PreintegratedImu:
        """The samples over ``[start, start + duration)`` preintegrated at ``bias_estimate``."""
        _, acc, gyro = self.samples(duration, start, corrupted)
        pim = PreintegratedImu(self.params, bias_estimate)
        return pim.integrate(acc, gyro, self.dt)

    def predict(self, pim: PreintegratedImu, bias_estimate: ImuBias | None = None,
                start: float = 0.0) -> NavState:
        """The state ``pim`` predicts from the true state at ``start``."""
        bias = ImuBias() if bias_estimate is None else bias_estimate
        return pim.predict(self.scenario.nav_state(start), bias)
