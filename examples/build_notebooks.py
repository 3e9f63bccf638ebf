"""Write the example notebooks of this folder (outputs cleared) from the cell lists below.

The notebooks are generated so that their text lives in one reviewable Python file; edit the
cells here and run ``.venv/bin/python examples/build_notebooks.py`` (from the repository root)
to rewrite the ``.ipynb`` files. ``tests/test_notebooks.py`` executes every notebook.
"""

from __future__ import annotations

import copy
import sys
import textwrap
from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = Path(__file__).resolve().parent

KERNELSPEC = {"name": "python3", "display_name": "Python 3 (ipykernel)", "language": "python"}


def md(text: str):
    return new_markdown_cell(textwrap.dedent(text).strip("\n"))


def code(text: str):
    return new_code_cell(textwrap.dedent(text).strip("\n"))


# A cell shared by the notebooks that read data files: $FGOPT_DATA, else ../shared/data next to
# the repository (the notebooks run with examples/ as working directory).
DATA_CELL = code("""
    import os
    from pathlib import Path


    def find_data_dir() -> Path:
        \"\"\"$FGOPT_DATA, else ../shared/data next to the repository root.\"\"\"
        if os.environ.get("FGOPT_DATA"):
            return Path(os.environ["FGOPT_DATA"])
        here = Path.cwd().resolve()
        for root in [here, *here.parents]:
            if (root / "pyproject.toml").exists():
                return root.parent / "shared" / "data"
        return here / "data"


    DATA = find_data_dir()
    print("data folder:", DATA, "(present)" if DATA.is_dir() else "(absent)")
""")


# ----------------------------------------------------------------------------------------------
# 01: the miniSAM paper's pose graph
# ----------------------------------------------------------------------------------------------
NB01 = [
    md("""
    # 01 — The miniSAM pose graph example

    The 2D pose graph of the miniSAM paper (Sec. II-C, Fig. 2 and Snippet 1): a vehicle drives
    forward, makes a 270° right turn, and a loop-closure measurement ties the last pose back to
    the second. The factor graph has

    * a **prior** on `x1` (fixes the gauge, i.e. the world frame),
    * four **odometry** between factors `x1-x2`, ..., `x4-x5`,
    * one **loop closure** between factor `x5-x2`.

    We build it with fgopt's miniSAM-style API, solve it with Levenberg-Marquardt, Gauss-Newton
    and Dogleg, print the result table and plot the trajectory.

    **Conventions.** fgopt's SE(2) tangent order is *rotation first*, `[theta, x, y]`, while
    GTSAM's Pose2 and miniSAM's (Sophus) SE2 put the translation first, `[x, y, theta]`. So
    miniSAM's `DiagonalLoss.Sigmas([1.0, 1.0, 0.1])` (x, y, theta) is
    `Diagonal.sigmas([0.1, 1.0, 1.0])` here. Between residuals are `Log(m^-1 a^-1 b)`; the cost is
    `0.5 * sum |whitened residual|^2`.
    """),
    code("""
    import time

    import matplotlib.pyplot as plt
    import numpy as np

    import fgopt
    from fgopt import SE2, SO2, BetweenFactor, PriorFactor, key
    from fgopt.noise import Diagonal
    """),
    md("""
    ## The factor graph

    `key('x', i)` makes the key of pose `x_i`. The odometry says "5 m forward, then turn 90°
    right" (`SE2(SO2(-pi/2), [5, 0])` is a rotation by -90° and a translation of 5 m along the
    vehicle's x axis). The loop closure from `x5` to `x2` is the same kind of motion.
    """),
    code("""
    loss = Diagonal.sigmas([0.1, 1.0, 1.0])          # (theta, x, y): fgopt's tangent order

    graph = fgopt.FactorGraph()
    graph.add(PriorFactor(key('x', 1), SE2(SO2(0.0), [0.0, 0.0]), loss))                  # prior
    graph.add(BetweenFactor(key('x', 1), key('x', 2), SE2(SO2(0.0), [5.0, 0.0]), loss))    # odometry
    graph.add(BetweenFactor(key('x', 2), key('x', 3), SE2(SO2(-np.pi / 2), [5.0, 0.0]), loss))
    graph.add(BetweenFactor(key('x', 3), key('x', 4), SE2(SO2(-np.pi / 2), [5.0, 0.0]), loss))
    graph.add(BetweenFactor(key('x', 4), key('x', 5), SE2(SO2(-np.pi / 2), [5.0, 0.0]), loss))
    graph.add(BetweenFactor(key('x', 5), key('x', 2), SE2(SO2(-np.pi / 2), [5.0, 0.0]), loss))  # loop closure
    print(graph)
    """),
    md("""
    ## Initial values

    A deliberately wrong initial guess (the paper's values): every pose is off by a few tenths of
    a metre and up to 0.2 rad.
    """),
    code("""
    initial = fgopt.Variables()
    initial.add(key('x', 1), SE2(SO2(0.2), [0.2, -0.3]))
    initial.add(key('x', 2), SE2(SO2(-0.1), [5.1, 0.3]))
    initial.add(key('x', 3), SE2(SO2(-np.pi / 2 - 0.2), [9.9, -0.1]))
    initial.add(key('x', 4), SE2(SO2(-np.pi + 0.1), [10.2, -5.0]))
    initial.add(key('x', 5), SE2(SO2(np.pi / 2 - 0.1), [5.1, -5.1]))
    print(initial)
    print("initial cost:", graph.error(initial))
    """),
    md("""
    ## The structure of the problem

    Each factor touches one or two poses, so the Gauss-Newton matrix `H = J^T W J` is block
    sparse (the paper's Eq. 21): 3x3 blocks on the diagonal, and off the diagonal only for pairs
    of poses linked by a factor (`x2-x5` is the loop closure). `graph.compile` builds the problem
    fgopt's solvers iterate on; here we only linearize it once to look at `H`.
    """),
    code("""
    problem = graph.compile(initial, ordering="natural")
    problem.linearize(problem.initial_state())
    H = problem.pattern.full(problem.H_data).toarray()
    blocks = np.array([[np.abs(H[3 * i:3 * i + 3, 3 * j:3 * j + 3]).max() > 0 for j in range(5)]
                       for i in range(5)])
    print("non-zero 3x3 blocks of H (rows/cols x1..x5):")
    print(blocks.astype(int))
    assert blocks[1, 4] and blocks[4, 1] and not blocks[0, 2]   # x2-x5 loop closure, no x1-x3 block
    """),
    md("""
    ## Solve with LM, Gauss-Newton and Dogleg

    `fgopt.optimize` returns a `Result` (status, cost history, per-iteration records, timing);
    `result.values` are the optimized `Variables` (the initial values are not modified).
    `linear_solver="auto"` picks dense Cholesky for such a tiny problem.
    """),
    code("""
    results = {}
    print(f"{'method':8s} {'status':10s} {'iters':>5s} {'initial cost':>13s} {'final cost':>11s} {'time (ms)':>9s}")
    for method in ["lm", "gn", "dogleg"]:
        t0 = time.perf_counter()
        r = fgopt.optimize(graph, initial, method=method)
        ms = 1e3 * (time.perf_counter() - t0)
        results[method] = r
        print(f"{method:8s} {r.status.value:10s} {r.iterations:5d} {r.initial_cost:13.6g} "
              f"{r.final_cost:11.3g} {ms:9.1f}")
    """),
    md("The per-iteration table of the LM run (`verbose=True` prints it while solving):"),
    code("""
    print(results["lm"].table())
    """),
    md("""
    ## The result table

    The measurements are exactly consistent, so every method reaches zero cost and the true
    poses: a 5 m square, `x3` facing -90°, `x4` facing 180°, `x5` facing +90°.
    """),
    code("""
    truth = {1: (0, 0, 0), 2: (5, 0, 0), 3: (10, 0, -np.pi / 2), 4: (10, -5, np.pi), 5: (5, -5, np.pi / 2)}
    print(f"{'key':4s}" + "".join(f"{m + ' (x, y, theta)':>28s}" for m in results))
    for i in range(1, 6):
        row = "".join("   ({:6.3f}, {:6.3f}, {:6.3f})".format(
            r.values.at(key('x', i)).x(), r.values.at(key('x', i)).y(), r.values.at(key('x', i)).theta())
            for r in results.values())
        print(f"x{i:<3d}{row}")

    for method, r in results.items():
        assert r.success, (method, r.status, r.message)
        assert r.final_cost < 1e-10, (method, r.final_cost)
        for i, (x, y, th) in truth.items():
            err = np.linalg.norm(SE2.from_xytheta(x, y, th).local(r.values.at(key('x', i))))
            assert err < 1e-5, (method, i, err)
    # the caller's initial values are untouched
    assert abs(initial.at(key('x', 1)).x() - 0.2) < 1e-15
    """),
    md("""
    ## Plot

    `fgopt.plot.plot_pose_graph` draws the trajectory (poses in key order), the loop closures
    (between factors on non-consecutive keys) and, faintly, the initial guess. It draws into any
    matplotlib axes.
    """),
    code("""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    values = results["lm"].values
    fgopt.plot.plot_pose_graph(graph, values, ax=axes[0], initial=initial, title="miniSAM pose graph (LM)")
    for i in range(1, 6):
        p = values.at(key('x', i))
        axes[0].annotate(f"x{i}", (p.x(), p.y()), textcoords="offset points", xytext=(6, 6))
        axes[0].arrow(p.x(), p.y(), 0.8 * np.cos(p.theta()), 0.8 * np.sin(p.theta()), head_width=0.25, color="k")
    for method, r in results.items():
        costs = np.maximum(r.cost_history, 1e-30)
        axes[1].semilogy(costs, marker="o", label=method)
    axes[1].set_xlabel("iteration"); axes[1].set_ylabel("cost"); axes[1].legend(); axes[1].grid(alpha=0.3)
    axes[1].set_title("cost per iteration")
    plt.show()
    """),
]


