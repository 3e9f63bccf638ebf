"""Ceres through pyceres 2.6, with **Python callback costs**.

pyceres ships no pose-graph or reprojection cost, so each residual block here is a Python
``pyceres.CostFunction`` subclass with hand-written analytic Jacobians (Ceres calls back into
Python once per residual block per evaluation). The residuals follow Ceres' own examples:

* 2D (``examples/slam/pose_graph_2d``): one ``x, y, yaw`` block per pose;
  ``e = [R(yaw_a)^T (p_b - p_a) - p_ab, wrap(yaw_b - yaw_a - yaw_ab)]``.
* 3D (``examples/slam/pose_graph_3d``): position (3) and quaternion (4, ``EigenQuaternionManifold``,
  ``x, y, z, w``) blocks; ``e = [R(q_a)^T (p_b - p_a) - p_ab, 2 vec(q_ab ⊗ (q_a^-1 ⊗ q_b)^-1)]``.
* BAL (``examples/bundle_adjuster``): Snavely camera (9) and point (3) blocks, ``SPARSE_SCHUR``.

Whitening uses the upper Cholesky factor ``R`` (``R^T R = information``). Ceres' examples use
``information.llt().matrixL()``, which only agrees for diagonal information; we use the correct
factor so that Ceres optimizes the same weighting as everyone else. Gauge: the first pose is held
constant (as the examples do). Solver: ``SPARSE_NORMAL_CHOLESKY`` (SuiteSparse) for pose graphs,
``max_num_iterations=200`` as the pose-graph examples set; Ceres' default tolerances otherwise.
"""

from __future__ import annotations

import math

import numpy as np

from . import SolveOutput


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _quat_left(p):
    """4x4 matrix L(p) with p ⊗ q = L(p) q, quaternions stored x, y, z, w."""
    x, y, z, w = p
    return np.array([[w, -z, y, x], [z, w, -x, y], [-y, x, w, z], [-x, -y, -z, w]])


def _quat_right(q):
    """4x4 matrix R(q) with p ⊗ q = R(q) p."""
    x, y, z, w = q
    return np.array([[w, z, -y, x], [-z, w, x, y], [y, -x, w, z], [-x, -y, -z, w]])


def _quat_mul(p, q):
    return _quat_left(p) @ q


_CONJ = np.array([-1.0, -1.0, -1.0, 1.0])


def _pyceres():
    import pyceres

    return pyceres


