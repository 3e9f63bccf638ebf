"""SymForce 0.12 runner: ``symforce.opt.optimizer.Optimizer`` with ``Factor``s built from
``symforce.codegen.geo_factors_codegen.between_factor`` / ``prior_factor`` (the geo factors).

SymForce generates one Python linearization function per factor *type* (codegen is cached by
expression structure), and its C++ optimizer calls that Python function once per factor per
linearization. We therefore build one symbolic ``Factor`` per factor type (codegen, counted in the
first, warm-up load) and reuse its generated function for every edge through ``NumericFactor``,
instead of re-tracing the same expression thousands of times.

Gauge: a prior on the first pose with GTSAM's example variances. Residual charts are SymForce's
(``Pose3`` tangent = SO(3) log and translation difference); the yardstick re-evaluates the final
estimate with GTSAM's. BAL: a symbolic Snavely residual (``Rot3.from_tangent`` of the angle-axis).
"""


import numpy as np

from . import SolveOutput

_INIT = {}


def _sf():
    if "sf" not in _INIT:
        import symforce

        try:
            symforce.set_epsilon_to_symbol()
        except Exception:  # already imported symbolic: epsilon stays as configured
            pass
        import sym
        import symforce.symbolic as sf

        _INIT["sf"] = sf
        _INIT["sym"] = sym
    return _INIT["sf"], _INIT["sym"]


def _linearization(name, func, keys, optimized):
    """Generate (once per process) the linearization function of ``func`` w.r.t. ``optimized``."""
    key = (name, tuple(optimized))
    if key not in _INIT:
        from symforce.opt.factor import Factor

        f = Factor(keys=keys, residual=func)
        _INIT[key] = f.to_numeric_factor(optimized).linearization_function
    return _INIT[key]


def _residuals():
    sf, _ = _sf()
    from symforce.codegen.geo_factors_codegen import between_factor, prior_factor

    def between2(a: sf.Pose2, b: sf.Pose2, z: sf.Pose2, sqrt_info: sf.M33,
                 epsilon: sf.Scalar) -> sf.V3:
        return sf.V3(between_factor(a, b, z, sqrt_info, epsilon))

    def prior2(a: sf.Pose2, z: sf.Pose2, sqrt_info: sf.M33, epsilon: sf.Scalar) -> sf.V3:
        return sf.V3(prior_factor(a, z, sqrt_info, epsilon))

    def between3(a: sf.Pose3, b: sf.Pose3, z: sf.Pose3, sqrt_info: sf.M66,
                 epsilon: sf.Scalar) -> sf.V6:
        return sf.V6(between_factor(a, b, z, sqrt_info, epsilon))

    def prior3(a: sf.Pose3, z: sf.Pose3, sqrt_info: sf.M66, epsilon: sf.Scalar) -> sf.V6:
        return sf.V6(prior_factor(a, z, sqrt_info, epsilon))

    def snavely(cam: sf.V9, point: sf.V3, uv: sf.V2, epsilon: sf.Scalar) -> sf.V2:
        R = sf.Rot3.from_tangent(cam[0:3], epsilon=epsilon)
        P = R * point + sf.V3(cam[3:6])
        px = -P[0] / P[2]
        py = -P[1] / P[2]
        r2 = px * px + py * py
        d = 1 + r2 * (cam[7] + cam[8] * r2)
        return sf.V2(cam[6] * d * px - uv[0], cam[6] * d * py - uv[1])

    def bearing_range(x: sf.Pose2, lm: sf.V2, z: sf.V2, inv_sigmas: sf.V2,
                      epsilon: sf.Scalar) -> sf.V2:
        local = x.inverse() * lm
        bearing = sf.atan2(local[1], local[0], epsilon=epsilon)
        return sf.V2(sf.wrap_angle(bearing - z[0]) * inv_sigmas[0],
                     (local.norm(epsilon=epsilon) - z[1]) * inv_sigmas[1])

    return dict(between2=between2, prior2=prior2, between3=between3, prior3=prior3,
                snavely=snavely, bearing_range=bearing_range)