# ----------------------------------------------------------------------------------------------
# 02: custom factors
# ----------------------------------------------------------------------------------------------
NB02 = [
    md("""
    # 02 — Custom factors: plain Python, numerical, and `@fgopt.factor`

    A factor is a residual `e(x)` over a few variables with a noise model. fgopt offers three
    ways to write a new one:

    1. **Python, analytic Jacobians** (miniSAM's Snippet 2): subclass `fgopt.Factor`, implement
       `error(values)` and `jacobians(values)` (derivatives in each variable's *tangent space*).
    2. **Python, numerical Jacobians**: subclass `fgopt.NumericalFactor` and write only `error`;
       Jacobians come from central differences through the variable's own `retract`.
    3. **Symbolic** (SymForce-style): write the residual once over symbolic types and decorate
       it with `@fgopt.factor`. fgopt derives the tangent-space Jacobians symbolically,
       generates a batched numba kernel (cached on disk) and evaluates all instances in one call.

    The example: a **GPS antenna on a lever arm**. A robot pose `x_i` (SE(2)) carries a GPS
    antenna at `lever = (0.5, 0.2)` m in the body frame; the GPS measures the antenna's world
    position `z_i`. The residual is

    `e(x) = x * lever - z = R(theta) lever + t - z`  (2-vector).

    With fgopt's retraction `x (+) d = x Exp(d)`, `d = [dtheta, dx, dy]`,
    `(x Exp(d)) * lever = x * (lever + dtheta J lever + [dx, dy]) + O(d^2)` with
    `J = [[0, -1], [1, 0]]`, so the exact Jacobian is `de/dd = R [J lever | I2]`, a 2x3 matrix.

    We solve a 200-pose trajectory with odometry plus GPS on every pose, once per variant, and
    time them.
    """),
    code("""
    import time

    import matplotlib.pyplot as plt
    import numpy as np

    import fgopt
    from fgopt import SE2, BetweenFactor, key
    from fgopt.noise import Diagonal, Isotropic
    from fgopt.symbolic import V2, Pose2
    """),
    md("## A simulated robot: odometry and GPS"),
    code("""
    rng = np.random.default_rng(1)
    N = 200
    LEVER = np.array([0.5, 0.2])
    ODOM_SIGMAS = np.array([0.02, 0.05, 0.05])      # (theta, x, y)
    GPS_SIGMA = 0.5

    truth = [SE2.from_xytheta(0.0, 0.0, 0.0)]
    for i in range(1, N):
        truth.append(truth[-1] * SE2.from_xytheta(1.0, 0.0, 0.15 * np.sin(i / 10)))
    odometry = [truth[i].between(truth[i + 1]).retract(rng.normal(size=3) * ODOM_SIGMAS) for i in range(N - 1)]
    gps = [truth[i] * LEVER + rng.normal(size=2) * GPS_SIGMA for i in range(N)]

    # initial guess: dead reckoning from a wrong initial heading
    initial = fgopt.Variables()
    pose = SE2.from_xytheta(0.0, 0.0, 0.3)
    for i in range(N):
        initial.add(key('x', i), pose)
        if i < N - 1:
            pose = pose * odometry[i]
    """),
    md("""
    ## 1. A `Factor` subclass with analytic Jacobians

    `super().__init__(keys, dim, loss)`; `values.at(k)` reads a variable. `SE2 * point`
    transforms a point. Jacobians are returned as one `(dim, tangent dim)` array per key.
    """),
    code("""
    class GpsFactor(fgopt.Factor):
        \"\"\"GPS antenna at `lever` (body frame) measured at world position `measured`.\"\"\"

        def __init__(self, pose_key, measured, lever, loss):
            super().__init__([pose_key], 2, loss)
            self.measured = np.asarray(measured, dtype=float)
            self.lever = np.asarray(lever, dtype=float)

        def error(self, values):
            return values.at(self.keys[0]) * self.lever - self.measured

        def jacobians(self, values):
            R = values.at(self.keys[0]).rotation().matrix()
            lx, ly = self.lever
            return [np.column_stack([R @ [-ly, lx], R])]     # d e / d [theta, x, y]
    """),
    md("## 2. A `NumericalFactor` subclass: only `error`"),
    code("""
    class GpsNumericalFactor(fgopt.NumericalFactor):
        def __init__(self, pose_key, measured, lever, loss):
            super().__init__([pose_key], 2, loss)
            self.measured = np.asarray(measured, dtype=float)
            self.lever = np.asarray(lever, dtype=float)

        def error(self, values):
            return values.at(self.keys[0]) * self.lever - self.measured
    """),
    md("""
    ## 3. The same residual with `@fgopt.factor`

    Arguments are annotated with symbolic types (`Pose2` is the twin of `fgopt.SE2`, same
    storage and tangent). Calling the factor type makes an instance: arguments given a key are
    variables, anything else is a constant stored with the instance. One kernel is generated per
    pattern of variables (here: only `pose` is a variable).
    """),
    code("""
    @fgopt.factor
    def gps_factor(pose: Pose2, lever: V2, measured: V2) -> V2:
        return pose * lever - measured
    """),
    md("""
    Before solving, check that the three variants agree at a random pose: same residual, and
    Jacobians equal to each other (the numerical ones to about 1e-8).
    """),
    code("""
    noise = Isotropic.sigma(2, GPS_SIGMA)
    check_values = fgopt.Variables({key('x', 0): SE2.from_xytheta(1.0, -2.0, 0.7)})
    variants = {
        "Factor (analytic)": GpsFactor(key('x', 0), gps[0], LEVER, noise),
        "NumericalFactor": GpsNumericalFactor(key('x', 0), gps[0], LEVER, noise),
        "@fgopt.factor": gps_factor(pose=key('x', 0), lever=LEVER, measured=gps[0], loss=noise),
    }
    ref_e = variants["Factor (analytic)"].error(check_values)
    ref_J = variants["Factor (analytic)"].jacobians(check_values)[0]
    for name, f in variants.items():
        e, J = f.error(check_values), f.jacobians(check_values)[0]
        print(f"{name:18s} e = {np.round(e, 6)}  |J - J_analytic| = {np.abs(J - ref_J).max():.1e}")
        assert np.allclose(e, ref_e, atol=1e-12)
        assert np.allclose(J, ref_J, atol=1e-7)
    """),
    md("""
    ## Solve the same problem with each variant, and time it

    Each solve builds the graph (odometry + one GPS factor per pose) and runs LM. The Python
    factors take fgopt's *slow path* (one Python call per factor and iteration; the numerical one
    calls `error` 6 more times per Jacobian); the `@fgopt.factor` instances are evaluated in a
    single numba call per iteration. The first symbolic solve may include the one-time numba
    compilation of the generated kernel (cached on disk afterwards), so we report the best of a
    few repeats.
    """),
    code("""
    def build_graph(make_gps):
        graph = fgopt.FactorGraph()
        odom_noise = Diagonal.sigmas(ODOM_SIGMAS)
        for i in range(N - 1):
            graph.add(BetweenFactor(key('x', i), key('x', i + 1), odometry[i], odom_noise))
        for i in range(N):
            graph.add(make_gps(key('x', i), gps[i], noise))
        return graph

    makers = {
        "Factor (analytic)": lambda k, z, n: GpsFactor(k, z, LEVER, n),
        "NumericalFactor": lambda k, z, n: GpsNumericalFactor(k, z, LEVER, n),
        "@fgopt.factor": lambda k, z, n: gps_factor(pose=k, lever=LEVER, measured=z, loss=n),
    }
    REPEATS = 3
    solved, timings = {}, {}
    for name, make in makers.items():
        graph = build_graph(make)
        times = []
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            result = fgopt.optimize(graph, initial)
            times.append(time.perf_counter() - t0)
        solved[name], timings[name] = result, times

    print(f"{'variant':18s} {'iters':>5s} {'final cost':>12s} {'best (ms)':>10s} {'all runs (ms)':>24s}")
    for name, r in solved.items():
        t = timings[name]
        print(f"{name:18s} {r.iterations:5d} {r.final_cost:12.6f} {1e3 * min(t):10.1f}   "
              + ", ".join(f"{1e3 * x:.1f}" for x in t))
    """),
    code("""
    def mean_position_error(values):
        return np.mean([np.linalg.norm(values.at(key('x', i)).translation() - truth[i].translation())
                        for i in range(N)])

    costs = [r.final_cost for r in solved.values()]
    for name, r in solved.items():
        print(f"{name:18s} mean position error {mean_position_error(r.values):.3f} m "
              f"(initial {mean_position_error(initial):.1f} m)")
        assert r.success, (name, r.message)
        assert mean_position_error(r.values) < 0.3
    assert max(costs) - min(costs) < 1e-6 * min(costs), costs    # the same optimum
    # the symbolic factor is the fast one once compiled
    assert min(timings["@fgopt.factor"]) < min(timings["Factor (analytic)"])
    """),
    md("""
    ## The generated code

    `gps_factor.source` is the generated module: a residual kernel and a linearization kernel
    (residual + tangent-space Jacobian), each a loop over instances of flat, CSE'd scalar code
    compiled with `@numba.njit`, plus the Python wrappers fgopt calls.
    """),
    code("""
    print(gps_factor.source)
    assert "def _linearize_kernel" in gps_factor.source
    """),
    md("## The trajectory"),
    code("""
    fig, ax = plt.subplots(figsize=(7, 5))
    gx = np.array(gps)
    ax.scatter(gx[:, 0], gx[:, 1], s=4, color="tab:orange", label="GPS fixes")
    tx = np.array([p.translation() for p in truth])
    ax.plot(tx[:, 0], tx[:, 1], "k-", lw=2, alpha=0.4, label="truth")
    fgopt.plot.plot_pose_graph(None, solved["@fgopt.factor"].values, ax=ax, initial=initial,
                               title="odometry + GPS on a lever arm")
    plt.show()
    """),
]


