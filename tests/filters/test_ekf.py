"""fgopt.filters.ManifoldEKF: the error-state EKF over products of groups and vectors.

Checked against GTSAM 4.3's NavStateImuEKF (same dynamics, same inputs: equal states and
covariances), against the textbook linear Kalman filter (vector states), against a hand
computation for a group-valued measurement with the covariance reset, for statistical
consistency (NEES) on a simulated 15-state IMU + GPS run, and for bad input (clear errors,
filter untouched).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import fgopt
from fgopt.filters import ManifoldEKF
from fgopt.manifolds import SE3, SO3
from fgopt.symbolic import M33, V2, V3, Pose3, Rot3, Scalar

GRAVITY = 9.81


# ---------------------------------------------------------------------- models
def ins(R: Rot3, p: V3, v: V3, bg: V3, ba: V3, gyro: V3, accel: V3, dt: Scalar):
    """Strapdown step with gyro / accelerometer biases (a 15-DOF error state)."""
    a = R * (accel - ba) + V3(0, 0, -GRAVITY)
    return R * Rot3.exp((gyro - bg) * dt), p + v * dt + a * (dt * dt / 2), v + a * dt, bg, ba


def gps(p: V3) -> V3:
    return p


def _skew(w):
    return M33([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


def navstate_dynamics(R: Rot3, p: V3, v: V3, gyro: V3, accel: V3, dt: Scalar):
    """Exact integration of constant body rate and specific force (GTSAM's NavStateImuEKF:
    X+ = W(g, dt) phi_dt(X) U(w, f, dt)), with J_l and the double integral as series in W."""
    W = _skew(gyro * dt)
    Jl, N, Wk = M33.eye(), M33.eye() * 0.5, M33.eye()
    for k in range(1, 5):  # |w dt| <= 0.05 here: the W^5 term is below 1e-9 relative
        Wk = Wk * W
        Jl = Jl + Wk * (1.0 / math.factorial(k + 1))
        N = N + Wk * (1.0 / math.factorial(k + 2))
    g = V3(0, 0, -GRAVITY)
    return (R * Rot3.exp(gyro * dt), p + v * dt + g * (dt * dt / 2) + R * (N * accel) * (dt * dt),
            v + g * dt + R * (Jl * accel) * dt)


def heading(R: Rot3) -> Rot3:
    return R


def rotate(R: Rot3, w: V3, dt: Scalar):
    return R * Rot3.exp(w * dt)


def constant_velocity(p: V2, v: V2, dt: Scalar):
    return p + v * dt, v


def position2(p: V2) -> V2:
    return p


def range_to(p: V3, landmark: V3) -> Scalar:
    return (p - landmark).norm()


def _ins_filter(**kw):
    x0 = (SO3(), np.zeros(3), np.array([20.0, 0.0, 0.0]), np.zeros(3), np.zeros(3))
    return ManifoldEKF(ins, [gps], x0=x0, P0=np.eye(15), **kw)


@pytest.fixture(scope="module")
def ins_filter():
    return _ins_filter()


def _snapshot(ekf):
    return ekf.storage, ekf.covariance, ekf.num_predicts, ekf.num_updates


def _unchanged(ekf, snap):
    s, P, npred, nupd = snap
    return (np.array_equal(ekf.storage, s) and np.array_equal(ekf.covariance, P)
            and ekf.num_predicts == npred and ekf.num_updates == nupd)


# ---------------------------------------------------------------------- against GTSAM
def _gtsam_navstate_ekf(gtsam, rng):
    """A random NavState, a random SPD 9x9 covariance, and GTSAM's NavStateImuEKF started there
    (Z-up gravity; gyroscope / integration / accelerometer covariances 1e-4 / 1e-5 / 1e-3)."""
    R0, p0, v0 = SO3.random(rng), rng.normal(size=3), rng.normal(size=3) * 3
    A = rng.normal(size=(9, 9))
    P0 = A @ A.T * 0.01 + np.eye(9) * 0.01
    params = gtsam.PreintegrationParams.MakeSharedU(GRAVITY)
    params.setGyroscopeCovariance(np.eye(3) * 1e-4)
    params.setIntegrationCovariance(np.eye(3) * 1e-5)
    params.setAccelerometerCovariance(np.eye(3) * 1e-3)
    theirs = gtsam.NavStateImuEKF(gtsam.NavState(gtsam.Rot3(R0.matrix()), p0, v0), P0, params)
    return R0, p0, v0, P0, theirs


def test_matches_gtsam_navstate_imu_ekf():
    """Same dynamics, inputs, noise and GPS fix as GTSAM's NavStateImuEKF: equal state and
    covariance (to rounding) after 8 predicts and an update.

    GTSAM's NavState tangent is [dR, R^T dp, R^T dv] (its retract adds R dp), fgopt's product
    tangent is [dR, dp, dv], so P_fgopt = M P_gtsam M^T with M = diag(I, R, R); isotropic
    process noise is the same in both. Both filters update without the covariance reset
    (GTSAM performReset=False, fgopt reset=False): with the reset the two filters transport
    the covariance differently (GTSAM: d retract / d X; fgopt: the ESKF reset d / d delta).
    After an update the two charts reinterpret P at the corrected attitude differently, so this
    product-state comparison stops there; the NavState-state test below runs many cycles.
    """
    gtsam = pytest.importorskip("gtsam")
    if not hasattr(gtsam, "NavStateImuEKF"):
        pytest.skip("this GTSAM has no NavStateImuEKF")
    rng = np.random.default_rng(0)
    R0, p0, v0, P0, theirs = _gtsam_navstate_ekf(gtsam, rng)

    def M(R):
        out = np.eye(9)
        out[3:6, 3:6] = out[6:9, 6:9] = R
        return out

    ours = ManifoldEKF(navstate_dynamics, [gps], x0=(R0, p0, v0),
                       P0=M(R0.matrix()) @ P0 @ M(R0.matrix()).T, reset=False)
    dt = 0.01
    Q_state = np.diag([1e-4] * 3 + [1e-5] * 3 + [1e-3] * 3) * dt  # GTSAM: blockdiag(Cg, Ci, Ca) dt
    for _ in range(8):
        w, f = rng.normal(size=3) * 0.5, rng.normal(size=3) + [0, 0, GRAVITY]
        theirs.predict(w, f, dt)
        ours.predict(np.r_[w, f], dt, np.zeros((6, 6)), Q_state)
    X = theirs.state()
    R, p, v = ours.state
    assert np.allclose(R.matrix(), X.attitude().matrix(), atol=1e-13)
    assert np.allclose(p, X.position(), atol=1e-12) and np.allclose(v, X.velocity(), atol=1e-12)
    Mx = M(R.matrix())
    assert np.allclose(ours.covariance, Mx @ theirs.covariance() @ Mx.T, rtol=1e-10, atol=1e-14)

    z, R_gps = p + rng.normal(size=3) * 0.5, np.eye(3) * 0.3
    H = np.zeros((3, 9))
    H[:, 3:6] = R.matrix()  # d position / d (GTSAM tangent)
    theirs.updateWithVector(X.position(), H, z, R_gps, False)
    ours.update(z, R_gps, "gps")
    X = theirs.state()
    R2, p2, v2 = ours.state
    assert np.allclose(R2.matrix(), X.attitude().matrix(), atol=1e-13)
    assert np.allclose(p2, X.position(), atol=1e-12) and np.allclose(v2, X.velocity(), atol=1e-12)
    assert np.allclose(ours.covariance, Mx @ theirs.covariance() @ Mx.T, rtol=1e-10, atol=1e-14)


def test_navstate_state_matches_gtsam_over_predict_update_cycles():
    """With the state a NavState (fgopt.symbolic.NavState: GTSAM's chart R Exp(dR), p + R dP,
    v + R dV) the covariances are GTSAM's directly, and stay equal over three cycles of five
    predicts and a GPS update (no reset on either side)."""
    gtsam = pytest.importorskip("gtsam")
    if not hasattr(gtsam, "NavStateImuEKF"):
        pytest.skip("this GTSAM has no NavStateImuEKF")
    from fgopt.navigation import NavState
    from fgopt.symbolic import NavState as SymNavState

    def imu_step(X: SymNavState, gyro: V3, accel: V3, dt: Scalar) -> SymNavState:
        R, p, v = navstate_dynamics(X.attitude(), X.position(), X.velocity(), gyro, accel, dt)
        return SymNavState(R, p, v)

    def nav_gps(X: SymNavState) -> V3:
        return X.position()

    rng = np.random.default_rng(8)
    R0, p0, v0, P0, theirs = _gtsam_navstate_ekf(gtsam, rng)
    ours = ManifoldEKF(imu_step, [nav_gps], x0=[NavState(R0, p0, v0)], P0=P0, reset=False)
    dt, R_gps = 0.01, np.eye(3) * 0.3
    Q_state = np.diag([1e-4] * 3 + [1e-5] * 3 + [1e-3] * 3) * dt
    H = np.zeros((3, 9))
    for _ in range(3):
        for _ in range(5):
            w, f = rng.normal(size=3) * 0.5, rng.normal(size=3) + [0, 0, GRAVITY]
            theirs.predict(w, f, dt)
            ours.predict(np.r_[w, f], dt, np.zeros((6, 6)), Q_state)
        X = theirs.state()
        z = X.position() + rng.normal(size=3) * 0.5
        H[:, 3:6] = X.attitude().matrix()
        theirs.updateWithVector(X.position(), H, z, R_gps, False)
        ours.update(z, R_gps, "nav_gps")
        X, (mine,) = theirs.state(), ours.state
        assert isinstance(mine, NavState)
        assert np.allclose(mine.to_storage()[4:], np.r_[X.position(), X.velocity()], atol=1e-12)
        assert np.allclose(SO3(mine.to_storage()[:4]).matrix(), X.attitude().matrix(), atol=1e-13)
        assert np.allclose(ours.covariance, theirs.covariance(), rtol=1e-10, atol=1e-14)


# ---------------------------------------------------------------------- against the textbook
def test_vector_state_equals_the_linear_kalman_filter():
    """A constant-velocity model over V2 states is linear: predict and the Joseph-form update
    equal the textbook Kalman filter's to rounding, over 20 steps."""
    rng = np.random.default_rng(1)
    P = np.diag([1.0, 2.0, 0.5, 0.7])
    x = np.array([1.0, -2.0, 0.3, 0.1])
    ekf = ManifoldEKF(constant_velocity, [position2], x0=(x[:2], x[2:]), P0=P)
    dt = 0.1
    F = np.block([[np.eye(2), dt * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    Qs = np.diag([0.01, 0.01, 0.05, 0.05])
    Rm = np.array([[0.2, 0.05], [0.05, 0.3]])
    for k in range(20):
        ekf.predict(None, dt, np.zeros((0, 0)), Qs)
        x, P = F @ x, F @ P @ F.T + Qs
        if k % 3 == 0:
            z = rng.normal(size=2)
            ekf.update(z, Rm)
            y = z - H @ x
            S = H @ P @ H.T + Rm
            K = P @ H.T @ np.linalg.inv(S)
            x = x + K @ y
            A = np.eye(4) - K @ H
            P = A @ P @ A.T + K @ Rm @ K.T
            assert ekf.nis == pytest.approx(y @ np.linalg.solve(S, y), rel=1e-9)
            assert np.allclose(ekf.innovation_covariance, S, rtol=1e-12)
        assert np.allclose(ekf.storage, x, atol=1e-12)
        assert np.allclose(ekf.covariance, P, rtol=1e-12, atol=1e-15)


def test_group_measurement_with_reset_matches_hand_computation():
    """A Rot3 state measured by a Rot3 sensor: innovation Log(R^-1 z), H = -dy/dx (finite
    differences), Joseph update, correction R Exp(K y), then the reset P <- J_r(d) P J_r(d)^T."""
    rng = np.random.default_rng(2)
    R0 = SO3.random(rng)
    A = rng.normal(size=(3, 3))
    P0 = A @ A.T * 0.05 + np.eye(3) * 0.02
    ekf = ManifoldEKF(rotate, {"attitude": heading}, x0=[R0], P0=P0)
    z = R0 * SO3.exp(np.array([0.1, -0.05, 0.2]))
    Rm = np.diag([0.01, 0.02, 0.015])
    ekf.update(z, Rm, "attitude")

    y = R0.local(z)
    h = 1e-6
    J = np.stack([(R0.retract(e).local(z) - R0.retract(-e).local(z)) / (2 * h)
                  for e in np.eye(3) * h], axis=1)
    H = -J
    S = H @ P0 @ H.T + Rm
    K = P0 @ H.T @ np.linalg.inv(S)
    d = K @ y
    Aj = np.eye(3) - K @ H
    Pj = Aj @ P0 @ Aj.T + K @ Rm @ K.T
    th = np.linalg.norm(d)
    W = np.array([[0, -d[2], d[1]], [d[2], 0, -d[0]], [-d[1], d[0], 0]])
    Jr = np.eye(3) - (1 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * W @ W
    assert ekf.state[0].equals(R0.retract(d), 1e-8)  # H here is a finite difference
    assert np.allclose(ekf.innovation, y, atol=1e-12)
    assert np.allclose(ekf.covariance, Jr @ Pj @ Jr.T, rtol=1e-7, atol=1e-12)


# ---------------------------------------------------------------------- behaviour
def test_fifteen_state_ins_is_consistent_and_covariance_stays_spd():
    """Simulated IMU + GPS with the filter's own noise levels: position error at the GPS level,
    mean NEES / n near 1 (the covariance is honest), P exactly symmetric and PD throughout,
    quaternion of unit norm."""
    rng = np.random.default_rng(3)
    dt, steps, every = 0.01, 3000, 10
    s_g, s_a, s_bg, s_ba, s_gps = 2e-3, 2e-2, 1e-4, 1e-3, 0.5
    truth = _ins_filter()  # the generated process, used noise-free to simulate the truth
    x = [SO3(), np.zeros(3), np.array([20.0, 0, 0]), np.array([0.01, -0.01, 0.005]),
         np.array([0.05, -0.03, 0.02])]
    truth.set_state(x, np.eye(15))
    ekf = _ins_filter()
    P0 = np.diag([1e-4] * 3 + [1.0] * 3 + [0.1] * 3 + [1e-4] * 3 + [1e-2] * 3)
    e0 = rng.multivariate_normal(np.zeros(15), P0)
    ekf.set_state([x[0].retract(e0[:3]), x[1] + e0[3:6], x[2] + e0[6:9], x[3] + e0[9:12],
                   x[4] + e0[12:]], P0)
    Q = np.diag([s_g**2] * 3 + [s_a**2] * 3) / dt
    Q_state = np.diag([0.0] * 9 + [s_bg**2] * 3 + [s_ba**2] * 3) * dt
    nees, errs = [], []
    for k in range(steps):
        t = k * dt
        w_true = np.array([0.05 * np.sin(0.3 * t), 0.02, 0.1 * np.cos(0.1 * t)])
        f_true = truth["R"].matrix().T @ (np.array([0.2 * np.cos(0.2 * t), 0.5, 0.0])
                                          + [0, 0, GRAVITY])
        # the truth carries the biases in its state: the measured input is true + bias + noise
        u_true = np.r_[w_true + truth["bg"], f_true + truth["ba"]]
        truth.predict(u_true, dt, np.zeros((6, 6)))
        walk = np.r_[s_bg * rng.normal(size=3), s_ba * rng.normal(size=3)] * np.sqrt(dt)
        truth.set_state([*truth.state[:3], truth["bg"] + walk[:3], truth["ba"] + walk[3:]],
                        np.eye(15))
        noise = np.r_[s_g * rng.normal(size=3), s_a * rng.normal(size=3)] / np.sqrt(dt)
        ekf.predict(u_true + noise, dt, Q, Q_state)
        if (k + 1) % every == 0:
            ekf.update(truth["p"] + s_gps * rng.normal(size=3), np.eye(3) * s_gps**2)
        if k > steps // 3 and k % 25 == 0:
            e = np.concatenate([ekf["R"].local(truth["R"])]
                               + [truth[n] - ekf[n] for n in ("p", "v", "bg", "ba")])
            P = ekf.covariance
            nees.append(e @ np.linalg.solve(P, e))
            errs.append(np.linalg.norm(e[3:6]))
            assert np.array_equal(P, P.T) and np.linalg.eigvalsh(P).min() > 0
    assert abs(np.linalg.norm(ekf.storage[:4]) - 1.0) < 1e-14
    assert np.sqrt(np.mean(np.square(errs))) < 2 * s_gps
    assert 0.5 < np.mean(nees) / 15 < 1.6, np.mean(nees) / 15


def test_pose3_state_tracks_a_trajectory():
    """A Pose3 + V3 state (body twist integrated on SE(3)) with position fixes: converges from a
    wrong start, covariance PD."""
    def body_motion(T: Pose3, v: V3, w: V3, dt: Scalar):
        return T * Pose3(Rot3.exp(w * dt), v * dt), v

    def position(T: Pose3) -> V3:
        return T.translation()

    truth = SE3()
    v = np.array([2.0, 0.0, 0.1])
    ekf = ManifoldEKF(body_motion, [position], x0=(SE3(SO3(), [3.0, -2.0, 1.0]), v * 1.2),
                      P0=np.diag([0.01] * 3 + [9.0] * 3 + [1.0] * 3))
    w, dt = np.array([0.0, 0.0, 0.2]), 0.05
    Q = np.eye(3) * 1e-6 / dt
    for k in range(400):
        truth = truth * SE3.exp(np.r_[w * dt, v * dt])
        ekf.predict(w, dt, Q, np.diag([0.0] * 6 + [1e-6] * 3))
        if k % 5 == 0:
            ekf.update(truth.translation(), np.eye(3) * 0.01)
    T, _ = ekf.state
    assert np.linalg.norm(T.translation() - truth.translation()) < 0.2
    assert np.linalg.eigvalsh(ekf.covariance).min() > 0


def test_declared_manifold_state_tracks_a_trajectory():
    """A state on SE_2(3) declared with @fgopt.manifold (fgopt.symbolic.SE23: attitude,
    velocity, position, coupled by the group exponential) plus a gyro bias: converges from a
    wrong start with position fixes; the stored quaternion stays of unit norm (the declared
    normalize projects the process output)."""
    from fgopt.symbolic import SE23, V9

    def extended(X: SE23, bg: V3, gyro: V3, accel: V3, dt: Scalar):
        R = X.rotation()
        body_v = R.inverse() * X.velocity()
        body_g = R.inverse() * V3(0, 0, -GRAVITY)
        a = accel + body_g
        xi = V9(list((gyro - bg) * dt) + list(a * dt) + list(body_v * dt + a * (dt * dt / 2)))
        return X.retract(xi), bg

    def position(X: SE23) -> V3:
        return X.position()

    start = SE23.Value([0.0, 0.0, 0.0, 1.0, 10.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    truth = ManifoldEKF(extended, [position], x0=(start, np.array([0.02, -0.01, 0.01])),
                        P0=np.eye(12))
    ekf = ManifoldEKF(extended, [position],
                      x0=(start.retract(np.r_[0.05, -0.05, 0.1, 1.0, -1.0, 0.5, 3, -2, 1]),
                          np.zeros(3)),
                      P0=np.diag([0.01] * 3 + [2.0] * 3 + [10.0] * 3 + [1e-3] * 3))
    dt = 0.01
    Q = np.diag([1e-6] * 3 + [1e-4] * 3) / dt
    for k in range(1500):
        u = np.r_[0.1 * np.sin(0.01 * k), 0.05, 0.2, 0.3 * np.cos(0.02 * k), 0.5, GRAVITY]
        truth.predict(u, dt, np.zeros((6, 6)))
        ekf.predict(u, dt, Q, np.diag([0.0] * 9 + [1e-10] * 3))
        if k % 10 == 9:
            ekf.update(truth["X"].position(), np.eye(3) * 0.01)
    X, X_true = ekf["X"], truth["X"]
    assert np.linalg.norm(X.position() - X_true.position()) < 0.2
    assert np.linalg.norm(X.local(X_true)[:3]) < 0.05  # attitude
    assert abs(np.linalg.norm(ekf.storage[:4]) - 1.0) < 1e-12
    assert np.linalg.eigvalsh(ekf.covariance).min() > 0


def test_measurement_parameters_and_predicted_measurement():
    """A range measurement to a landmark given at update time (keyword parameter, scalar
    measurement); predict_measurement evaluates h at the estimate."""
    def still(p: V3, dt: Scalar):
        return p

    ekf = ManifoldEKF(still, {"range": range_to}, x0=[np.array([1.0, 2.0, 0.0])],
                      P0=np.eye(3) * 4.0)
    truth = np.array([0.0, 0.0, 0.0])
    rng = np.random.default_rng(4)
    for _ in range(60):
        lm = rng.normal(size=3) * 10
        ekf.update(np.linalg.norm(truth - lm), np.array([[1e-4]]), "range", landmark=lm)
    assert np.linalg.norm(ekf["p"] - truth) < 0.05
    lm = np.array([3.0, 4.0, 0.0])
    assert ekf.predict_measurement("range", landmark=lm) == pytest.approx(
        np.linalg.norm(ekf["p"] - lm))
    with pytest.raises(fgopt.FgoptError, match="missing \\['landmark'\\]"):
        ekf.update(1.0, np.array([[1e-4]]), "range")


def test_state_access_repr_and_jacobians(ins_filter):
    """State by name and in order, marginals, the informative repr, and F, G."""
    ekf = ins_filter
    assert ekf.state_names == ("R", "p", "v", "bg", "ba") and ekf.dim == 15
    assert ekf.input_names == ("gyro", "accel") and ekf.measurement_names == ("gps",)
    assert isinstance(ekf["R"], SO3) and ekf.marginal("v").shape == (3, 3)
    r = repr(ekf)
    assert "ManifoldEKF ins" in r and "R: Rot3" in r and "gps -> V3" in r and "dim 15" in r
    F, G = ekf.jacobians(np.r_[0.1, 0.2, 0.3, 0.0, 0.0, GRAVITY], 0.01)
    assert F.shape == (15, 15) and G.shape == (15, 6)
    assert np.allclose(F[3:6, 6:9], np.eye(3) * 0.01)  # d p+ / d v
    assert np.allclose(F[9:, 9:], np.eye(6))  # biases are constant


def test_predict_many_equals_single_predicts_and_is_atomic():
    """predict_many over a block equals the single predicts bit for bit; a non-finite row
    raises naming the row and restores the state and covariance from before the call."""
    rng = np.random.default_rng(5)
    U = np.column_stack([rng.normal(size=(50, 3)) * 0.1,
                         rng.normal(size=(50, 3)) + [0, 0, GRAVITY]])
    Q, Qs = np.eye(6) * 1e-4, np.diag([0.0] * 9 + [1e-8] * 6)
    one, many = _ins_filter(), _ins_filter()
    for u in U:
        one.predict(u, 0.01, Q, Qs)
    many.predict_many(U, 0.01, Q, Qs)
    assert np.array_equal(one.storage, many.storage)
    assert np.array_equal(one.covariance, many.covariance) and many.num_predicts == 50
    bad = U.copy()
    bad[30, 4] = np.inf
    snap = _snapshot(many)
    with pytest.raises(fgopt.FgoptError, match="row 30.*u\\[4\\] is not finite"):
        many.predict_many(bad, 0.01, Q, Qs)
    assert _unchanged(many, snap)
    with pytest.raises(fgopt.FgoptError, match="row 2.*dt must be positive"):
        many.predict_many(U[:5], [0.01, 0.01, -0.01, 0.01, 0.01], Q, Qs)
    assert _unchanged(many, snap)


# ---------------------------------------------------------------------- bad input
BAD_PREDICTS = {
    "u wrong size": ({"u": np.zeros(5)}, "u needs 6 numbers"),
    "u nan": ({"u": np.r_[0, 0, np.nan, 0, 0, 9.8]}, "u\\[2\\] is not finite"),
    "dt zero": ({"dt": 0.0}, "dt must be positive"),
    "dt nan": ({"dt": np.nan}, "dt must be positive"),
    "dt text": ({"dt": "x"}, "dt must be a number"),
    "Q shape": ({"Q": np.eye(5)}, "Q must be 6x6"),
    "Q negative": ({"Q": -np.eye(6)}, "Q is not positive semi-definite"),
    "Q asymmetric": ({"Q": np.eye(6) + np.triu(np.ones((6, 6)), 1)}, "Q is not symmetric"),
    "Q inf": ({"Q": np.full((6, 6), np.inf)}, "Q is not finite"),
    "Q_state negative": ({"Q_state": -np.eye(15)}, "Q_state is not positive semi-definite"),
}


@pytest.mark.parametrize("case", list(BAD_PREDICTS))
def test_bad_predict_raises_and_leaves_the_filter_unchanged(ins_filter, case):
    """Every bad predict argument gives an FgoptError naming it; state, P, counts unchanged."""
    kwargs = {"u": np.r_[0.01, 0.0, 0.0, 0.0, 0.0, GRAVITY], "dt": 0.01, "Q": np.eye(6) * 1e-4}
    change, message = BAD_PREDICTS[case]
    kwargs.update(change)
    snap = _snapshot(ins_filter)
    with pytest.raises(fgopt.FgoptError, match=message):
        ins_filter.predict(**kwargs)
    assert _unchanged(ins_filter, snap)


BAD_UPDATES = {
    "z wrong size": ({"z": np.zeros(2)}, "'z'.*3 numbers"),
    "z nan": ({"z": np.array([0.0, np.nan, 0.0])}, "z\\[1\\] is not finite"),
    "z nan list": ({"z": [0.0, np.nan, 0.0]}, "'z' is not finite"),
    "R not PD": ({"R": np.diag([1.0, 0.0, 1.0])}, "R is not positive definite"),
    "R shape": ({"R": np.eye(2)}, "R must be 3x3"),
    "R asymmetric": ({"R": np.array([[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]])},
                     "R is not symmetric"),
    "unknown which": ({"which": "lidar"}, "no measurement 'lidar'"),
    "unexpected parameter": ({"lever": np.zeros(3)}, "unknown \\['lever'\\]"),
}


@pytest.mark.parametrize("case", list(BAD_UPDATES))
def test_bad_update_raises_and_leaves_the_filter_unchanged(ins_filter, case):
    """Every bad update argument gives an FgoptError naming it; state, P, counts unchanged."""
    kwargs = {"z": np.array([1.0, 0.5, 0.0]), "R": np.eye(3), "which": "gps"}
    change, message = BAD_UPDATES[case]
    kwargs.update(change)
    snap = _snapshot(ins_filter)
    with pytest.raises(fgopt.FgoptError, match=message):
        ins_filter.update(**kwargs)
    assert _unchanged(ins_filter, snap)


def test_bad_construction_raises_fgopt_errors():
    """No dt argument, unknown state names, wrong x0 / P0, a measurement with the wrong type."""
    x0 = [SO3(), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)]

    def no_dt(p: V3, v: V3):
        return p + v, v

    def bad_gps(p: Rot3) -> Rot3:
        return p

    with pytest.raises(fgopt.FgoptError, match="no time-step argument 'dt'"):
        ManifoldEKF(no_dt, [], x0=[np.zeros(3), np.zeros(3)], P0=np.eye(6))
    with pytest.raises(fgopt.FgoptError, match="must name distinct arguments"):
        ManifoldEKF(ins, [gps], x0=x0, P0=np.eye(15), state=["R", "q"])
    with pytest.raises(fgopt.FgoptError, match="x0 has 2 values"):
        ManifoldEKF(ins, [gps], x0=x0[:2], P0=np.eye(15))
    with pytest.raises(fgopt.FgoptError, match="P0 is not positive definite"):
        ManifoldEKF(ins, [gps], x0=x0, P0=-np.eye(15))
    with pytest.raises(fgopt.FgoptError, match="P0 must be 15x15"):
        ManifoldEKF(ins, [gps], x0=x0, P0=np.eye(9))
    with pytest.raises(fgopt.FgoptError, match="takes 'p' as Rot3"):
        ManifoldEKF(ins, [bad_gps], x0=x0, P0=np.eye(15))
