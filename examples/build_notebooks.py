"""Write the example notebooks of this folder (outputs cleared) from the cell lists below.

The notebooks are generated so that their text lives in one reviewable Python file; edit the
cells here and run ``.venv/bin/python examples/build_notebooks.py`` (from the repository root)
to rewrite the ``.ipynb`` files. ``tests/test_notebooks.py`` executes every notebook.
"""

from __future__ import annotations

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

    **Conventions.** fgopt's SE(2) tangent order is *rotation first*, `[theta, x, y]` (as GTSAM's
    storage of Pose2 noise is `[x, y, theta]`, miniSAM/Sophus puts translation first). So
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

    Two ways to make a type a manifold:

    1. **Duck typing**: give the class those three methods; nothing to register.
    2. **Registration**: `fgopt.manifolds.register(cls, ops)` with an *ops* object (traits) that
       answers for values of `cls` — for types you cannot or do not want to change (here: Python's
       built-in `complex`).

    Both are on fgopt's *slow path* (Python calls per variable); the built-in Lie groups and
    vectors use batched numba kernels.
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
    print(f"solved in {time.perf_counter() - t0:.2f} s")
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
]


NOTEBOOKS = {
    "01_minisam_pose_graph.ipynb": NB01,
    "02_custom_factor.ipynb": NB02,
    "03_custom_manifold.ipynb": NB03,
}


def build(name: str, cells: list) -> nbformat.NotebookNode:
    nb = new_notebook(cells=cells)
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