# ----------------------------------------------------------------------------------------------
# 03: custom manifolds
# ----------------------------------------------------------------------------------------------
NB03 = [
    md("""
    # 03 — Custom manifolds

    fgopt optimizes any value type it can read as a point on a manifold. It needs three things
    (miniSAM's Python manifold protocol, Snippet 3 of the paper):

    * `dim()`: the tangent-space dimension,
    * `retract(vec)`: `x (+) vec`, the point reached from `x` along the tangent vector `vec`,
    * `local(other)`: the tangent vector from `x` to `other`, so `x.retract(x.local(y)) == y`.

    Three ways to make a type a manifold:

    1. **Duck typing**: give the class those three methods; nothing to register.
    2. **Registration**: `fgopt.manifolds.register(cls, ops)` with an *ops* object (traits) that
       answers for values of `cls` — for types you cannot or do not want to change (here: Python's
       built-in `complex`).
    3. **Declaration**: `@fgopt.manifold` on a small class whose `retract` / `local` are written
       over fgopt's symbolic types. fgopt derives batched numba kernels, the tangent-space
       Jacobian machinery and a numeric value type from it, so the manifold gets everything the
       built-in groups get: one storage array, batched factors, `@fgopt.factor` signatures.

    The first two are on fgopt's *slow path* (Python calls per variable and per factor); the
    built-in Lie groups, vectors and declared manifolds use batched numba kernels.
    """),
    code("""
    import cmath
    import time

    import matplotlib.pyplot as plt
    import numpy as np

    import fgopt
    from fgopt import key
    from fgopt.factors import numerical_jacobians
    from fgopt.noise import Isotropic
    """),
    md("""
    ## 1. A unit vector on the sphere S^2 (duck typing)

    A direction `n` (|n| = 1) has two degrees of freedom. Its tangent space at `n` is the plane
    orthogonal to `n`, with an orthonormal basis `B(n)` (3x2). `retract` moves along the great
    circle (the exponential map of the sphere); `local` is its inverse.
    """),
    code("""
    def tangent_basis(n):
        \"\"\"Orthonormal basis (3x2) of the plane orthogonal to the unit vector n.\"\"\"
        a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        b1 = np.cross(n, a)
        b1 /= np.linalg.norm(b1)
        return np.column_stack([b1, np.cross(n, b1)])


    class UnitVector3:
        \"\"\"A point of S^2.\"\"\"

        def __init__(self, v):
            v = np.asarray(v, dtype=float)
            self.v = v / np.linalg.norm(v)

        def dim(self):
            return 2

        def basis(self):
            return tangent_basis(self.v)

        def retract(self, vec):
            w = self.basis() @ np.asarray(vec, dtype=float)      # tangent vector in R^3
            theta = np.linalg.norm(w)
            if theta < 1e-12:
                return UnitVector3(self.v + w)
            return UnitVector3(np.cos(theta) * self.v + np.sin(theta) * w / theta)

        def local(self, other):
            c = float(np.clip(self.v @ other.v, -1.0, 1.0))
            w = other.v - c * self.v                               # component orthogonal to v
            s = np.linalg.norm(w)
            if s < 1e-12:
                return np.zeros(2)
            return np.arccos(c) * (self.basis().T @ w) / s

        def __repr__(self):
            return f"UnitVector3({np.array2string(self.v, precision=4)})"


    n = UnitVector3([1.0, 2.0, 3.0])
    d = np.array([0.1, -0.2])
    print("local(retract(d)) =", n.local(n.retract(d)))
    assert np.allclose(n.local(n.retract(d)), d)
    m = UnitVector3([0.0, 1.0, 0.2])
    assert np.allclose(n.retract(n.local(m)).v, m.v)
    print("fgopt reads it as a manifold of dim", fgopt.manifolds.ops_for(n).dim(n))
    """),
    md("""
    ### Plane fitting

    Points `p_i` are measured on a plane `{p : n . p = d}` with 2 cm noise; the unknowns are the
    unit normal `n` (an `UnitVector3`) and the offset `d` (a plain `float` variable). Each point
    gives a 1-D residual `e_i = n . p_i - d`. Without the unit-norm constraint the problem would
    be degenerate (`n = 0, d = 0` has zero cost); on the manifold the constraint holds by
    construction. The Jacobians: `de/d(delta n) = p^T B(n)` and `de/dd = -1`.
    """),
    code("""
    class PlanePointFactor(fgopt.Factor):
        \"\"\"Signed distance n . p - d of the measured point p to the plane (n, d).\"\"\"

        def __init__(self, normal_key, offset_key, point, loss):
            super().__init__([normal_key, offset_key], 1, loss)
            self.p = np.asarray(point, dtype=float)

        def error(self, values):
            return np.array([values.at(self.keys[0]).v @ self.p - values.at(self.keys[1])])

        def jacobians(self, values):
            n = values.at(self.keys[0])
            return [(self.p @ n.basis()).reshape(1, 2), np.array([[-1.0]])]


    rng = np.random.default_rng(0)
    n_true = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    d_true = 2.0
    in_plane = rng.uniform(-5, 5, size=(300, 2)) @ tangent_basis(n_true).T
    points = d_true * n_true + in_plane + 0.02 * rng.normal(size=(300, 3))

    graph = fgopt.FactorGraph()
    for p in points:
        graph.add(PlanePointFactor(key('n', 0), key('d', 0), p, Isotropic.sigma(1, 0.02)))
    initial = fgopt.Variables()
    initial.add(key('n', 0), UnitVector3([0.0, 0.0, 1.0]))
    initial.add(key('d', 0), 0.0)

    # the analytic Jacobians agree with central differences through UnitVector3.retract
    f0 = graph[0]
    for J, Jn in zip(f0.jacobians(initial), numerical_jacobians(f0.error, initial, f0.keys)):
        assert np.allclose(J, Jn, atol=1e-6), (J, Jn)

    t0 = time.perf_counter()
    result = fgopt.optimize(graph, initial, verbose=True)
    t_python = time.perf_counter() - t0
    print(f"solved in {t_python:.2f} s")
    n_hat, d_hat = result.values.at(key('n', 0)), result.values.at(key('d', 0))
    angle = np.degrees(np.arccos(np.clip(n_hat.v @ n_true, -1, 1)))
    print("normal:", n_hat, " true:", np.round(n_true, 4), f" angle error {angle:.3f} deg")
    print(f"offset: {d_hat:.4f}  true: {d_true}")
    assert result.success
    assert angle < 0.2 and abs(d_hat - d_true) < 0.02
    assert abs(np.linalg.norm(n_hat.v) - 1) < 1e-12
    """),
    md("""
    Marginal covariances work for custom manifolds too: they are expressed in the variable's
    tangent space (here the 2-D basis `B(n)` at the estimate, in radians).
    """),
    code("""
    cov = fgopt.marginals(result, [key('n', 0), key('d', 0)])
    sig_n = np.degrees(np.sqrt(np.diag(cov[key('n', 0)])))
    sig_d = np.sqrt(cov[key('d', 0)][0, 0])
    print(f"normal direction 1-sigma: {sig_n.round(4)} deg, offset 1-sigma: {sig_d:.4f} m")
    assert np.all(sig_n < 0.1) and sig_d < 0.01
    """),
    md("""
    ## 2. Registering a type: `complex` as the unit circle

    The built-in `complex` cannot get new methods, so we register **traits** for it: unit complex
    numbers `z = exp(i theta)` form SO(2). The ops object answers for any value of the type:
    `dim`, `storage_dim`, `to_storage` / `from_storage` (`[re, im]`), `retract(z, d) = z exp(i d)`,
    `local(z, w) = arg(w / z)`, and `batch_kind` (`None`: no batched numba kernels, the slow
    path).
    """),
    code("""
    class UnitComplexOps:
        \"\"\"Manifold traits of `complex`: unit complex numbers, i.e. SO(2).\"\"\"

        def dim(self, z):
            return 1

        def storage_dim(self, z):
            return 2

        def to_storage(self, z):
            return np.array([z.real, z.imag])

        def from_storage(self, like, data):
            return complex(data[0], data[1])

        def retract(self, z, delta):
            return z * cmath.exp(1j * float(np.asarray(delta).reshape(-1)[0]))

        def local(self, z, w):
            return np.array([cmath.phase(w / z)])

        def batch_kind(self, z):
            return None


    fgopt.manifolds.register(complex, UnitComplexOps())
    print(fgopt.manifolds.ops_for(1j).local(1 + 0j, 1j))
    """),
    md("""
    ### Headings around a loop

    A robot drives once around a circle; we estimate its heading `h_i` (a unit complex number)
    at 24 stations from noisy relative turns between consecutive stations (closing the loop) and
    one compass reading at the start. The factors use `NumericalFactor`, so only `error` is
    written; its numerical Jacobians use the registered `retract`.
    """),
    code("""
    class RelativeTurn(fgopt.NumericalFactor):
        def __init__(self, a, b, turn, loss):
            super().__init__([a, b], 1, loss)
            self.turn = cmath.exp(1j * turn)

        def error(self, values):
            za, zb = values.at(self.keys[0]), values.at(self.keys[1])
            return np.array([cmath.phase(zb / (za * self.turn))])


    class Compass(fgopt.NumericalFactor):
        def __init__(self, a, heading, loss):
            super().__init__([a], 1, loss)
            self.z = cmath.exp(1j * heading)

        def error(self, values):
            return np.array([cmath.phase(values.at(self.keys[0]) / self.z)])


    M = 24
    heading = 2 * np.pi * np.arange(M) / M + 0.4
    TURN_SIGMA = 0.01
    graph2, initial2 = fgopt.FactorGraph(), fgopt.Variables()
    graph2.add(Compass(key('h', 0), heading[0], Isotropic.sigma(1, 0.01)))
    for i in range(M):
        j = (i + 1) % M
        graph2.add(RelativeTurn(key('h', i), key('h', j), heading[j] - heading[i] + TURN_SIGMA * rng.normal(),
                                Isotropic.sigma(1, TURN_SIGMA)))
        initial2.add(key('h', i), cmath.exp(1j * (heading[i] + 0.5 * rng.normal())))   # up to ~1 rad off

    result2 = fgopt.optimize(graph2, initial2, verbose=True)
    err = np.array([abs(cmath.phase(result2.values.at(key('h', i)) / cmath.exp(1j * heading[i]))) for i in range(M)])
    err0 = np.array([abs(cmath.phase(initial2.at(key('h', i)) / cmath.exp(1j * heading[i]))) for i in range(M)])
    print(f"heading error: initial max {np.degrees(err0.max()):.1f} deg -> optimized max {np.degrees(err.max()):.2f} deg")
    print("a value is still a", type(result2.values.at(key('h', 3))).__name__, result2.values.at(key('h', 3)))
    assert result2.success
    assert isinstance(result2.values.at(key('h', 3)), complex)
    assert np.degrees(err.max()) < 4.0
    """),
    code("""
    fig = plt.figure(figsize=(11, 4.5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.scatter(*points.T, s=3, color="tab:blue", alpha=0.6, label="points")
    c = points.mean(axis=0)
    ax.quiver(*c, *(3 * n_hat.v), color="tab:red", label="fitted normal")
    ax.quiver(*c, *(3 * n_true), color="k", linestyle=":", label="true normal")
    ax.set_title("plane fit on S^2 x R"); ax.legend(loc="upper left", fontsize="small")
    ax = fig.add_subplot(1, 2, 2)
    for vals, style, label in [(initial2, "o--", "initial"), (result2.values, "s-", "optimized")]:
        z = np.array([vals.at(key('h', i)) for i in range(M)])
        ax.plot(np.arange(M), np.degrees(np.unwrap(np.angle(z))), style, ms=4, label=label)
    ax.plot(np.arange(M), np.degrees(heading), "k:", label="truth")
    ax.set_xlabel("station"); ax.set_ylabel("heading (deg)"); ax.legend(); ax.set_title("headings on the unit circle")
    plt.show()
    """),
    md("""
    ## 3. Declaring a manifold: `@fgopt.manifold`

    The sphere of section 1 again, now *declared*: the class states `storage_dim` and `dim` and
    writes `retract(x, d)` and `local(x, y)` over symbolic types (`V3`, `Matrix`, `cos`, ...),
    plus an `identity()`, a `normalize(x)` for storage that drifts, and accessors (`direction`,
    `basis`) that factor bodies can call. The basis choice of `tangent_basis` (a branch on
    `|n_x| < 0.9`) becomes a branchless `where`. Norms that vanish at `d = 0` are shifted by
    `epsilon` (`v.norm()`), so `sin(t) / t` is finite there.

    On the first run fgopt derives the declaration with SymPy, checks it numerically (a
    `local` that does not invert `retract`, a storage of the wrong size or a non-finite
    `retract` raise an `FgoptError` naming the method), and writes a generated module to the
    kernel cache (batched numba `retract` / `local`, `storage_D_tangent` for factor Jacobians);
    later runs just load it. `Sphere` is the symbolic type for factor signatures,
    `Sphere.Value` the numeric value type.
    """),
    code("""
    from fgopt.symbolic import V1, V3, Abs, Matrix, Scalar, atan2, cos, sin, where


    @fgopt.manifold
    class Sphere:
        \"\"\"Unit vectors of R^3 (the chart of UnitVector3 above).\"\"\"

        storage_dim = 3
        dim = 2

        def identity():
            return V3(0, 0, 1)

        def direction(x):
            return V3(x[0], x[1], x[2])

        def basis(x):
            n = x.direction()
            a = where(Abs(n[0]) < 0.9, V3(1, 0, 0), V3(0, 1, 0))
            b1 = n.cross(a)
            b1 = b1 / b1.norm(0)
            b2 = n.cross(b1)
            return Matrix.shaped(3, 2)([[b1[0], b2[0]], [b1[1], b2[1]], [b1[2], b2[2]]])

        def retract(x, d):
            w = x.basis() * d
            theta = w.norm()                  # sqrt(|w|^2 + epsilon^2): finite sin(t)/t at 0
            return cos(theta) * x.direction() + (sin(theta) / theta) * w

        def local(x, y):
            n, m = x.direction(), y.direction()
            s = n.cross(m).norm()             # sin of the angle, shifted by epsilon
            return (atan2(s, n.dot(m), epsilon=0) / s) * (x.basis().T * m)

        def normalize(x):
            return x.direction() / x.direction().norm(0)


    s = Sphere.Value([1.0, 2.0, 3.0])
    print(s, "basis:\\n", s.basis())
    assert np.allclose(s.local(s.retract(d)), d)
    assert np.allclose(s.retract(d).direction(), n.retract(d).v)    # the same chart as UnitVector3
    print(fgopt.check_manifold(Sphere))
    """),
    md("""
    The plane fit of section 1 with the declared sphere: the residual is an `@fgopt.factor`
    over `Sphere` (its Jacobian comes from the declaration's `storage_D_tangent`), all 300
    factors run as one batched kernel, and the normals live in one storage array.
    """),
    code("""
    @fgopt.factor
    def plane_point(normal: Sphere, offset: Scalar, point: V3) -> V1:
        \"\"\"Signed distance normal . point - offset.\"\"\"
        return V1(normal.direction().dot(point) - offset)


    graph3, initial3 = fgopt.FactorGraph(), fgopt.Variables()
    for p in points:
        graph3.add(plane_point(key('n', 0), key('d', 0), p, loss=Isotropic.sigma(1, 0.02)))
    initial3.add(key('n', 0), Sphere.Value([0.0, 0.0, 1.0]))
    initial3.add(key('d', 0), 0.0)
    fgopt.optimize(graph3, initial3)                  # first run: kernels compile (cached on disk)
    t0 = time.perf_counter()
    result3 = fgopt.optimize(graph3, initial3, verbose=True)
    t_declared = time.perf_counter() - t0
    n3 = result3.values.at(key('n', 0))
    print(f"declared manifold: {t_declared * 1e3:.1f} ms per solve vs {t_python * 1e3:.0f} ms on the "
          f"Python path ({t_python / t_declared:.0f}x); normal {n3}")
    assert result3.success and len(result3.problem.batches) == 1
    assert np.allclose(n3.direction(), n_hat.v, atol=1e-6)
    assert abs(result3.values.at(key('d', 0)) - d_hat) < 1e-6
    cov3 = fgopt.marginals(result3, [key('n', 0)])[key('n', 0)]
    assert np.allclose(np.degrees(np.sqrt(np.diag(cov3))), sig_n, rtol=1e-3)   # same basis, same marginal
    """),
    md("""
    fgopt ships manifolds declared this way: `fgopt.symbolic.Unit3` (GTSAM's chart of the
    sphere), `OrientedPlane3` (unit normal and distance, GTSAM's) and `SE23` (extended poses:
    rotation, velocity, position), with numeric value types `fgopt.Unit3`, `fgopt.OrientedPlane3`,
    `fgopt.SE23`. Products need no code beyond a declaration:
    `@fgopt.manifold class NavState(fgopt.Product(Rot3, V3, V3, names=("attitude", "position",
    "velocity")))` gives a state whose accessors work in factor bodies and on numeric values.
    """),
    code("""
    from fgopt.symbolic import Rot3


    @fgopt.manifold
    class NavState(fgopt.Product(Rot3, V3, V3, names=("attitude", "position", "velocity"))):
        \"\"\"Attitude, position, velocity (SO(3) x R^3 x R^3).\"\"\"


    x = NavState.Value().retract(np.arange(9) * 0.1)
    print(x)
    print("plane:", fgopt.OrientedPlane3([0.0, 0.0, 1.0, -2.0]).retract([0.1, 0.0, 0.05]))
    assert np.allclose(x.position(), [0.3, 0.4, 0.5]) and isinstance(x.attitude(), fgopt.SO3)
    """),
]