def _make_cost_classes():
    pyceres = _pyceres()

    class Pose2Between(pyceres.CostFunction):
        """Ceres pose_graph_2d error term; blocks: pose_a (x, y, yaw), pose_b."""

        def __init__(self, z, sqrt_info):
            super().__init__()
            self.set_num_residuals(3)
            self.set_parameter_block_sizes([3, 3])
            self.zx, self.zy, self.zt = float(z[0]), float(z[1]), float(z[2])
            self.S = np.ascontiguousarray(sqrt_info)

        def Evaluate(self, parameters, residuals, jacobians):
            a, b = parameters
            c, s = math.cos(a[2]), math.sin(a[2])
            dx, dy = b[0] - a[0], b[1] - a[1]
            e = np.array([c * dx + s * dy - self.zx, -s * dx + c * dy - self.zy,
                          math.remainder(b[2] - a[2] - self.zt, 2.0 * math.pi)])
            residuals[:] = self.S @ e
            if jacobians is not None:
                RT = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
                if jacobians[0] is not None:
                    Ja = -RT
                    Ja[0, 2] = -s * dx + c * dy
                    Ja[1, 2] = -c * dx - s * dy
                    jacobians[0][:] = (self.S @ Ja).ravel()
                if jacobians[1] is not None:
                    jacobians[1][:] = (self.S @ RT).ravel()
            return True

    class Pose3Between(pyceres.CostFunction):
        """Ceres pose_graph_3d error term; blocks: p_a (3), q_a (4), p_b (3), q_b (4)."""

        def __init__(self, z, sqrt_info):
            super().__init__()
            self.set_num_residuals(6)
            self.set_parameter_block_sizes([3, 4, 3, 4])
            self.pm = np.array(z[:3], dtype=float)
            self.qm = np.array(z[3:7], dtype=float)
            self.Lqm = _quat_left(self.qm)
            self.S = np.ascontiguousarray(sqrt_info)

        def Evaluate(self, parameters, residuals, jacobians):
            pa, qa, pb, qb = parameters
            ux, uy, uz, w = qa.tolist()
            dx, dy, dz = (pb - pa).tolist()
            # f = conj(q_a) * d as Eigen evaluates it: d - 2w (u x d) + 2 u x (u x d)
            c0, c1, c2 = uy * dz - uz * dy, uz * dx - ux * dz, ux * dy - uy * dx
            e0, e1, e2 = uy * c2 - uz * c1, uz * c0 - ux * c2, ux * c1 - uy * c0
            pm = self.pm
            # A = q_m * conj(q_b); delta = A * q_a (quaternions x, y, z, w)
            mx, my, mz, mw = self.qm
            bx, by, bz, bw = (-qb[0], -qb[1], -qb[2], qb[3])
            Ax = mw * bx + bw * mx + my * bz - mz * by
            Ay = mw * by + bw * my + mz * bx - mx * bz
            Az = mw * bz + bw * mz + mx * by - my * bx
            Aw = mw * bw - mx * bx - my * by - mz * bz
            r = np.array([dx - 2 * w * c0 + 2 * e0 - pm[0], dy - 2 * w * c1 + 2 * e1 - pm[1],
                          dz - 2 * w * c2 + 2 * e2 - pm[2],
                          2 * (Aw * ux + w * Ax + Ay * uz - Az * uy),
                          2 * (Aw * uy + w * Ay + Az * ux - Ax * uz),
                          2 * (Aw * uz + w * Az + Ax * uy - Ay * ux)])
            S = self.S
            residuals[:] = S @ r
            if jacobians is None:
                return True
            uu = ux * ux + uy * uy + uz * uz
            a = 1.0 - 2.0 * uu
            M = [[a + 2 * ux * ux, 2 * ux * uy + 2 * w * uz, 2 * ux * uz - 2 * w * uy],
                 [2 * uy * ux - 2 * w * uz, a + 2 * uy * uy, 2 * uy * uz + 2 * w * ux],
                 [2 * uz * ux + 2 * w * uy, 2 * uz * uy - 2 * w * ux, a + 2 * uz * uz]]
            ud = ux * dx + uy * dy + uz * dz
            u = (ux, uy, uz)
            d = (dx, dy, dz)
            # df/du = 2w [d]x + 2 ((u.d) I + u d^T - 2 d u^T); df/dw = -2 (u x d)
            Dd = [[0.0, -dz, dy], [dz, 0.0, -dx], [-dy, dx, 0.0]]
            Fu = [[2 * w * Dd[i][j] + 2 * ((ud if i == j else 0.0) + u[i] * d[j] - 2 * d[i] * u[j])
                   for j in range(3)] for i in range(3)]
            J = np.zeros((6, 14))
            Mn = np.array(M)
            J[:3, 0:3] = -Mn
            J[:3, 3:6] = Fu
            J[:3, 6] = (-2 * c0, -2 * c1, -2 * c2)
            J[:3, 7:10] = Mn
            J[3:, 3:7] = ((2 * Aw, -2 * Az, 2 * Ay, 2 * Ax), (2 * Az, 2 * Aw, -2 * Ax, 2 * Ay),
                          (-2 * Ay, 2 * Ax, 2 * Aw, 2 * Az))
            J[3:, 10:14] = 2.0 * (self.Lqm @ _quat_right(qa))[:3] * _CONJ
            SJ = S @ J
            for k, (lo, hi) in enumerate(((0, 3), (3, 7), (7, 10), (10, 14))):
                if jacobians[k] is not None:
                    jacobians[k][:] = SJ[:, lo:hi].ravel()
            return True

    class Snavely(pyceres.CostFunction):
        """Ceres' SnavelyReprojectionError with analytic Jacobians; blocks camera (9), point (3)."""

        def __init__(self, uv):
            super().__init__()
            self.set_num_residuals(2)
            self.set_parameter_block_sizes([9, 3])
            self.u, self.v = float(uv[0]), float(uv[1])

        def Evaluate(self, parameters, residuals, jacobians):
            cam, X = parameters
            aa = cam[0:3]
            th2 = aa @ aa
            if th2 > 1e-24:
                th = math.sqrt(th2)
                K = _skew(aa / th)
                st, ct = math.sin(th), math.cos(th)
                R = np.eye(3) + st * K + (1.0 - ct) * (K @ K)
            else:
                th, st, ct = 0.0, 0.0, 1.0
                K = _skew(aa)
                R = np.eye(3) + K
            P = R @ X + cam[3:6]
            iz = 1.0 / P[2]
            px, py = -P[0] * iz, -P[1] * iz
            f, k1, k2 = cam[6], cam[7], cam[8]
            r2 = px * px + py * py
            dist = 1.0 + r2 * (k1 + k2 * r2)
            residuals[0] = f * dist * px - self.u
            residuals[1] = f * dist * py - self.v
            if jacobians is not None:
                # d pred / d P
                g = 2.0 * (k1 + 2.0 * k2 * r2)
                Dp = f * np.array([[dist + g * px * px, g * px * py],
                                   [g * px * py, dist + g * py * py]])
                dpdP = np.array([[-iz, 0.0, -px * iz], [0.0, -iz, -py * iz]])
                JP = Dp @ dpdP
                if jacobians[0] is not None:
                    if th > 0.0:
                        Ka = _skew(aa)
                        Jr = (np.eye(3) - (1.0 - ct) / th2 * Ka
                              + (th - st) / (th2 * th) * (Ka @ Ka))
                    else:
                        Jr = np.eye(3)
                    Jc = np.empty((2, 9))
                    Jc[:, 0:3] = JP @ (-(R @ _skew(X)) @ Jr)
                    Jc[:, 3:6] = JP
                    Jc[0, 6], Jc[1, 6] = dist * px, dist * py
                    Jc[0, 7], Jc[1, 7] = f * r2 * px, f * r2 * py
                    Jc[0, 8], Jc[1, 8] = f * r2 * r2 * px, f * r2 * r2 * py
                    jacobians[0][:] = Jc.ravel()
                if jacobians[1] is not None:
                    jacobians[1][:] = (JP @ R).ravel()
            return True

    class BearingRange(pyceres.CostFunction):
        """Bearing and range from a pose (x, y, yaw) to a known landmark."""

        def __init__(self, lm, z, sigmas):
            super().__init__()
            self.set_num_residuals(2)
            self.set_parameter_block_sizes([3])
            self.lx, self.ly = float(lm[0]), float(lm[1])
            self.b, self.r = float(z[0]), float(z[1])
            self.ib, self.ir = 1.0 / sigmas[0], 1.0 / sigmas[1]

        def Evaluate(self, parameters, residuals, jacobians):
            x = parameters[0]
            c, s = math.cos(x[2]), math.sin(x[2])
            dx, dy = self.lx - x[0], self.ly - x[1]
            lx, ly = c * dx + s * dy, -s * dx + c * dy
            rho2 = lx * lx + ly * ly
            rho = math.sqrt(rho2)
            residuals[0] = math.remainder(math.atan2(ly, lx) - self.b, 2.0 * math.pi) * self.ib
            residuals[1] = (rho - self.r) * self.ir
            if jacobians is not None and jacobians[0] is not None:
                # dl/dx = -R^T, dl/dyaw = [ly, -lx]
                dbl = np.array([-ly, lx]) / rho2
                drl = np.array([lx, ly]) / rho
                RT = np.array([[c, s], [-s, c]])
                J = np.empty((2, 3))
                J[0, :2] = -(dbl @ RT) * self.ib
                J[0, 2] = -self.ib
                J[1, :2] = -(drl @ RT) * self.ir
                J[1, 2] = (drl[0] * ly - drl[1] * lx) * self.ir
                jacobians[0][:] = J.ravel()
            return True

    return Pose2Between, Pose3Between, Snavely, BearingRange