class SymforceRunner:
    name = "symforce"
    pinning = "C++ optimizer is single-threaded; BLAS env vars = 1"
    note = "Python Optimizer: generated Python linearization called per factor"

    def version(self) -> str:
        import symforce

        return symforce.__version__

    def supports(self, spec) -> str | None:
        return None

    def load(self, spec):
        from symforce.opt.numeric_factor import NumericFactor
        from symforce.opt.optimizer import Optimizer
        from symforce.values import Values

        from .. import problems

        sf, sym = _sf()
        res = _residuals()
        data = problems.load(spec.name)
        eps = sym.epsilon if hasattr(sym, "epsilon") else 2.2e-15
        factors = []
        vals = {"epsilon": float(eps)}
        if spec.kind in ("pose2d", "pose3d"):
            g = data
            n, m = len(g.ids), len(g.edge_i)
            if g.is3d:
                to_pose = lambda r: sym.Pose3.from_storage(  # noqa: E731
                    [r[3], r[4], r[5], r[6], r[0], r[1], r[2]])
                S = g.sqrt_info("gtsam")  # rot, trans = sf.Pose3 tangent order
                bname, pname = "between3", "prior3"
                prior_sqrt = np.diag(1.0 / np.sqrt([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]))
            else:
                to_pose = lambda r: sym.Pose2.from_storage(  # noqa: E731
                    [np.cos(r[2]), np.sin(r[2]), r[0], r[1]])
                perm = np.array([2, 0, 1])  # sf.Pose2 tangent: theta, x, y
                info = g.info[:, perm][:, :, perm]
                S = np.swapaxes(np.linalg.cholesky(info), 1, 2)
                bname, pname = "between2", "prior2"
                prior_sqrt = np.diag(1.0 / np.sqrt([1e-8, 1e-6, 1e-6]))
            vals["x"] = [to_pose(r) for r in g.poses]
            vals["z"] = [to_pose(r) for r in g.meas]
            vals["S"] = [np.ascontiguousarray(s) for s in S]
            vals["x0"] = to_pose(g.poses[0])
            vals["S0"] = prior_sqrt
            lin_b = _linearization(bname, res[bname], ["a", "b", "z", "sqrt_info", "epsilon"],
                                   ["a", "b"])
            lin_p = _linearization(pname, res[pname], ["a", "z", "sqrt_info", "epsilon"], ["a"])
            for k in range(m):
                i, j = int(g.edge_i[k]), int(g.edge_j[k])
                factors.append(NumericFactor([f"x[{i}]", f"x[{j}]", f"z[{k}]", f"S[{k}]", "epsilon"],
                                             [f"x[{i}]", f"x[{j}]"], lin_b))
            factors.append(NumericFactor(["x[0]", "x0", "S0", "epsilon"], ["x[0]"], lin_p))
            optimized = [f"x[{i}]" for i in range(n)]
        elif spec.kind == "bal":
            b = data
            vals["c"] = [np.ascontiguousarray(c) for c in b.cameras]
            vals["p"] = [np.ascontiguousarray(p) for p in b.points]
            vals["uv"] = [np.ascontiguousarray(o) for o in b.obs]
            lin = _linearization("snavely", res["snavely"], ["cam", "point", "uv", "epsilon"],
                                 ["cam", "point"])
            for k in range(len(b.obs)):
                ci, pi = int(b.cam_idx[k]), int(b.pt_idx[k])
                factors.append(NumericFactor([f"c[{ci}]", f"p[{pi}]", f"uv[{k}]", "epsilon"],
                                             [f"c[{ci}]", f"p[{pi}]"], lin))
            optimized = ([f"c[{i}]" for i in range(len(b.cameras))]
                         + [f"p[{i}]" for i in range(len(b.points))])
        elif spec.kind == "robot_localization":
            p = data
            to_pose = lambda r: sym.Pose2.from_storage(  # noqa: E731
                [np.cos(r[2]), np.sin(r[2]), r[0], r[1]])
            vals["x"] = [to_pose(r) for r in p.poses]
            vals["lm"] = [np.ascontiguousarray(l) for l in p.landmarks]
            vals["brz"] = [np.ascontiguousarray(z) for z in p.br_meas]
            vals["bri"] = 1.0 / p.br_sigmas
            vals["odo"] = [to_pose(z) for z in p.odom_meas]
            vals["So"] = np.diag(1.0 / p.odom_sigmas[[2, 0, 1]])
            lin_br = _linearization("bearing_range", res["bearing_range"],
                                    ["x", "lm", "z", "inv_sigmas", "epsilon"], ["x"])
            lin_b = _linearization("between2", res["between2"],
                                   ["a", "b", "z", "sqrt_info", "epsilon"], ["a", "b"])
            for k in range(len(p.br_meas)):
                i, j = int(p.br_pose[k]), int(p.br_lm[k])
                factors.append(NumericFactor([f"x[{i}]", f"lm[{j}]", f"brz[{k}]", "bri", "epsilon"],
                                             [f"x[{i}]"], lin_br))
            for k in range(len(p.odom_meas)):
                factors.append(NumericFactor([f"x[{k}]", f"x[{k + 1}]", f"odo[{k}]", "So",
                                              "epsilon"], [f"x[{k}]", f"x[{k + 1}]"], lin_b))
            optimized = [f"x[{i}]" for i in range(len(p.poses))]
        else:
            raise ValueError(spec.kind)
        values = Values(**vals)
        return {"kind": spec.kind, "factors": factors, "values": values, "optimized": optimized,
                "Optimizer": Optimizer}

    def reset(self, st):
        pass  # optimize() never changes the input Values

    def solve(self, st, mode):
        Optimizer = st["Optimizer"]
        params = Optimizer.Params(verbose=False)
        if mode == "5it":
            params.iterations = 5
            params.early_exit_min_reduction = -1.0  # never "converged" by relative reduction
            params.early_exit_min_absolute_error = -1.0
        # the Optimizer (C++ problem set-up, ordering, symbolic factorization) is built per solve
        opt = Optimizer(factors=st["factors"], optimized_keys=st["optimized"], params=params)
        result = opt.optimize(st["values"])
        its = result.iterations
        init_err = float(its[0].new_error) if len(its) else None
        # iterations[0] is the evaluation at the initial guess
        return SolveOutput(result, max(len(its) - 1, 0), init_err, float(result.error()),
                           str(result.status).split(".")[-1])

    def estimate(self, st, out):
        v = out.raw.optimized_values
        k = st["kind"]
        if k in ("pose2d", "robot_localization"):
            x = v["x"]
            return {"poses": np.array([[p.t[0], p.t[1], np.arctan2(p.R.data[1], p.R.data[0])]
                                       for p in x])}
        if k == "pose3d":
            rows = []
            for p in v["x"]:
                s = p.to_storage()  # qx qy qz qw x y z
                rows.append([s[4], s[5], s[6], s[0], s[1], s[2], s[3]])
            return {"poses": np.array(rows)}
        if k == "bal":
            return {"cameras": np.array([np.ravel(c) for c in v["c"]]),
                    "points": np.array([np.ravel(p) for p in v["p"]])}
        raise ValueError(k)


RUNNER = SymforceRunner()