# ----------------------------------------------------------------------------------------------
# 04: g2o pose graphs
# ----------------------------------------------------------------------------------------------
NB04 = [
    md("""
    # 04 — Pose graphs from g2o files

    Real benchmark pose graphs (Carlone et al.'s collection, as in the miniSAM paper's Table II):

    * `pose2d/input_M3500_g2o.g2o`: Manhattan world, 3500 SE(2) poses, 5453 edges;
    * `pose3d/sphere2500.g2o`: a robot on a sphere, 2500 SE(3) poses, 4949 edges.

    `fgopt.io.read_g2o` reads them into a `FactorGraph` (vectorized batches of between factors)
    and the initial `Variables` (the file's vertices). `add_prior=True` adds a tight prior on the
    first pose to fix the gauge (needed for marginal covariances). We solve with LM, plot before /
    after with `fgopt.plot`, show the cost history, and compute the marginal covariance of one
    pose with `fgopt.marginals`.

    The files are read from `$FGOPT_DATA` (default `../shared/data` next to the repository). If
    the folder is absent, the notebook uses a generated Manhattan-world graph
    (`fgopt.datasets.manhattan_2d`) and a generated 3D grid (`fgopt.datasets.grid_3d`) instead.
    """),
    code("""
    import time

    import matplotlib.pyplot as plt
    import numpy as np

    import fgopt
    from fgopt import key
    """),
    DATA_CELL,
    md("""
    ## Load

    `QUOTED` are the final costs other solvers (GTSAM, Ceres) reach on these files; fgopt's cost
    is GTSAM's `graph.error` (`0.5 * sum` of squared whitened residuals).
    """),
    code("""
    QUOTED = {"input_M3500_g2o.g2o": 68.957, "sphere2500.g2o": 675.70}
    problems = {}
    for rel in ["pose2d/input_M3500_g2o.g2o", "pose3d/sphere2500.g2o"]:
        path = DATA / rel
        if path.is_file():
            t0 = time.perf_counter()
            graph, initial = fgopt.io.read_g2o(path, add_prior=True)
            print(f"read {rel} in {time.perf_counter() - t0:.2f} s: {graph}")
            problems[path.name] = (graph, initial, None)
        else:
            print(f"{path} is absent: using a generated graph instead")
    if "input_M3500_g2o.g2o" not in problems:
        syn = fgopt.datasets.manhattan_2d(num_poses=3500, seed=0)
        problems["manhattan_2d (generated)"] = (syn.graph, syn.initial, syn.truth)
    if "sphere2500.g2o" not in problems:
        syn = fgopt.datasets.grid_3d(num_poses=1000, seed=0)
        problems["grid_3d (generated)"] = (syn.graph, syn.initial, syn.truth)
    """),
    md("""
    ## Solve

    Levenberg-Marquardt with the default linear solver (`"auto"`: CHOLMOD's sparse Cholesky for
    problems of this size). `verbose=True` prints one row per iteration.
    """),
    code("""
    results = {}
    for name, (graph, initial, truth) in problems.items():
        print(f"=== {name}")
        t0 = time.perf_counter()
        results[name] = fgopt.optimize(graph, initial, method="lm", verbose=True)
        print(f"wall time {time.perf_counter() - t0:.2f} s\\n")
    """),
    code("""
    def absolute_trajectory_error(values, truth):
        \"\"\"RMS position error after aligning the first poses (both graphs have a prior there).\"\"\"
        keys = sorted(truth.keys())
        d = [values.at(k).local(truth.at(k)) for k in keys]
        pos = np.array([v[-3:] if v.shape[0] == 6 else v[1:] for v in d])
        return float(np.sqrt(np.mean(np.sum(pos ** 2, axis=1))))

    print(f"{'problem':28s} {'status':10s} {'iters':>5s} {'initial cost':>14s} {'final cost':>12s} {'quoted':>8s} {'time (s)':>8s}")
    for name, r in results.items():
        quoted = QUOTED.get(name)
        print(f"{name:28s} {r.status.value:10s} {r.iterations:5d} {r.initial_cost:14.6g} {r.final_cost:12.6g} "
              f"{quoted if quoted else '-':>8} {r.timing['total']:8.2f}")
        assert r.success, (name, r.message)
        assert r.final_cost < 1e-2 * r.initial_cost
        if quoted is not None:     # the same optimum as GTSAM / Ceres
            assert abs(r.final_cost - quoted) < 1e-3 * quoted, (name, r.final_cost, quoted)
        truth = problems[name][2]
        if truth is not None:      # generated graphs: compare with the ground truth
            ate = absolute_trajectory_error(r.values, truth)
            print(f"    absolute trajectory error vs truth: {ate:.3f} m")
            assert ate < 1.0
    """),
    md("""
    ## Before / after and the cost history

    `fgopt.plot.plot_pose_graph(graph, values, initial=...)` draws the optimized trajectory
    over the initial guess (dashed) with the loop closures; `fgopt.plot.plot_cost_history` plots
    the cost of every accepted iterate on a log scale.
    """),
    code("""
    fig = plt.figure(figsize=(13, 4.2 * len(results)), layout="constrained")
    for row, (name, r) in enumerate(results.items()):
        graph, initial, _ = problems[name]
        dim3 = initial.at(initial.keys()[0]).dim() == 6
        ax0 = fig.add_subplot(len(results), 3, 3 * row + 1, projection="3d" if dim3 else None)
        fgopt.plot.plot_pose_graph(graph, initial, ax=ax0, loop_closures=False, title=f"{name}: initial")
        ax1 = fig.add_subplot(len(results), 3, 3 * row + 2, projection="3d" if dim3 else None)
        fgopt.plot.plot_pose_graph(graph, r.values, ax=ax1, title=f"{name}: optimized")
        fgopt.plot.plot_cost_history(r, ax=fig.add_subplot(len(results), 3, 3 * row + 3))
    plt.show()
    """),
    md("""
    ## Marginal covariance of one pose

    At the optimum, the Gaussian approximation of the posterior has covariance `H^-1`
    (`H = J^T W J`). `fgopt.marginals(result, [key])` factors `H` once and returns the blocks of
    `H^-1` of the requested poses, in each pose's tangent space at the estimate: SE(2) order
    `[theta, x, y]` (translation in the *body* frame, GTSAM's Pose2 convention), SE(3) `[w, v]`.
    The first pose `x0` is pinned by the prior, so uncertainty grows with the distance (in the graph)
    from it.
    """),
    code("""
    name2d = next(n for n in results if problems[n][1].at(problems[n][1].keys()[0]).dim() == 3)
    r = results[name2d]
    k = key('x', 1000)
    t0 = time.perf_counter()
    cov = fgopt.marginals(r, [key('x', 0), k])
    print(f"marginals in {time.perf_counter() - t0:.3f} s")
    np.set_printoptions(precision=5, suppress=True)
    print(f"covariance of x1000 ({name2d}), tangent order (theta, x, y):\\n{cov[k]}")
    sig = np.sqrt(np.diag(cov[k]))
    print(f"1-sigma: theta {np.degrees(sig[0]):.3f} deg, x {sig[1]:.3f} m, y {sig[2]:.3f} m")
    sig0 = np.sqrt(np.diag(cov[key('x', 0)]))
    print(f"1-sigma of the prior-pinned first pose x0: {sig0}")
    assert np.all(np.linalg.eigvalsh(cov[k]) > 0)            # a proper covariance
    assert np.allclose(cov[k], cov[k].T)
    assert sig0.max() < 1e-2 < sig[1:].max()                 # x0 pinned, x1000 uncertain
    """),
    md("""
    The 3-sigma position ellipse of `x1000` (body-frame covariance rotated into the world
    frame with the pose's rotation), over the neighbouring optimized trajectory:
    """),
    code("""
    pose = r.values.at(k)
    Rw = pose.rotation().matrix()
    P = Rw @ cov[k][1:, 1:] @ Rw.T
    w, V = np.linalg.eigh(P)
    a = np.linspace(0, 2 * np.pi, 100)
    ell = pose.translation()[:, None] + 3 * V @ (np.sqrt(w)[:, None] * np.array([np.cos(a), np.sin(a)]))
    xy = np.array([r.values.at(key('x', i)).translation() for i in range(900, 1101)])
    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot(xy[:, 0], xy[:, 1], ".-", ms=2, lw=0.5, label="x900..x1100")
    ax.plot(ell[0], ell[1], "r-", label="3-sigma ellipse of x1000")
    ax.plot(*pose.translation(), "r+", ms=12)
    ax.set_aspect("equal"); ax.legend(); ax.set_title(f"marginal covariance ({name2d})")
    plt.show()
    """),
]