_CLASSES = None


def cost_classes():
    global _CLASSES
    if _CLASSES is None:
        _CLASSES = _make_cost_classes()
    return _CLASSES


class CeresRunner:
    name = "ceres"
    pinning = "SolverOptions.num_threads = 1; BLAS env vars = 1"
    note = "pyceres, Python callback costs (analytic Jacobians)"

    def version(self) -> str:
        import importlib.metadata as md

        return "pyceres " + md.version("pyceres")

    def supports(self, spec) -> str | None:
        return None

    def load(self, spec):
        from .. import problems

        pyceres = _pyceres()
        Pose2Between, Pose3Between, Snavely, BearingRange = cost_classes()
        data = problems.load(spec.name)
        prob = pyceres.Problem()
        costs = []  # keep the Python cost objects alive
        st = {"kind": spec.kind, "problem": prob, "costs": costs}
        if spec.kind == "pose2d":
            X = np.ascontiguousarray(data.poses, dtype=float).copy()
            S = data.sqrt_info("g2o")
            for k in range(len(data.edge_i)):
                c = Pose2Between(data.meas[k], S[k])
                costs.append(c)
                prob.add_residual_block(c, None, [X[data.edge_i[k]], X[data.edge_j[k]]])
            prob.set_parameter_block_constant(X[0])
            st.update(arrays=[X], init=[X.copy()], max_iter=200)
        elif spec.kind == "pose3d":
            Pp = np.ascontiguousarray(data.poses[:, :3]).copy()
            Q = np.ascontiguousarray(data.poses[:, 3:7]).copy()
            S = data.sqrt_info("g2o")
            for k in range(len(data.edge_i)):
                i, j = data.edge_i[k], data.edge_j[k]
                c = Pose3Between(data.meas[k], S[k])
                costs.append(c)
                prob.add_residual_block(c, None, [Pp[i], Q[i], Pp[j], Q[j]])
            for i in range(len(Q)):
                if prob.has_parameter_block(Q[i]):
                    prob.set_manifold(Q[i], pyceres.EigenQuaternionManifold())
            prob.set_parameter_block_constant(Pp[0])
            prob.set_parameter_block_constant(Q[0])
            st.update(arrays=[Pp, Q], init=[Pp.copy(), Q.copy()], max_iter=200)
        elif spec.kind == "bal":
            Cm = data.cameras.copy()
            Xp = data.points.copy()
            for k in range(len(data.obs)):
                c = Snavely(data.obs[k])
                costs.append(c)
                prob.add_residual_block(c, None, [Cm[data.cam_idx[k]], Xp[data.pt_idx[k]]])
            st.update(arrays=[Cm, Xp], init=[Cm.copy(), Xp.copy()], max_iter=50)
        elif spec.kind == "robot_localization":
            X = data.poses.copy()
            for k in range(len(data.br_meas)):
                c = BearingRange(data.landmarks[data.br_lm[k]], data.br_meas[k], data.br_sigmas)
                costs.append(c)
                prob.add_residual_block(c, None, [X[data.br_pose[k]]])
            S = np.diag(1.0 / data.odom_sigmas)
            for k in range(len(data.odom_meas)):
                c = Pose2Between(data.odom_meas[k], S)
                costs.append(c)
                prob.add_residual_block(c, None, [X[k], X[k + 1]])
            st.update(arrays=[X], init=[X.copy()], max_iter=50)
        else:
            raise ValueError(spec.kind)
        return st

    def reset(self, st):
        for a, a0 in zip(st["arrays"], st["init"]):
            np.copyto(a, a0)

    def options(self, st, mode):
        pyceres = _pyceres()
        o = pyceres.SolverOptions()
        o.num_threads = 1
        o.minimizer_progress_to_stdout = False
        o.logging_type = pyceres.LoggingType.SILENT
        if st["kind"] == "bal":
            o.linear_solver_type = pyceres.LinearSolverType.SPARSE_SCHUR
        else:
            o.linear_solver_type = pyceres.LinearSolverType.SPARSE_NORMAL_CHOLESKY
        o.max_num_iterations = st["max_iter"]
        if mode == "5it":
            o.max_num_iterations = 5
            o.function_tolerance = 0.0
            o.gradient_tolerance = 0.0
            o.parameter_tolerance = 0.0
        return o

    def solve(self, st, mode):
        pyceres = _pyceres()
        o = self.options(st, mode)
        summary = pyceres.SolverSummary()
        pyceres.solve(o, st["problem"], summary)
        # Ceres counts its iteration 0 (the initial evaluation) as a successful step
        its = summary.num_successful_steps + summary.num_unsuccessful_steps - 1
        return SolveOutput(None, its, summary.initial_cost, summary.final_cost,
                           str(summary.termination_type).split(".")[-1],
                           {"successful_steps": summary.num_successful_steps,
                            "linear_solver_s": summary.linear_solver_time_in_seconds,
                            "jacobian_eval_s": summary.jacobian_evaluation_time_in_seconds,
                            "residual_eval_s": summary.residual_evaluation_time_in_seconds})

    def estimate(self, st, out):
        k = st["kind"]
        if k in ("pose2d", "robot_localization"):
            return {"poses": st["arrays"][0].copy()}
        if k == "pose3d":
            Pp, Q = st["arrays"]
            return {"poses": np.concatenate([Pp, Q / np.linalg.norm(Q, axis=1, keepdims=True)], 1)}
        if k == "bal":
            return {"cameras": st["arrays"][0].copy(), "points": st["arrays"][1].copy()}
        raise ValueError(k)


RUNNER = CeresRunner()
