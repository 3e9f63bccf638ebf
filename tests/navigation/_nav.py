"""Shared helpers of the navigation tests: GTSAM conversions, a random IMU setup, rotations of a
given angle. Test modules load it by file path (``_load_helpers``), so it cannot collide with
other folders' helpers under pytest's importlib import mode."""

from __future__ import annotations

import math

import numpy as np

from fgopt.manifolds import SE3, SO3
from fgopt.navigation import NavState, PreintegrationParams

#: rotation angles where Exp / Log / Jacobians switch formulas or become singular
SPECIAL_ANGLES = (0.0, 1e-9, 1e-4, 0.3, 2.0, math.pi - 1e-4, math.pi - 1e-7)
#: angles for central differences with step 1e-6 (a step must not carry Log across pi)
FD_ANGLES = SPECIAL_ANGLES[:-1]

SA = np.diag([0.01, 0.02, 0.03])
SW = np.diag([1e-4, 2e-4, 3e-4])
SI = 1e-6 * np.eye(3)
SBA = 1e-3 * np.eye(3)
SBW = 2e-5 * np.eye(3)
BIAS_HAT = np.array([0.1, -0.2, 0.05, 0.01, 0.02, -0.03])
SENSOR = SE3(SO3.from_rotvec([0.1, -0.2, 0.3]), [0.2, -0.1, 0.05])
SENSOR_ROTATION = SE3(SO3.from_rotvec([0.1, -0.2, 0.3]), [0.0, 0.0, 0.0])


def rotation_with_angle(rng, angle: float) -> SO3:
    axis = rng.normal(size=3)
    return SO3.exp(axis / np.linalg.norm(axis) * angle)


def fgopt_params(combined=False, body_P_sensor=None, omega=None, error_mode="logmap",
                 up=True) -> PreintegrationParams:
    kw = dict(bias_acc_covariance=SBA, bias_omega_covariance=SBW) if combined else {}
    make = PreintegrationParams.make_u if up else PreintegrationParams.make_d
    return make(9.81, accelerometer_covariance=SA, gyroscope_covariance=SW,
                integration_covariance=SI, body_P_sensor=body_P_sensor, omega_coriolis=omega,
                error_mode=error_mode, **kw)


def gtsam_params(gtsam, combined=False, body_P_sensor=None, omega=None, error_mode="logmap",
                 up=True):
    cls = gtsam.PreintegrationCombinedParams if combined else gtsam.PreintegrationParams
    p = cls.MakeSharedU(9.81) if up else cls.MakeSharedD(9.81)
    p.setAccelerometerCovariance(SA)
    p.setGyroscopeCovariance(SW)
    p.setIntegrationCovariance(SI)
    if combined:
        p.setBiasAccCovariance(SBA)
        p.setBiasOmegaCovariance(SBW)
    if body_P_sensor is not None:
        p.setBodyPSensor(pose(gtsam, body_P_sensor))
    if omega is not None:
        p.setOmegaCoriolis(np.asarray(omega, dtype=float))
    p.setImuFactorErrorMode(gtsam.ImuFactorErrorMode.Logmap if error_mode == "logmap"
                            else gtsam.ImuFactorErrorMode.ComponentWise)
    return p


def pose(gtsam, p: SE3):
    return gtsam.Pose3(gtsam.Rot3(p.rotation().matrix()), p.translation())


def navstate(gtsam, x: NavState):
    return gtsam.NavState(gtsam.Rot3(x.rotation()), x.position(), x.velocity())


def bias(gtsam, b):
    b = np.asarray(b, dtype=float)
    return gtsam.imuBias.ConstantBias(b[:3], b[3:])


def samples(rng, n: int, rate: float = 1.0):
    """``n`` random specific forces (around 1 g) and angular rates (``rate`` rad/s)."""
    return (rng.normal(size=(n, 3)) + np.array([0.0, 0.0, 9.81]), rate * rng.normal(size=(n, 3)),
            0.01 + 0.002 * rng.random(n))