# ----------------------------------------------------------------------------------------------
# 05: bundle adjustment
# ----------------------------------------------------------------------------------------------
NB05 = [
    md("""
    # 05 — Bundle adjustment on a BAL problem

    *Bundle Adjustment in the Large* (Agarwal et al., 2010) problems: cameras with 9 parameters
    `[r (angle-axis), t, f, k1, k2]` and 3D points; each observation is a 2D image point. The
    predicted pixel is `f (1 + k1 |p|^2 + k2 |p|^4) p` with `p = -P_xy / P_z`, `P = R(r) X + t`.
    `fgopt.io.read_bal` reads a file into one batch of generated reprojection factors
    (`bal_reprojection`, an `@fgopt.factor` over an R^9 camera and an R^3 point) with unit noise,
    so the cost is `0.5 * sum |e|^2` in pixels².

    We use `bal/problem-49-7776-pre.txt` (Ladybug, 49 cameras, 7776 points, 31843 observations);
    if it is absent we fall back to `bal/dubrovnik-3-7-pre.txt`, and to a synthetic scene without
    the data folder. We report the initial / final cost and the RMS reprojection error, and plot
    the cameras and points.
    """),
    code("""
    import time

    import matplotlib.pyplot as plt
    import numpy as np

    import fgopt
    from fgopt import key
    from fgopt.manifolds import vector_kind
    """),
    DATA_CELL,
    md("""
    ### A synthetic scene (only used without the data folder)

    Cameras near the origin looking down their `-z` axis (BAL's convention) at a cloud of points,
    projected with the BAL model in numpy, with 0.5 px noise; the initial guess perturbs cameras
    and points. It is built with `graph.add_batch`, the same way `read_bal` builds its graph.
    """),
    code("""
    def rotate(r, X):
        \"\"\"Rotate the points X (n, 3) by the angle-axis vectors r (n, 3) (Rodrigues).\"\"\"
        th = np.linalg.norm(r, axis=1, keepdims=True)
        k = r / np.where(th > 0, th, 1.0)
        return (X * np.cos(th) + np.cross(k, X) * np.sin(th)
                + k * np.sum(k * X, axis=1, keepdims=True) * (1 - np.cos(th)))

    def bal_project(cams, X):
        \"\"\"BAL projection of points X (n, 3) by cameras (n, 9).\"\"\"
        P = rotate(cams[:, :3], X) + cams[:, 3:6]
        p = -P[:, :2] / P[:, 2:3]
        r2 = np.sum(p ** 2, axis=1, keepdims=True)
        return cams[:, 6:7] * (1 + cams[:, 7:8] * r2 + cams[:, 8:9] * r2 ** 2) * p

    def synthetic_scene(num_cameras=12, num_points=400, seed=0):
        rng = np.random.default_rng(seed)
        cams = np.column_stack([0.05 * rng.normal(size=(num_cameras, 3)), rng.normal(size=(num_cameras, 3)),
                                np.full(num_cameras, 500.0), np.zeros((num_cameras, 2))])
        pts = rng.uniform([-4, -4, -14], [4, 4, -8], size=(num_points, 3))
        ci, pj = np.meshgrid(np.arange(num_cameras), np.arange(num_points), indexing="ij")
        ci, pj = ci.ravel(), pj.ravel()
        meas = bal_project(cams[ci], pts[pj]) + 0.5 * rng.normal(size=(ci.shape[0], 2))
        graph = fgopt.FactorGraph()
        keys = np.column_stack([int(key('c', 0)) + ci, int(key('p', 0)) + pj])
        graph.add_batch(fgopt.io.reprojection_kernel(), keys, meas)
        noisy_cams = cams + np.concatenate([0.01 * rng.normal(size=(num_cameras, 6)), np.zeros((num_cameras, 3))], 1)
        initial = fgopt.Variables()
        initial.add_rows([int(key('c', i)) for i in range(num_cameras)], vector_kind(9), noisy_cams)
        initial.add_rows([int(key('p', j)) for j in range(num_points)], vector_kind(3),
                         pts + 0.1 * rng.normal(size=pts.shape))
        return graph, initial
    """),
    md("## Load"),
    code("""
    candidates = ["bal/problem-49-7776-pre.txt", "bal/dubrovnik-3-7-pre.txt"]
    path = next((DATA / c for c in candidates if (DATA / c).is_file()), None)
    if path is not None:
        t0 = time.perf_counter()
        graph, initial = fgopt.io.read_bal(path)
        source = path.name
        print(f"read {path.name} in {time.perf_counter() - t0:.2f} s")
    else:
        print(f"no BAL file under {DATA}: using a synthetic scene")
        graph, initial = synthetic_scene()
        source = "synthetic scene"
    batch = graph.batches[0]
    cam_keys = sorted(k for k, val in initial.items() if val.shape[0] == 9)
    print(f"{source}: {len(cam_keys)} cameras, {len(initial) - len(cam_keys)} points, "
          f"{batch.keys.shape[0]} observations")
    """),
    md("""
    ## Reprojection errors

    The batch holds the observation keys `(camera, point)` and the measured pixels (its
    constants); the kernel evaluates all residuals in one call. The RMS reprojection error is
    over observations, `sqrt(mean |e|^2)` (pixels), so `cost = 0.5 * n * RMS^2`.
    """),
    code("""
    def reprojection_errors(values):
        cams = np.array([values.at(k) for k in batch.keys[:, 0]])
        pts = np.array([values.at(k) for k in batch.keys[:, 1]])
        res = batch.kernel.residual((cams, pts), batch.constants)
        return np.linalg.norm(res, axis=1)

    e0 = reprojection_errors(initial)
    print(f"initial: cost {graph.error(initial):.6g}, RMS {np.sqrt(np.mean(e0 ** 2)):.3f} px, median {np.median(e0):.3f} px")
    assert np.isclose(0.5 * np.sum(e0 ** 2), graph.error(initial), rtol=1e-9)
    if path is None:   # the generated kernel agrees with the numpy BAL model
        c = np.array([initial.at(k) for k in batch.keys[:, 0]])
        x = np.array([initial.at(k) for k in batch.keys[:, 1]])
        assert np.allclose(batch.kernel.residual((c, x), batch.constants), bal_project(c, x) - batch.constants)
    """),
    md("""
    ## Solve

    LM; `linear_solver="auto"` picks a sparse Cholesky for the (cameras + points) system. BA has a
    7-DOF gauge freedom (similarity transform of the whole scene) that nothing fixes: LM's
    damping keeps the steps well-posed.
    """),
    code("""
    t0 = time.perf_counter()
    result = fgopt.optimize(graph, initial, method="lm", verbose=True)
    wall = time.perf_counter() - t0
    print(f"wall time {wall:.1f} s")
    """),
    code("""
    e1 = reprojection_errors(result.values)
    rms0, rms1 = np.sqrt(np.mean(e0 ** 2)), np.sqrt(np.mean(e1 ** 2))
    print(f"{'':8s} {'cost':>12s} {'RMS (px)':>9s} {'median (px)':>12s}")
    print(f"{'initial':8s} {result.initial_cost:12.6g} {rms0:9.3f} {np.median(e0):12.3f}")
    print(f"{'final':8s} {result.final_cost:12.6g} {rms1:9.3f} {np.median(e1):12.3f}")
    print(f"{result.status.value} after {result.iterations} iterations, {wall:.1f} s")

    assert result.status in (fgopt.Status.CONVERGED, fgopt.Status.MAX_ITERATIONS), result.message
    assert np.isclose(0.5 * np.sum(e1 ** 2), result.final_cost, rtol=1e-6)
    assert result.final_cost < 0.05 * result.initial_cost
    if source == "problem-49-7776-pre.txt":
        assert result.final_cost < 1.01 * 13344.3       # Ceres' final cost on this problem
        assert rms1 < 1.0
    elif path is None:
        assert rms1 < 1.0                               # 0.5 px noise per coordinate
    """),
    md("""
    ## Cameras and points

    `fgopt.plot.plot_bundle` draws the camera centres (`-R^T t`) and the points (the view is
    cropped to the bulk of the scene; BAL files have far outliers). Below: before and after, and
    the distribution of reprojection errors.
    """),
    code("""
    fig = plt.figure(figsize=(15, 4.8), layout="constrained")
    fgopt.plot.plot_bundle(initial, ax=fig.add_subplot(1, 3, 1, projection="3d"), title="initial")
    fgopt.plot.plot_bundle(result.values, ax=fig.add_subplot(1, 3, 2, projection="3d"), title="optimized")
    ax = fig.add_subplot(1, 3, 3)
    bins = np.logspace(-3, np.log10(max(e0.max(), 10)), 60)
    ax.hist(e0, bins=bins, alpha=0.6, label=f"initial (RMS {rms0:.2f} px)")
    ax.hist(e1, bins=bins, alpha=0.6, label=f"final (RMS {rms1:.2f} px)")
    ax.set_xscale("log"); ax.set_xlabel("reprojection error (px)"); ax.set_ylabel("observations")
    ax.legend(); ax.set_title(source)
    plt.show()
    """),
]


