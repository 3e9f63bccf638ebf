"""fgopt runner. Everything fgopt-specific is in :func:`load_fgopt` and :func:`solve_fgopt`; adapt
those two if fgopt's API changes.

* pose graphs: ``fgopt.io.read_g2o(path, add_prior=True)`` (tight prior on the lowest-id pose;
  ``repair_information="clip"`` for files with non-PD information, i.e. cubicle)
* BAL: ``fgopt.io.read_bal(path)`` (no gauge prior, as the protocol says)
* robot localization: ``BetweenFactor`` odometry plus bearing-range to a known landmark as an
  ``@fgopt.factor`` kernel (fallback: a Python ``Factor`` with analytic Jacobians)
* "5it": ``LevenbergMarquardt(LMParams(max_iterations=5, every tolerance 0))``; "converge":
  ``fgopt.optimize(graph, initial, method="lm")`` with its defaults.

Extra LM options (e.g. ``linear_solver=ldlt``, ``ordering=metis``) come from the environment
variable ``FGOPT_BENCH_OPTIONS="key=value,key=value"`` (``benchmarks.run --fgopt-options``).
"""

from __future__ import annotations

import os

import numpy as np

from . import SolveOutput

NEEDS_CLIP = {"cubicle"}


def bench_options() -> dict:
    """LMParams overrides from ``FGOPT_BENCH_OPTIONS``."""
    raw = os.environ.get("FGOPT_BENCH_OPTIONS", "").strip()
    out = {}
    for item in filter(None, (s.strip() for s in raw.split(","))):
        k, _, v = item.partition("=")
        for conv in (int, float):
            try:
                v = conv(v)
                break
            except ValueError:
                continue
        out[k.strip()] = v
    return out


def load_fgopt(spec):
    """Problem spec -> ``(graph, initial)`` built the fgopt way."""
    import fgopt.io

    if spec.kind in ("pose2d", "pose3d"):
        repair = "clip" if spec.name in NEEDS_CLIP else None
        return fgopt.io.read_g2o(spec.path, add_prior=True, repair_information=repair)
    if spec.kind == "bal":
        return fgopt.io.read_bal(spec.path)
    if spec.kind == "robot_localization":
        return _robot_graph()
    raise ValueError(spec.kind)


def solve_fgopt(graph, initial, mode: str):
    """Run LM: exactly 5 iterations with every stopping test off, or to convergence."""
    import fgopt
    from fgopt.solvers import LevenbergMarquardt, LMParams

    opts = bench_options()
    if mode == "5it":
        params = LMParams(max_iterations=5, relative_tolerance=0.0, absolute_tolerance=0.0,
                          gradient_tolerance=0.0, step_tolerance=0.0, **opts)
        return LevenbergMarquardt(params).optimize(graph, initial)
    return fgopt.optimize(graph, initial, method="lm", **opts)


def _bearing_range_symbolic():
    """Bearing-range to a known landmark as an ``@fgopt.factor`` kernel (fast path)."""
    from ._fgopt_symbolic import bearing_range_known

    return bearing_range_known


