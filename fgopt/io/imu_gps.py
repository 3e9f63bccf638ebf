"""IMU + GPS CSV files of GTSAM's ``ImuFactorsExample``, and that example's factor graph.

Format (read from GTSAM's ``examples/ImuFactorsExample.cpp``), one record per line:

* ``i,x,y,z,qx,qy,qz,qw,vx,vy,vz``: the initial state (first line);
* ``0,ax,ay,az,wx,wy,wz``: an IMU sample (specific force, angular rate; body frame), held for
  the example's fixed ``dt = 0.005`` s;
* ``1,x,y,z,qx,qy,qz,qw``: a GPS fix (the example uses the position only; the attitude is
  ground truth for comparisons).

An all-zero quaternion (the initial line of ``imuAndGPSdata.csv``) is read as the identity, as
GTSAM's ``Rot3::Quaternion`` turns it into the identity matrix.

:func:`imu_factors_example` builds the example's problem as one batch: a state ``(x_k, v_k,
b_k)`` at every GPS fix, an ImuFactor with the samples since the previous fix, a bias
BetweenFactor, and a GpsFactor on ``x_k``; priors on the first state; initial values from
chaining ``PreintegratedImu.predict`` from the initial state (dead reckoning, zero bias).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import FileFormatError
from ..factors import BetweenFactor, PriorFactor
from ..graph import FactorGraph
from ..key import Key, key
from ..manifolds import SE3, SO3
from ..navigation import (CombinedImuFactor, GpsFactor, ImuBias, ImuFactor, NavState,
                          PreintegratedCombinedImu, PreintegratedImu, PreintegrationParams)
from ..noise import Diagonal, Isotropic
from ..variables import Variables

log = logging.getLogger("fgopt.io")

#: The sample period hard-coded in GTSAM's ImuFactorsExample.
EXAMPLE_DT = 0.005


@dataclass
class ImuGpsData:
    """Contents of an ImuFactorsExample CSV file."""

    initial_pose: SE3
    initial_velocity: np.ndarray
    imu: np.ndarray
    """``(n, 6)``: accelerometer (m/s^2) then gyroscope (rad/s), body frame."""
    gps: np.ndarray
    """``(m, 7)``: position ``x y z`` then the (unused) quaternion ``qx qy qz qw``."""
    imu_before_gps: np.ndarray
    """``(m,)``: number of IMU samples that precede each GPS line."""
    path: str = ""


def _quaternion(q: np.ndarray, path: str, line: int) -> SO3:
    n = float(np.linalg.norm(q))
    if n == 0.0:
        log.info("%s:%d: all-zero quaternion read as the identity (as GTSAM)", path, line)
        return SO3()
    if not abs(n - 1.0) < 1e-3:
        raise FileFormatError(f"quaternion {q.tolist()} is not a unit quaternion", path, line)
    return SO3(q)


def read_imu_gps_csv(path: str | os.PathLike) -> ImuGpsData:
    """Read an ImuFactorsExample CSV (module docstring); malformed lines raise
    :class:`~fgopt.errors.FileFormatError` with ``path:line``."""
    path = os.fspath(path)
    imu, gps, before = [], [], []
    init = None
    with open(path) as fh:
        for lineno, raw in enumerate(fh, 1):
            text = raw.strip()
            if not text:
                continue
            parts = text.split(",")
            tag = parts[0].strip()
            try:
                nums = [float(p) for p in parts[1:]]
            except ValueError:
                raise FileFormatError(f"non-numeric field in {text!r}", path, lineno) from None
            want = {"i": 10, "0": 6, "1": 7}.get(tag)
            if want is None:
                raise FileFormatError(f"unknown record type {tag!r} (expected i, 0 or 1)",
                                      path, lineno)
            if len(nums) != want:
                raise FileFormatError(f"record {tag!r} needs {want} numbers, got {len(nums)}",
                                      path, lineno)
            if not np.all(np.isfinite(nums)):
                raise FileFormatError(f"non-finite number in {text!r}", path, lineno)
            if tag == "i":
                if init is not None:
                    raise FileFormatError("a second initial-state line", path, lineno)
                rot = _quaternion(np.array(nums[3:7]), path, lineno)
                init = (SE3(rot, nums[0:3]), np.array(nums[7:10]))
            elif init is None:
                raise FileFormatError("the first record must be the initial state ('i')",
                                      path, lineno)
            elif tag == "0":
                imu.append(nums)
            else:
                gps.append(nums)
                before.append(len(imu))
    if init is None:
        raise FileFormatError("no initial-state line", path)
    return ImuGpsData(init[0], init[1], np.array(imu, dtype=float).reshape(-1, 6),
                      np.array(gps, dtype=float).reshape(-1, 7),
                      np.array(before, dtype=np.int64), path)


def example_params(combined: bool = False) -> PreintegrationParams:
    """The IMU parameters of GTSAM's ImuFactorsExample (NED frame with zero gravity, as the
    example's ``MakeSharedD(0.0)``)."""
    kw = {}
    if combined:
        kw = dict(bias_acc_rw_sigma=0.004905, bias_gyro_rw_sigma=0.000001454441043)
    return PreintegrationParams.make_d(0.0, accel_sigma=0.0003924,
                                       gyro_sigma=0.000205689024915, integration_sigma=1e-4,
                                       **kw)