# ----------------------------------------------------------------------------------------------
# 06: on-manifold EKF
# ----------------------------------------------------------------------------------------------
NB06 = [
    md("""
    # 06 — An on-manifold EKF for a strapdown IMU + GPS

    This follows the *On-Manifold EKF with SymForce* notebook (a fixed-wing strapdown INS):
    an IMU drives the prediction, 5 Hz GPS position fixes correct it, and the attitude lives on
    SO(3). The continuous model is the 10-state strapdown kinematics

    * state: world position `p`, world velocity `v` (Z up), body-to-world attitude quaternion `q`,
    * input: gyro `w` (body angular rate) and accelerometer `f` (body specific force),

    `der(p) = v`, `der(v) = R(q) f + g`, `der(q) = 1/2 q ⊗ [0, w]`, `g = (0, 0, -9.81)`.

    Here the model is written once, as a Python function over **fgopt's symbolic types**
    (`V3`, and `Rot3` for the attitude: quaternion storage, 3-D tangent), and two public APIs
    do the rest:

    * `fgopt.symbolic.generate(fn, which=...)` compiles it into a numba function that returns
      the next state and its **tangent-space Jacobians** (the role of SymForce's
      `Codegen.with_linearization`);
    * `fgopt.filters.ManifoldEKF(process, measurements, x0, P0)` is an error-state EKF over the
      product manifold `R^3 x R^3 x SO(3)` built from such functions: `predict(u, dt, Q)`,
      `update(z, R, which)`, Joseph-form covariance update, corrections applied through the
      retraction.

    Then we simulate a coordinated turn with a biased, noisy IMU and show dead reckoning
    drifting by hundreds of metres while the EKF stays near the GPS noise level.
    """),
    code("""
    import time

    import matplotlib.pyplot as plt
    import numpy as np

    from fgopt import SO3
    from fgopt.filters import ManifoldEKF
    from fgopt.symbolic import V3, Rot3, Scalar, generate

    T_START = time.perf_counter()
    """),
    md("""
    ## 1. The discrete process model, over symbolic types

    Over one IMU interval `dt` with constant `w` and `f`, the quaternion ODE has the exact solution
    `q+ = q ⊗ Exp(w dt)`, i.e. `R+ = R Exp(w dt)` on SO(3) (unit norm by construction); position
    and velocity are integrated with the acceleration `a = R f + g` held over the step.
    `Rot3 * V3` rotates a vector; `Rot3.exp` is the SO(3) exponential (with fgopt's
    epsilon-safe handling of the zero rotation). The function returns the next values of its
    first three arguments: that is what makes them the filter's state.
    """),
    code("""
    GRAVITY = 9.81

    def propagate(p: V3, v: V3, R: Rot3, w: V3, f: V3, dt: Scalar):
        \"\"\"One strapdown step: returns (p+, v+, R+).\"\"\"
        a = R * f + V3(0, 0, -GRAVITY)
        return p + v * dt + a * (dt * dt / 2), v + a * dt, R * Rot3.exp(w * dt)


    def gps(p: V3) -> V3:
        \"\"\"The GPS measures the position.\"\"\"
        return p
    """),
    md("""
    ## 2. Generated code with tangent-space Jacobians: `F` and `G`

    The error state `d = (dp, dv, dtheta)` perturbs the estimate by the retraction
    `x ⊞ d = (p + dp, v + dv, R Exp(dtheta))`. The EKF needs

    `F = ∂ [ f(x ⊞ d) ⊟ f(x) ] / ∂d` at `d = 0` (9x9), and `G = ∂ [ f(x, u + e) ⊟ f(x, u) ] / ∂e` (9x6),

    where `⊟` of the attitude is `Log(R+^-1 R+(d))`. `generate` derives exactly these (SymPy,
    first-order retraction), CSEs them and writes a numba module to fgopt's kernel cache (a
    second run loads it without SymPy). `which` names the arguments to differentiate by; the
    stacked Jacobian has one row block per output (in its tangent space) and one column block
    per argument of `which`.
    """),
    code("""
    t0 = time.perf_counter()
    step = generate(propagate, which=["p", "v", "R", "w", "f"])
    print(step)
    print(f"generated (or loaded from the cache) in {time.perf_counter() - t0:.1f} s; "
          f"column blocks {step.cols}")
    print("\\n".join(step.source.splitlines()[:12]))
    """),
    md("""
    ### Checking the generated Jacobians

    Against (a) central differences through the manifold retraction, using fgopt's numeric `SO3`
    (the twin of `Rot3`: same storage, `R.retract(d) = R * SO3.exp(d)`), and (b) the
    textbook closed forms: `∂v+/∂dθ = -R [f]x dt`, `∂R+/∂dθ = Exp(w dt)^T`,
    `∂R+/∂w = J_r(w dt) dt` (right Jacobian of SO(3)), `∂v+/∂f = R dt`. The first call also
    compiles the function (or loads it from numba's cache). Arguments are numeric values:
    arrays for vectors, an `SO3` for the `Rot3`.
    """),
    code("""
    def boxplus(x, d):
        \"\"\"(p, v, R) ⊞ (dp, dv, dtheta).\"\"\"
        return x[0] + d[:3], x[1] + d[3:6], x[2].retract(d[6:])

    def boxminus(x, y):
        \"\"\"y ⊟ x in the tangent space at x.\"\"\"
        return np.concatenate([y[0] - x[0], y[1] - x[1], x[2].local(y[2])])

    def skew(a):
        return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])

    def right_jacobian(phi):
        th = np.linalg.norm(phi)
        K = skew(phi)
        return np.eye(3) - (1 - np.cos(th)) / th**2 * K + (th - np.sin(th)) / th**3 * K @ K

    rng_check = np.random.default_rng(42)
    x0 = (np.array([10.0, -5.0, 200.0]), np.array([19.0, 6.0, 0.5]), SO3.random(rng_check))
    w0, f0, h = np.array([0.1, -0.05, 0.25]), np.array([0.3, -0.2, 10.4]), 0.01
    t0 = time.perf_counter()
    x1, J = step(*x0, w0, f0, h)
    print(f"first call (compile or cache load) {time.perf_counter() - t0:.2f} s")
    F0, G0 = J[:, :9], J[:, 9:]

    F_fd = np.zeros((9, 9))
    for i in range(9):
        e = np.zeros(9); e[i] = 1e-6
        plus, minus = step.value(*boxplus(x0, e), w0, f0, h), step.value(*boxplus(x0, -e), w0, f0, h)
        F_fd[:, i] = (boxminus(x1, plus) - boxminus(x1, minus)) / 2e-6
    G_fd = np.zeros((9, 6))
    for i in range(6):
        e = np.zeros(6); e[i] = 1e-6
        plus = step.value(*x0, w0 + e[:3], f0 + e[3:], h)
        minus = step.value(*x0, w0 - e[:3], f0 - e[3:], h)
        G_fd[:, i] = (boxminus(x1, plus) - boxminus(x1, minus)) / 2e-6
    Rm = x0[2].matrix()
    print("max |F - F_finite_diff| =", np.abs(F0 - F_fd).max(), "  max |G - G_finite_diff| =", np.abs(G0 - G_fd).max())
    assert np.abs(F0 - F_fd).max() < 1e-6 and np.abs(G0 - G_fd).max() < 1e-6
    assert np.allclose(F0[3:6, 6:9], -Rm @ skew(f0) * h, atol=1e-12)
    assert np.allclose(F0[6:9, 6:9], SO3.exp(w0 * h).matrix().T, atol=1e-12)
    assert np.allclose(G0[6:9, 0:3], right_jacobian(w0 * h) * h, atol=1e-12)
    assert np.allclose(G0[3:6, 3:6], Rm * h, atol=1e-12)
    """),
    md("""
    ## 3. Truth: a coordinated turn

    A level flight at `V = 20 m/s`: straight for 5 s, roll into a `phi = 0.45 rad` (26°) bank over
    3 s, hold it for 20 s, roll out, and fly straight to `t = 40 s`. In a coordinated turn the
    specific force has no lateral component, which gives the turn rate `psi' = -g tan(phi) / V`
    (a right turn for a positive bank in the FLU body frame). The attitude is
    `R = Rz(psi) Rx(phi)`, so the body rates are `w = (phi', psi' sin(phi), psi' cos(phi))` and
    the specific force is `f = R^T (a - g) = (0, 0, g / cos(phi))`. Heading and position are
    integrated on a 1 ms grid; the IMU is sampled at the middle of each 10 ms interval.
    """),
    code("""
    DT, T_END, V = 0.01, 40.0, 20.0
    N = round(T_END / DT)
    PHI_MAX = 0.45
    knots = [0, 5, 8, 28, 31, T_END]

    def bank(t):
        return np.interp(t, knots, [0, 0, PHI_MAX, PHI_MAX, 0, 0])

    def bank_rate(t):
        rate = PHI_MAX / 3
        return np.where((t > 5) & (t < 8), rate, 0.0) - np.where((t > 28) & (t < 31), rate, 0.0)

    def heading_rate(t):
        return -GRAVITY * np.tan(bank(t)) / V

    fine = 10                                               # 1 ms integration grid
    tf = np.arange(N * fine + 1) * (DT / fine)
    psi_f = np.concatenate([[0.0], np.cumsum(0.5 * (heading_rate(tf[1:]) + heading_rate(tf[:-1])) * DT / fine)])
    vel_f = V * np.column_stack([np.cos(psi_f), np.sin(psi_f), np.zeros_like(psi_f)])
    pos_f = np.concatenate([[np.zeros(3)], np.cumsum(0.5 * (vel_f[1:] + vel_f[:-1]) * DT / fine, axis=0)])
    pos_f += [0.0, 0.0, 200.0]

    def attitude(psi, phi):
        return SO3.from_axis_angle([0, 0, 1], psi) * SO3.from_axis_angle([1, 0, 0], phi)

    t = np.arange(N + 1) * DT
    truth_p, truth_v = pos_f[::fine], vel_f[::fine]
    truth_R = [attitude(psi_f[k * fine], bank(tk)) for k, tk in enumerate(t)]

    # ideal IMU at the interval midpoints
    tm = t[:-1] + DT / 2
    psi_m, phi_m, psid_m = psi_f[fine // 2::fine][:N], bank(tm), heading_rate(tm)
    gyro = np.column_stack([bank_rate(tm), psid_m * np.sin(phi_m), psid_m * np.cos(phi_m)])
    acc_world = V * psid_m[:, None] * np.column_stack([-np.sin(psi_m), np.cos(psi_m), np.zeros(N)])
    accel = np.array([attitude(a, b).matrix().T @ (aw - [0, 0, -GRAVITY]) for a, b, aw in zip(psi_m, phi_m, acc_world)])
    U = np.column_stack([gyro, accel])                      # u = [w, f], the inputs in argument order
    print(f"heading change {np.degrees(psi_f[-1]):.0f} deg, turn rate {np.degrees(heading_rate(15.0)):.1f} deg/s, "
          f"specific force in the turn {accel[1500].round(3)} (g / cos(phi) = {GRAVITY / np.cos(PHI_MAX):.3f})")
    assert np.allclose(accel[1500, :2], 0, atol=1e-9)      # coordinated: no lateral force
    """),
    md("""
    ## 4. Sensors: a biased, noisy IMU and 5 Hz GPS

    The IMU the filter sees has constant biases (gyro ~0.6°/s, accelerometer ~0.1 m/s²) plus white
    noise at every 100 Hz sample; the GPS measures position with 1.5 m noise per axis every 0.2 s.
    """),
    code("""
    rng = np.random.default_rng(0)
    GYRO_BIAS, ACC_BIAS = np.array([0.01, -0.008, 0.012]), np.array([0.10, -0.05, 0.08])
    GYRO_SIGMA, ACC_SIGMA = 0.002, 0.05
    U_meas = U.copy()
    U_meas[:, :3] += GYRO_BIAS + GYRO_SIGMA * rng.standard_normal((N, 3))
    U_meas[:, 3:] += ACC_BIAS + ACC_SIGMA * rng.standard_normal((N, 3))

    GPS_SIGMA, GPS_EVERY = 1.5, round(0.2 / DT)
    gps_steps = np.arange(GPS_EVERY, N + 1, GPS_EVERY)
    gps_fixes = truth_p[gps_steps] + GPS_SIGMA * rng.standard_normal((gps_steps.shape[0], 3))
    print(f"{gps_fixes.shape[0]} GPS fixes, {N} IMU samples")
    """),
    md("""
    ## 5. The filter

    `ManifoldEKF(propagate, [gps], x0, P0)` generates (or loads from the cache) three functions
    from `propagate` and `gps` with `generate`: the process with `[F | G]`, the GPS innovation
    `z - p` with `H`, and the state retraction with the covariance reset Jacobian, plus one
    compiled step per `predict` / `update`.

    * **Predict** (every IMU sample): `x <- f(x, u)` and `P <- F P F^T + G Q_imu G^T + Q_b`.
      `Q_imu` is the white IMU noise (the covariance of `u` over one sample); `Q_b` is extra
      velocity / attitude random walk that absorbs the (unestimated) biases.
    * **Update** (GPS): innovation `y = z - p`, `K = P H^T (H P H^T + R)^-1`, the correction
      `K y` applied with the retraction `x <- x ⊞ K y` (the attitude stays a unit quaternion and
      its covariance a 3x3 block), Joseph-form covariance update, then the covariance moved to
      the tangent space at the corrected state (the ESKF reset).

    Dead reckoning is the same filter with no updates. The initial estimate is off by
    (3, -3, 2) m and (1, -1, 0.5) m/s.
    """),
    code("""
    x_start = (truth_p[0] + [3.0, -3.0, 2.0], truth_v[0] + [1.0, -1.0, 0.5], truth_R[0])
    P_start = np.diag([5.0, 5.0, 5.0, 2.0, 2.0, 2.0, 0.01, 0.01, 0.01])
    Q_imu = np.diag([GYRO_SIGMA**2] * 3 + [ACC_SIGMA**2] * 3)
    Q_b = np.diag([0.0] * 3 + [0.05] * 3 + [1e-4] * 3) * DT
    R_gps = np.eye(3) * GPS_SIGMA**2

    t0 = time.perf_counter()
    ekf = ManifoldEKF(propagate, [gps], x0=x_start, P0=P_start)
    print(f"filter ready in {time.perf_counter() - t0:.1f} s")
    print(ekf)

    def run(ekf, U, updates=True):
        est = [ekf.state]
        sigma = [np.sqrt(np.diag(ekf.covariance))]
        fix = 0
        for k in range(N):
            ekf.predict(U[k], DT, Q_imu, Q_b)
            if updates and fix < len(gps_steps) and gps_steps[fix] == k + 1:
                ekf.update(gps_fixes[fix], R_gps, "gps")
                fix += 1
            est.append(ekf.state)
            sigma.append(np.sqrt(np.diag(ekf.covariance)))
        return est, np.array(sigma)

    t0 = time.perf_counter()
    est, sigma = run(ekf, U_meas)
    print(f"EKF over {N} steps in {time.perf_counter() - t0:.2f} s (with per-step Python bookkeeping)")
    print(ekf)

    ideal, _ = run(ManifoldEKF(propagate, [gps], x0=(truth_p[0], truth_v[0], truth_R[0]), P0=P_start), U, updates=False)
    dead, _ = run(ManifoldEKF(propagate, [gps], x0=(truth_p[0], truth_v[0], truth_R[0]), P0=P_start), U_meas, updates=False)
    """),
    md("""
    ## 6. Results

    With the *ideal* IMU, open-loop integration reproduces the truth (a check of the model and
    the simulation); with the real one the biases integrate into an unbounded position error
    (tilt error from the gyro bias misprojects gravity, and position error grows with `t^3`).
    """),
    code("""
    def position_error(est):
        return np.linalg.norm(np.array([e[0] for e in est]) - truth_p, axis=1)

    def attitude_error_deg(est):
        return np.degrees([np.linalg.norm(e[2].local(r)) for e, r in zip(est, truth_R)])

    e_ideal, e_dead, e_ekf = position_error(ideal), position_error(dead), position_error(est)
    e_gps = np.linalg.norm(gps_fixes - truth_p[gps_steps], axis=1)
    settled = t >= 5.0
    a_dead, a_ekf = attitude_error_deg(dead), attitude_error_deg(est)
    pos_sigma = np.sqrt(np.sum(sigma[:, :3] ** 2, axis=1))
    within = np.mean(e_ekf[settled] < 3 * pos_sigma[settled])
    print(f"ideal IMU, open loop: max position error {e_ideal.max():.3f} m")
    print(f"{'':28s} {'dead reckoning':>15s} {'EKF':>8s} {'GPS fixes':>10s}")
    print(f"{'final position error (m)':28s} {e_dead[-1]:15.1f} {e_ekf[-1]:8.2f}")
    print(f"{'RMS position error (m)':28s} {np.sqrt(np.mean(e_dead**2)):15.1f} {np.sqrt(np.mean(e_ekf**2)):8.2f} "
          f"{np.sqrt(np.mean(e_gps**2)):10.2f}")
    print(f"{'max position error, t>5s (m)':28s} {e_dead[settled].max():15.1f} {e_ekf[settled].max():8.2f}")
    print(f"{'final attitude error (deg)':28s} {a_dead[-1]:15.1f} {a_ekf[-1]:8.2f}")
    print(f"EKF position error inside its 3-sigma bound {100 * within:.0f}% of the time (t > 5 s)")
    print(f"total notebook compute so far: {time.perf_counter() - T_START:.1f} s")

    assert e_ideal.max() < 1.0
    assert e_dead[-1] > 200.0                                      # hundreds of metres of drift
    assert np.sqrt(np.mean(e_ekf[settled] ** 2)) < 2 * GPS_SIGMA   # near the GPS noise level ...
    assert np.sqrt(np.mean(e_ekf[settled] ** 2)) < np.sqrt(np.mean(e_gps ** 2))   # ... and below a raw fix
    assert e_ekf[settled].max() < 4 * GPS_SIGMA
    assert e_dead[-1] > 100 * e_ekf[-1]
    assert a_ekf[-1] < a_dead[-1]
    assert within > 0.9
    """),
    code("""
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.6), layout="constrained")
    dead_p, est_p = np.array([e[0] for e in dead]), np.array([e[0] for e in est])
    ax = axes[0]
    ax.plot(truth_p[:, 0], truth_p[:, 1], "k-", lw=2, label="truth")
    ax.plot(dead_p[:, 0], dead_p[:, 1], "r--", label="dead reckoning")
    ax.plot(est_p[:, 0], est_p[:, 1], "b-", lw=1, label="EKF")
    ax.scatter(gps_fixes[:, 0], gps_fixes[:, 1], s=3, color="tab:orange", label="GPS")
    ax.set_xlabel("x [m]"); ax.set_ylabel("y [m]"); ax.axis("equal"); ax.legend(fontsize="small")
    ax.set_title("ground track")
    ax = axes[1]
    ax.semilogy(t, np.maximum(e_dead, 1e-3), "r--", label="dead reckoning")
    ax.semilogy(t, e_ekf, "b-", lw=1, label="EKF")
    ax.semilogy(t, 3 * pos_sigma, "b:", lw=1, label="EKF 3-sigma")
    ax.axhline(GPS_SIGMA * np.sqrt(3), color="tab:orange", ls="-.", label="GPS noise (3-D RMS)")
    ax.set_xlabel("t [s]"); ax.set_ylabel("position error [m]"); ax.legend(fontsize="small")
    ax.set_ylim(0.05, None); ax.set_title("position error vs truth")
    ax = axes[2]
    ax.plot(t, a_dead, "r--", label="dead reckoning")
    ax.plot(t, a_ekf, "b-", lw=1, label="EKF")
    ax.set_xlabel("t [s]"); ax.set_ylabel("attitude error [deg]"); ax.legend(fontsize="small")
    ax.set_title("attitude error |Log(R_est^-1 R_true)|")
    plt.show()
    """),
    md("""
    ## 7. Estimating the biases: a 15-DOF error state

    The attitude error above stays at a few degrees: this model does not estimate the gyro bias
    (0.6°/s here), and position fixes only observe attitude through accelerations. Adding bias
    states is a matter of two more `V3` arguments (and outputs) of the process function; the
    random walk of the biases goes into `Q_state`.
    """),
    code("""
    def propagate_with_biases(p: V3, v: V3, R: Rot3, bg: V3, ba: V3, w: V3, f: V3, dt: Scalar):
        a = R * (f - ba) + V3(0, 0, -GRAVITY)
        return p + v * dt + a * (dt * dt / 2), v + a * dt, R * Rot3.exp((w - bg) * dt), bg, ba

    ekf15 = ManifoldEKF(propagate_with_biases, [gps], x0=(*x_start, np.zeros(3), np.zeros(3)),
                        P0=np.diag([5.0] * 3 + [2.0] * 3 + [0.01] * 3 + [1e-4] * 3 + [0.05] * 3))
    Q_b15 = np.diag([0.0] * 3 + [1e-3] * 3 + [1e-6] * 3 + [1e-9] * 3 + [1e-6] * 3) * DT
    est15, fix = [ekf15.state], 0
    t0 = time.perf_counter()
    for k in range(N):
        ekf15.predict(U_meas[k], DT, Q_imu, Q_b15)
        if fix < len(gps_steps) and gps_steps[fix] == k + 1:
            ekf15.update(gps_fixes[fix], R_gps, "gps")
            fix += 1
        est15.append(ekf15.state)
    print(f"15-state EKF over {N} steps in {time.perf_counter() - t0:.2f} s")
    print(ekf15)
    e15, a15 = position_error(est15), attitude_error_deg(est15)
    print(f"RMS position error (t > 5 s): 9-state {np.sqrt(np.mean(e_ekf[settled]**2)):.2f} m, "
          f"15-state {np.sqrt(np.mean(e15[settled]**2)):.2f} m")
    print(f"final attitude error: 9-state {a_ekf[-1]:.2f} deg, 15-state {a15[-1]:.2f} deg")
    print("estimated gyro bias", ekf15["bg"].round(4), " true", GYRO_BIAS)
    print("estimated accel bias", ekf15["ba"].round(3), " true", ACC_BIAS)
    assert np.sqrt(np.mean(e15[settled] ** 2)) < 2 * GPS_SIGMA
    assert a15[-1] < a_ekf[-1]
    assert np.linalg.norm(ekf15["bg"] - GYRO_BIAS) < 0.5 * np.linalg.norm(GYRO_BIAS)
    print(f"total notebook compute: {time.perf_counter() - T_START:.1f} s")
    """),
    md("""
    ## Recap

    * The process model is written once, over `V3` and `Rot3`; `fgopt.symbolic.generate`
      compiles it with the 9x9 error-state transition and the 9x6 noise Jacobian in the Rot3
      tangent space (no finite differences, no hand-derived attitude Jacobians), checked above
      against finite differences and the textbook forms.
    * `fgopt.filters.ManifoldEKF` builds the whole error-state filter from that function and a
      one-line measurement function: corrections through the retraction (the quaternion stays on
      the unit sphere, the attitude covariance is a full-rank 3x3 block), Joseph-form update,
      covariance reset; one compiled call per predict and per update.
    * Dead reckoning with the biased IMU drifts by hundreds of metres in 40 s; the EKF holds the
      position error at the GPS noise level.
    * With bias states (two more arguments), the filter also recovers the gyro bias and the
      attitude. Heading is unobservable in straight, level flight and becomes observable in the
      turn (see the attitude panel).
    """),
]


