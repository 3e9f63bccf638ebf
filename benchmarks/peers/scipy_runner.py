"""``scipy.optimize.least_squares`` runner: ``method="trf"``, a finite-difference Jacobian with the
problem's sparsity (``jac_sparsity``, so ``tr_solver`` is LSMR), ``x_scale="jac"``.

Parametrization (scipy has no manifolds): 2D ``x, y, theta`` per pose; 3D ``t, rotation vector``
per pose; BAL the Snavely parameters. The first pose is held fixed (left out of ``x``). Residuals
are the yardstick's whitened residuals (GTSAM's between error). "5 iterations" = 5 trust-region
trial steps (``max_nfev=6``, ``ftol = xtol = None``, ``gtol = 2.3e-16``: scipy requires one tolerance above
machine epsilon);
"converge" = scipy's defaults (``ftol = xtol = gtol = 1e-8``, ``max_nfev = 100 n``).
"""

from __future__ import annotations

import numpy as np

from . import SolveOutput


class ScipyRunner:
    name = "scipy"
    pinning = "BLAS env vars = 1 (LSMR is single-threaded numpy)"
    note = "least_squares trf + jac_sparsity (finite differences, LSMR)"

    def version(self) -> str:
        import scipy

        return scipy.__version__

    def supports(self, spec) -> str | None:
        return None

    def load(self, spec):
        import scipy.sparse as sp

        from .. import problems, yardstick as Y

        data = problems.load(spec.name)
        st = {"kind": spec.kind, "data": data}
        if spec.kind in ("pose2d", "pose3d"):
            g = data
            d = g.dim
            R = g.sqrt_info("gtsam")
            fixed = g.poses[0].copy()
            n = len(g.ids)
            if g.is3d:
                x0 = np.concatenate([g.poses[1:, :3], Y.quat_to_rotvec(g.poses[1:, 3:7])], 1).ravel()

                def unpack(x):
                    v = x.reshape(-1, 6)
                    poses = np.concatenate([v[:, :3], Y.rotvec_to_quat(v[:, 3:])], 1)
                    return np.vstack([fixed, poses])
            else:
                x0 = g.poses[1:].ravel().copy()

                def unpack(x):
                    return np.vstack([fixed, x.reshape(-1, 3)])

            def fun(x):
                e = Y.pose_graph_residuals(g, unpack(x))
                return np.einsum("mij,mj->mi", R, e).ravel()

            # sparsity: the d rows of edge k depend on the d columns of poses i and j (not pose 0)
            m = len(g.edge_i)
            rows, cols = [], []
            for idx in (g.edge_i, g.edge_j):
                keep = idx > 0
                r = (np.arange(m)[keep, None] * d + np.arange(d))[:, :, None]
                c = ((idx[keep] - 1)[:, None] * d + np.arange(d))[:, None, :]
                r, c = np.broadcast_arrays(r, c)
                rows.append(r.ravel())
                cols.append(c.ravel())
            A = sp.coo_matrix((np.ones(sum(len(r) for r in rows), dtype=np.int8),
                               (np.concatenate(rows), np.concatenate(cols))),
                              shape=(m * d, (n - 1) * d)).tocsr()
            A.data[:] = 1
        elif spec.kind == "bal":
            b = data
            nc, npt = len(b.cameras), len(b.points)
            x0 = np.concatenate([b.cameras.ravel(), b.points.ravel()])

            def unpack(x):
                return x[:9 * nc].reshape(nc, 9), x[9 * nc:].reshape(npt, 3)

            def fun(x):
                c, p = unpack(x)
                return Y.bal_residuals(b, c, p).ravel()

            o = len(b.obs)
            r = np.repeat(np.arange(2 * o), 12)
            cc = np.concatenate([b.cam_idx[:, None] * 9 + np.arange(9),
                                 9 * nc + b.pt_idx[:, None] * 3 + np.arange(3)], 1)
            c = np.repeat(cc, 2, axis=0).ravel()
            A = sp.coo_matrix((np.ones(len(r), dtype=np.int8), (r, c)),
                              shape=(2 * o, x0.size)).tocsr()
        elif spec.kind == "robot_localization":
            p = data
            x0 = p.poses.ravel().copy()

            def unpack(x):
                return x.reshape(-1, 3)

            def fun(x):
                return Y.robot_residuals(p, unpack(x))

            A = None  # tiny: dense finite differences
        else:
            raise ValueError(spec.kind)
        st.update(x0=x0, fun=fun, unpack=unpack, A=A)
        return st

    def reset(self, st):
        pass

    def solve(self, st, mode):
        from scipy.optimize import least_squares

        kw = dict(method="trf", x_scale="jac")
        if st["A"] is not None:
            kw["jac_sparsity"] = st["A"]
        if mode == "5it":
            # scipy insists on one tolerance above machine epsilon: a gradient test at 2.3e-16
            kw.update(ftol=None, xtol=None, gtol=2.3e-16, max_nfev=6)
        res = least_squares(st["fun"], st["x0"], **kw)
        return SolveOutput(res, int(res.nfev) - 1, None, float(res.cost), f"status {res.status}",
                           {"nfev": int(res.nfev), "njev": int(res.njev or 0)})

    def estimate(self, st, out):
        x = out.raw.x
        if st["kind"] == "bal":
            c, p = st["unpack"](x)
            return {"cameras": c, "points": p}
        return {"poses": st["unpack"](x)}


RUNNER = ScipyRunner()