@dataclass
class ImuExampleProblem:
    """The ImuFactorsExample problem: ``graph``, dead-reckoned ``initial`` values, the
    preintegrations (one per IMU factor) and the GPS positions per state (NaN where none)."""

    graph: FactorGraph
    initial: Variables
    pims: list = field(repr=False)
    gps_positions: np.ndarray = field(repr=False)
    num_states: int = 0


def X(i: int) -> Key:
    return key("x", i)


def V(i: int) -> Key:
    return key("v", i)


def B(i: int) -> Key:
    return key("b", i)


def imu_factors_example(data: ImuGpsData | str | os.PathLike, *, dt: float = EXAMPLE_DT,
                        combined: bool = False, gps_every: int = 1,
                        params: PreintegrationParams | None = None) -> ImuExampleProblem:
    """GTSAM's ImuFactorsExample as one batch problem (module docstring). Keys ``x_k``
    (SE3), ``v_k`` (R^3), ``b_k`` (R^6) as GTSAM's ``X(k), V(k), B(k)``. ``combined``: use
    CombinedImuFactor (no bias BetweenFactor), as the example's ``-c`` flag; ``gps_every``: keep
    the GPS factor of every ``gps_every``-th state only."""
    if not isinstance(data, ImuGpsData):
        data = read_imu_gps_csv(data)
    params = params or example_params(combined)
    graph, initial = FactorGraph(), Variables()
    bias_noise = Isotropic.sigma(6, 1e-3)
    graph.add(PriorFactor(X(0), data.initial_pose,
                          Diagonal.sigmas([0.01, 0.01, 0.01, 0.5, 0.5, 0.5])))
    graph.add(PriorFactor(V(0), data.initial_velocity, Isotropic.sigma(3, 0.1)))
    graph.add(PriorFactor(B(0), np.zeros(6), bias_noise))
    initial.add(X(0), data.initial_pose)
    initial.add(V(0), data.initial_velocity)
    initial.add(B(0), np.zeros(6))
    state = NavState.from_pose_velocity(data.initial_pose, data.initial_velocity)
    bias = ImuBias()
    gps_noise = Isotropic.sigma(3, 1.0)
    pims = []
    start = 0
    m = data.gps.shape[0]
    gps_positions = np.full((m + 1, 3), np.nan)
    for k in range(1, m + 1):
        stop = int(data.imu_before_gps[k - 1])
        pim = (PreintegratedCombinedImu if combined else PreintegratedImu)(params, bias)
        pim.integrate(data.imu[start:stop, :3], data.imu[start:stop, 3:], dt)
        start = stop
        pims.append(pim)
        if combined:
            graph.add(CombinedImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), B(k), pim))
        else:
            graph.add(ImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), pim))
            graph.add(BetweenFactor(B(k - 1), B(k), np.zeros(6), bias_noise))
        if k % gps_every == 0:
            graph.add(GpsFactor(X(k), data.gps[k - 1, :3], gps_noise))
            gps_positions[k] = data.gps[k - 1, :3]
        state = pim.predict(state, bias)
        initial.add(X(k), state.pose())
        initial.add(V(k), state.velocity())
        initial.add(B(k), bias.vector())
    return ImuExampleProblem(graph, initial, pims, gps_positions, m + 1)
