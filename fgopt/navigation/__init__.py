"""Inertial navigation: NavState, IMU preintegration, IMU and GPS factors (GTSAM's names).

::

    from fgopt.navigation import (PreintegrationParams, PreintegratedImu, ImuBias, NavState,
                                  ImuFactor, GpsFactor)

    params = PreintegrationParams.make_u(9.81, accel_sigma=0.01, gyro_sigma=1e-3,
                                         integration_sigma=1e-4)
    pim = PreintegratedImu(params, ImuBias())
    pim.integrate(accel, gyro, dt)                   # (n, 3), (n, 3), dt: one numba loop
    graph.add(ImuFactor(X(0), V(0), X(1), V(1), B(0), pim))
    graph.add(GpsFactor(X(1), position, Isotropic.sigma(3, 1.0)))
    initial.add(X(1), pim.predict(NavState.from_pose_velocity(pose0, v0), bias0).pose())

Modules: ``navstate`` (the NavState manifold; kernels in ``_navstate_kernels``), ``bias``
(ImuBias), ``params`` (PreintegrationParams), ``preintegration`` (PreintegratedImu,
PreintegratedCombinedImu; loops in ``_preint_kernels``), ``factors`` (ImuFactor,
CombinedImuFactor, GpsFactor; kernels in ``_imu_kernels``), ``scenario`` (true trajectories and
noisy IMU samples: ConstantTwistScenario, AcceleratingScenario, ScenarioRunner). The symbolic
twin of NavState for ``@fgopt.factor`` is :class:`fgopt.symbolic.NavState`.
"""

from .bias import ImuBias as ImuBias
from .factors import CombinedImuFactor as CombinedImuFactor
from .factors import GpsFactor as GpsFactor
from .factors import ImuFactor as ImuFactor
from .navstate import NavState as NavState
from .params import PreintegrationParams as PreintegrationParams
from .preintegration import PreintegratedCombinedImu as PreintegratedCombinedImu
from .preintegration import PreintegratedImu as PreintegratedImu
from .scenario import AcceleratingScenario as AcceleratingScenario
from .scenario import ConstantTwistScenario as ConstantTwistScenario
from .scenario import ScenarioRunner as ScenarioRunner

#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["ImuBias", "CombinedImuFactor", "GpsFactor", "ImuFactor", "NavState",
           "PreintegrationParams", "PreintegratedCombinedImu", "PreintegratedImu",
           "AcceleratingScenario", "ConstantTwistScenario", "ScenarioRunner"]