# ----------------------------------------------------------------------------------------------
# 07: equality and inequality constraints
# ----------------------------------------------------------------------------------------------
NB07 = [
    md("""
    # 07 — Constraints: joint limits, a positive focal length, points on a plane

    `@fgopt.constraint` turns a typed symbolic function into a constraint type, exactly as
    `@fgopt.factor` does for residuals (same generated kernels, tangent-space Jacobians, any
    manifold). Its output `c(x)` must be `0`; with `inequality=True` it must be `<= 0`.
    Instances go into the graph with `graph.add`, and `fgopt.optimize` solves the graph with
    an augmented-Lagrangian loop around Levenberg-Marquardt. The result says how well the
    constraints hold (`result.constraint_violation`) and carries the Lagrange multipliers
    (`result.multipliers`, one array per constraint, `grad f + sum J^T lambda = 0`).

    Three small problems, each with a figure:

    1. inverse kinematics of a planar arm with joint limits (inequalities);
    2. a focal length kept above the lens' minimum (an inequality keeps it physical);
    3. noisy 3-D points put on one plane, the plane estimated with them (equalities over
       the declared manifold `OrientedPlane3`), checked against the closed-form plane fit.
    """),
    code("""
    import numpy as np
    import matplotlib.pyplot as plt

    import fgopt
    from fgopt import key
    from fgopt.symbolic import V1, V2, V3, OrientedPlane3, Scalar, cos, sin
    """),
    md("""
    ## 1. A planar arm reaching a target within joint limits

    Three links of lengths 1.0, 0.8 and 0.6. The cost keeps the joints near the rest pose
    (`0.5 sum q_i^2`); an equality puts the hand on the target; two inequalities per joint keep
    `|q_i| <= 1.5` rad (the elbow alone would like to bend further). With `|q_i| <= 1.2` the
    target is out of reach: the run ends `infeasible` (never `converged`), with the violation
    it could not remove.
    """),
    code("""
    LINKS = (1.0, 0.8, 0.6)


    @fgopt.factor
    def rest(q: Scalar) -> Scalar:
        return q


    @fgopt.constraint
    def hand_at(q0: Scalar, q1: Scalar, q2: Scalar, target: V2) -> V2:
        a0, a1, a2 = q0, q0 + q1, q0 + q1 + q2
        x = LINKS[0] * cos(a0) + LINKS[1] * cos(a1) + LINKS[2] * cos(a2)
        y = LINKS[0] * sin(a0) + LINKS[1] * sin(a1) + LINKS[2] * sin(a2)
        return V2(x - target[0], y - target[1])


    @fgopt.constraint(inequality=True)
    def joint_max(q: Scalar, limit: Scalar) -> Scalar:
        return q - limit


    @fgopt.constraint(inequality=True)
    def joint_min(q: Scalar, limit: Scalar) -> Scalar:
        return -limit - q


    def solve_arm(target, limit=None):
        graph, initial = fgopt.FactorGraph(), fgopt.Variables()
        for i in range(3):
            graph.add(rest(q=key("q", i)))
            initial.add(key("q", i), 0.1)
            if limit is not None:
                graph.add(joint_max(q=key("q", i), limit=limit))
                graph.add(joint_min(q=key("q", i), limit=limit))
        graph.add(hand_at(key("q", 0), key("q", 1), key("q", 2), np.asarray(target)))
        return fgopt.optimize(graph, initial)


    target = np.array([0.2, 1.1])
    free = solve_arm(target)
    limited = solve_arm(target, limit=1.5)
    too_tight = solve_arm(target, limit=1.2)
    for name, r in (("no limits", free), ("|q| <= 1.5", limited), ("|q| <= 1.2", too_tight)):
        q = [r.values.at(key("q", i)) for i in range(3)]
        print(f"{name:>11}: {r.status.value}, q = {np.round(q, 4)}, "
              f"violation {r.constraint_violation:.1e}")
    print("joint-limit multipliers:", np.round(np.concatenate(limited.multipliers[:-1]), 4))
    """),
    code("""
    def arm_points(q):
        a = np.cumsum(q)
        steps = np.c_[np.cos(a), np.sin(a)] * np.array(LINKS)[:, None]
        return np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])


    fig, ax = plt.subplots(figsize=(5, 4.5))
    for name, r, style in (("no limits", free, "--"), ("|q| <= 1.5", limited, "-")):
        q = [r.values.at(key("q", i)) for i in range(3)]
        pts = arm_points(q)
        ax.plot(pts[:, 0], pts[:, 1], style, marker="o", label=f"{name}: q = {np.round(q, 2)}")
    ax.plot(*target, "r*", ms=14, label="target")
    ax.set_aspect("equal")
    ax.legend(loc="lower left", fontsize=8)
    ax.set_title("planar arm inverse kinematics")
    plt.show()
    """),
    md("""
    Without limits the elbow bends past 1.5 rad; with them that joint sits on its limit (its
    multiplier is positive, the others' zero) and the other joints make up for it: the hand is
    still on the target.

    ## 2. A focal length kept above the lens' minimum

    A camera looks at points close to its optical axis: pixel offsets `u - cx` are small, so the
    focal length is poorly determined by the data, and with this noise the least-squares
    estimate comes out far too short (on other draws of the noise, close to zero). The lens' data sheet says `f >= 400` px: one inequality keeps the estimate
    physical.
    """),
    code("""
    rng = np.random.default_rng(4)
    F_TRUE, CX_TRUE = 500.0, 320.0
    xz = rng.uniform(-0.01, 0.01, size=12)            # X / Z of the points (near the axis)
    pixels = F_TRUE * xz + CX_TRUE + rng.normal(scale=3.0, size=xz.shape)


    @fgopt.factor
    def pixel(f: Scalar, cx: Scalar, ratio: Scalar, u: Scalar) -> Scalar:
        return f * ratio + cx - u


    @fgopt.constraint(inequality=True)
    def focal_at_least(f: Scalar, fmin: Scalar) -> Scalar:
        return fmin - f


    def calibrate(fmin=None):
        graph, initial = fgopt.FactorGraph(), fgopt.Variables()
        for r, u in zip(xz, pixels):
            graph.add(pixel(f=key("f", 0), cx=key("c", 0), ratio=float(r), u=float(u)))
        if fmin is not None:
            graph.add(focal_at_least(f=key("f", 0), fmin=fmin))
        initial.add(key("f", 0), 450.0)
        initial.add(key("c", 0), 300.0)
        return fgopt.optimize(graph, initial)


    plain, bounded = calibrate(), calibrate(fmin=400.0)
    for name, r in (("least squares", plain), ("f >= 400", bounded)):
        print(f"{name:>13}: f = {r.values.at(key('f', 0)):8.2f} px, "
              f"cx = {r.values.at(key('c', 0)):7.2f} px, cost {r.final_cost:.3f}")
    print("multiplier of f >= 400:", bounded.multipliers[0])
    """),
    code("""
    fs = np.linspace(0.0, 800.0, 400)
    A = np.c_[xz, np.ones_like(xz)]
    # cost profile over f (cx at its best value for each f)
    profile = [0.5 * np.sum((pixels - f * xz - np.mean(pixels - f * xz)) ** 2) for f in fs]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(fs, profile, label="cost, cx optimal for each f")
    ax.axvspan(0, 400, color="0.85", label="excluded: f < 400 px")
    ax.axvline(plain.values.at(key("f", 0)), color="C1", ls="--", label="least squares")
    ax.axvline(bounded.values.at(key("f", 0)), color="C2", label="with f >= 400")
    ax.axvline(F_TRUE, color="k", ls=":", label="true f")
    ax.set_xlabel("focal length f [px]")
    ax.set_ylabel("cost")
    ax.legend(fontsize=8)
    plt.show()
    """),
    md("""
    ## 3. Points on a plane, and the plane with them

    Noisy measurements `m_i` of points that lie on one plane. Each point `p_i` is pulled to its
    measurement, and an equality `n . p_i + d = 0` puts it on the plane `(n, d)`, itself a
    variable on the declared manifold `OrientedPlane3` (unit normal x distance). Minimizing
    `0.5 sum |p_i - m_i|^2` under these constraints is the total-least-squares plane fit: the
    normal is the singular vector of the centred measurements with the smallest singular value,
    and every `p_i` is the orthogonal projection of `m_i`. The solver should find exactly that.
    """),
    code("""
    rng = np.random.default_rng(1)
    n_true = np.array([0.2, -0.3, 1.0]) / np.linalg.norm([0.2, -0.3, 1.0])
    d_true = -1.5
    uv = rng.uniform(-2, 2, size=(40, 2))
    basis = np.linalg.svd(n_true[None])[2][1:]        # two directions in the plane
    on_plane = uv @ basis - d_true * n_true
    measured = on_plane + rng.normal(scale=0.05, size=on_plane.shape)


    @fgopt.factor
    def pull(p: V3, m: V3) -> V3:
        return p - m


    @fgopt.constraint
    def in_plane(p: V3, plane: OrientedPlane3) -> V1:
        c = plane.plane_coefficients()
        return V1(c[0] * p[0] + c[1] * p[1] + c[2] * p[2] + c[3])


    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    for i, m in enumerate(measured):
        graph.add(pull(p=key("p", i), m=m))
        graph.add(in_plane(p=key("p", i), plane=key("n", 0)))
        initial.add(key("p", i), m.copy())
    initial.add(key("n", 0), fgopt.OrientedPlane3.from_storage(np.array([0.0, 0.0, 1.0, 0.0])))
    result = fgopt.optimize(graph, initial)
    plane = result.values.at(key("n", 0)).to_storage()
    print(result.status.value, f"violation {result.constraint_violation:.1e}")

    # closed form: total least squares
    centre = measured.mean(axis=0)
    normal = np.linalg.svd(measured - centre)[2][-1]
    normal *= np.sign(normal @ plane[:3])
    print("normal (fgopt)      ", np.round(plane[:3], 8), " d =", round(plane[3], 8))
    print("normal (closed form)", np.round(normal, 8), " d =", round(-normal @ centre, 8))
    assert np.allclose(plane[:3], normal, atol=1e-6) and abs(plane[3] + normal @ centre) < 1e-6
    """),
    code("""
    points = np.array([result.values.at(key("p", i)) for i in range(len(measured))])
    fig = plt.figure(figsize=(6, 4.5))
    ax = fig.add_subplot(projection="3d")
    ax.scatter(*measured.T, s=10, label="measured")
    ax.scatter(*points.T, s=10, label="on the fitted plane")
    for a, b in zip(measured, points):
        ax.plot(*np.c_[a, b], color="0.6", lw=0.6)
    g1, g2 = np.meshgrid(np.linspace(-2, 2, 2), np.linspace(-2, 2, 2))
    corners = (np.stack([g1, g2], -1) @ basis) - plane[3] * plane[:3]
    ax.plot_surface(corners[..., 0], corners[..., 1], corners[..., 2], alpha=0.2)
    ax.legend(fontsize=8)
    ax.set_title("points on a plane (equality constraints)")
    plt.show()
    """),
]


NOTEBOOKS = {
    "01_minisam_pose_graph.ipynb": NB01,
    "02_custom_factor.ipynb": NB02,
    "03_custom_manifold.ipynb": NB03,
    "04_g2o_pose_graph.ipynb": NB04,
    "05_bundle_adjustment.ipynb": NB05,
    "06_on_manifold_ekf.ipynb": NB06,
    "07_constraints.ipynb": NB07,
}


def build(name: str, cells: list) -> nbformat.NotebookNode:
    nb = new_notebook(cells=copy.deepcopy(cells))
    stem = name.split("_")[0]
    for i, cell in enumerate(nb.cells):  # stable ids: regenerating gives no spurious diff
        cell.id = f"nb{stem}-{i:02d}"
    nb.metadata["kernelspec"] = KERNELSPEC
    nb.metadata["language_info"] = {"name": "python"}
    nbformat.validate(nb)
    return nb


def main(argv: list[str]) -> int:
    names = argv or list(NOTEBOOKS)
    for name in names:
        nb = build(name, NOTEBOOKS[name])
        path = HERE / name
        nbformat.write(nb, path)
        print("wrote", path.relative_to(HERE.parent))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