def _robot_graph():
    import fgopt
    from fgopt import SE2, BetweenFactor, FactorGraph, Variables, key
    from fgopt.factors import Factor

    from ..problems import robot_localization

    try:
        symbolic = _bearing_range_symbolic()
    except ImportError:
        symbolic = None

    class BearingRangeKnown(Factor):
        """Bearing and range from an SE2 pose to a known landmark (tangent: theta, vx, vy)."""

        def __init__(self, k, landmark, z, loss):
            super().__init__([k], 2, loss)
            self.lm = np.asarray(landmark, dtype=float)
            self.z = np.asarray(z, dtype=float)

        def _local(self, values):
            x = values.at(self.keys[0])
            d = self.lm - x.translation()
            th = x.theta()
            c, s = np.cos(th), np.sin(th)
            return c * d[0] + s * d[1], -s * d[0] + c * d[1]

        def error(self, values):
            lx, ly = self._local(values)
            b = np.arctan2(ly, lx) - self.z[0]
            return np.array([np.arctan2(np.sin(b), np.cos(b)), np.hypot(lx, ly) - self.z[1]])

        def jacobians(self, values):
            lx, ly = self._local(values)
            r2 = lx * lx + ly * ly
            r = np.sqrt(r2)
            return [np.array([[-1.0, ly / r2, -lx / r2], [0.0, -lx / r, -ly / r]])]

    p = robot_localization()
    graph, initial = FactorGraph(), Variables()
    for i, x in enumerate(p.poses):
        initial.add(key("x", i), SE2.from_xytheta(*x))
    br = fgopt.noise.Diagonal.sigmas(p.br_sigmas)
    for k in range(len(p.br_meas)):
        xk, lm, z = key("x", int(p.br_pose[k])), p.landmarks[p.br_lm[k]], p.br_meas[k]
        if symbolic is not None:
            graph.add(symbolic(pose=xk, landmark=lm.copy(), measured=z.copy(), loss=br))
        else:
            graph.add(BearingRangeKnown(xk, lm, z, br))
    # odometry: fgopt's SE2 tangent is theta, vx, vy
    odo = fgopt.noise.Diagonal.sigmas(p.odom_sigmas[[2, 0, 1]])
    for k, z in enumerate(p.odom_meas):
        graph.add(BetweenFactor(key("x", k), key("x", k + 1), SE2.from_xytheta(*z), odo))
    return graph, initial


class FgoptRunner:
    name = "fgopt"
    pinning = "NUMBA_NUM_THREADS=1 + BLAS env vars = 1 before import"
    note = ""

    def version(self) -> str:
        import subprocess

        import fgopt

        try:
            rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                                 text=True, cwd=os.path.dirname(fgopt.__file__)).stdout.strip()
        except OSError:
            rev = ""
        v = getattr(fgopt, "__version__", "?")
        return f"{v} ({rev})" if rev else v

    def supports(self, spec) -> str | None:
        return None

    def load(self, spec):
        graph, initial = load_fgopt(spec)
        return {"kind": spec.kind, "graph": graph, "initial": initial, "spec": spec}

    def reset(self, st):
        pass  # fgopt.optimize leaves `initial` untouched

    def solve(self, st, mode):
        res = solve_fgopt(st["graph"], st["initial"], mode)
        status = getattr(res.status, "value", str(res.status))
        extra = {"timing": dict(getattr(res, "timing", {}) or {}),
                 "message": getattr(res, "message", "")}
        return SolveOutput(res, res.iterations, res.initial_cost, res.final_cost, status, extra)

    def estimate(self, st, out):
        from fgopt import key

        from .. import problems

        values = out.raw.values
        k = st["kind"]
        data = problems.load(st["spec"].name)
        if k in ("pose2d", "pose3d"):
            rows = np.array([values.at(key("x", int(i))).to_storage() for i in data.ids])
            if k == "pose2d":  # c, s, x, y
                return {"poses": np.stack([rows[:, 2], rows[:, 3],
                                           np.arctan2(rows[:, 1], rows[:, 0])], 1)}
            return {"poses": np.concatenate([rows[:, 4:7], rows[:, 0:4]], 1)}
        if k == "robot_localization":
            rows = np.array([values.at(key("x", i)).to_storage() for i in range(len(data.poses))])
            return {"poses": np.stack([rows[:, 2], rows[:, 3],
                                       np.arctan2(rows[:, 1], rows[:, 0])], 1)}
        if k == "bal":
            cams = np.array([np.ravel(values.at(key("c", i))) for i in range(len(data.cameras))])
            pts = np.array([np.ravel(values.at(key("p", j))) for j in range(len(data.points))])
            return {"cameras": cams, "points": pts}
        raise ValueError(k)


RUNNER = FgoptRunner()
