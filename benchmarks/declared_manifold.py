"""A user-declared manifold at full speed: ``Unit3`` (``@fgopt.manifold``) vs built-ins and vs
the same manifold on the Python slow path, measured side by side in one run (issue 13).

    .venv/bin/python -m benchmarks.declared_manifold [--n 4760] [--reps 3] [--skip-cold]
                                                      [--json benchmarks/results/X.json]

Problems (one topology, four ways of writing it):

* **large** (~10,000 factors): ``n`` directions, each linked to the next one and to the one 5
  further by a direction-between factor (``b.local(Unit3(b_R_a * a))``: the angle between b and
  the rotated a, in b's tangent basis), plus a prior every 10 directions.
    - ``Unit3`` declared with ``@fgopt.manifold`` (``fgopt.symbolic.Unit3``), an
      ``@fgopt.factor`` between and the generated ``PriorFactor``: the batched path;
    - the same graph over ``R^2`` vectors (built-in ``BetweenFactor`` / ``PriorFactor``): a
      built-in space of the same dimension (2), the cheapest kernels fgopt has;
    - the same graph over ``SO3`` (built-in between / prior, generated kernels): the nearest
      built-in Lie group (dimension 3);
    - the same manifold as a plain Python class with ``NumericalFactor``\\ s: the slow path
      (2 iterations, 1 sample: it takes seconds per iteration).
  Reported: seconds per LM iteration (5 iterations, every stopping test off; ``(total - setup) /
  5``, so the first linearization is included), median of ``--reps`` warm solves.
* **small** (305 factors: 150 directions, links +1 and +5, a prior every 14): the problem of the
  issue; seconds per solve to convergence, batched vs Python slow path.
* **first solve of a new manifold**: a fresh process declares a manifold (the Unit3 source under
  a new name), a factor over it, and solves a 40-factor graph; cold (empty kernel cache) and
  warm (second process, same cache). Reported: from the declaration to the first result, and
  ``import fgopt`` and numba's per-process start (the first call of any cached numba function)
  separately; wall and CPU seconds (the machine is shared). The children run as a new user's
  process: the default NumPy-twin budget (not this script's warm-process ``FGOPT_NUMPY_BUDGET=0``),
  so a small first solve runs on NumPy twins and never imports numba; the empty cache folder is
  a fresh install's (fgopt's own numba cache lives there too).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
           "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_v] = "1"
# Warm-process figures: small batches on the compiled kernels from the first timed call (a
# process reaches this after 0.5 s of NumPy-twin work; see fgopt/_jit.py). The first-solve
# children run as a new user's process: the default budget (or the one given to this script).
_GIVEN_BUDGET = os.environ.get("FGOPT_NUMPY_BUDGET")
os.environ.setdefault("FGOPT_NUMPY_BUDGET", "0")

import argparse
import json
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def five_it():
    from fgopt.solvers import LMParams

    return LMParams(max_iterations=5, relative_tolerance=0.0, absolute_tolerance=0.0,
                    gradient_tolerance=0.0, step_tolerance=0.0)


def _rotation_between(a: np.ndarray, b: np.ndarray):
    from fgopt import SO3

    axis = np.cross(a, b)
    return SO3.from_axis_angle(axis / np.linalg.norm(axis),
                               np.arctan2(np.linalg.norm(axis), a @ b))


def topology(n: int, links=(1, 5), prior_every: int = 10):
    """(pairs, prior indices) of the benchmark graph."""
    pairs = [(i, i + k) for i in range(n) for k in links if i + k < n]
    return pairs, list(range(0, n, prior_every))


def unit3_graph(n: int, links=(1, 5), prior_every: int = 10, seed: int = 0):
    """The declared-Unit3 graph, plus the truth and the measured rotations."""
    import fgopt
    from fgopt import SO3, key
    from fgopt.noise import Isotropic
    from fgopt.symbolic import V2, Rot3, Unit3

    @fgopt.factor
    def direction_between(a: Unit3, b: Unit3, b_R_a: Rot3) -> V2:
        return b.local(Unit3(b_R_a * a.point3()))

    U = Unit3.Value
    rng = np.random.default_rng(seed)
    truth = np.array([U(rng.normal(size=3)).to_storage() for _ in range(n)])
    pairs, priors = topology(n, links, prior_every)
    noise = Isotropic.sigma(2, 0.01)
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    rots = []
    for i, j in pairs:
        R = _rotation_between(truth[i], truth[j]) * SO3.exp(0.01 * rng.normal(size=3))
        rots.append(R)
        graph.add(direction_between(key("u", i), key("u", j), R, loss=noise))
    for i in priors:
        graph.add(fgopt.PriorFactor(key("u", i), U(truth[i]), noise))
    starts = [U(t).retract(0.2 * rng.normal(size=2)) for t in truth]
    for i, s in enumerate(starts):
        initial.add(key("u", i), s)
    return graph, initial, truth, rots, starts


def builtin_graph(n: int, space: str, links=(1, 5), prior_every: int = 10, seed: int = 0):
    """The same topology over R^2 vectors or SO3 with built-in factors."""
    import fgopt
    from fgopt import SO3, key
    from fgopt.noise import Isotropic

    rng = np.random.default_rng(seed)
    d = 2 if space == "R2" else 3
    pairs, priors = topology(n, links, prior_every)
    noise = Isotropic.sigma(d, 0.01)
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    if space == "R2":
        truth = [rng.normal(size=2) for _ in range(n)]
        for i, j in pairs:
            m = truth[j] - truth[i] + 0.01 * rng.normal(size=2)
            graph.add(fgopt.BetweenFactor(key("u", i), key("u", j), m, noise))
        for i in priors:
            graph.add(fgopt.PriorFactor(key("u", i), truth[i], noise))
        for i, t in enumerate(truth):
            initial.add(key("u", i), t + 0.2 * rng.normal(size=2))
    else:
        truth = [SO3.random(rng) for _ in range(n)]
        for i, j in pairs:
            m = truth[i].between(truth[j]) * SO3.exp(0.01 * rng.normal(size=3))
            graph.add(fgopt.BetweenFactor(key("u", i), key("u", j), m, noise))
        for i in priors:
            graph.add(fgopt.PriorFactor(key("u", i), truth[i], noise))
        for i, t in enumerate(truth):
            initial.add(key("u", i), t.retract(0.2 * rng.normal(size=3)))
    return graph, initial


def declared_vector_graph(n: int, links=(1, 5), prior_every: int = 10, seed: int = 0):
    """The built-in R^2 graph (same truth, measurements and start) over a *declared* copy of
    R^2 (``retract = x + d``, ``local = y - x``) with an ``@fgopt.factor`` between and the
    generated prior: the same math as the built-in graph, so its time over the built-in's is the
    cost of the declaration path itself."""
    import fgopt
    from fgopt import key
    from fgopt.noise import Isotropic
    from fgopt.symbolic import V2

    @fgopt.manifold
    class DeclaredR2:
        storage_dim = 2
        dim = 2

        def identity():
            return V2(0, 0)

        def retract(x, d):
            return V2(x[0] + d[0], x[1] + d[1])

        def local(x, y):
            return V2(y[0] - x[0], y[1] - x[1])

    @fgopt.factor
    def declared_r2_between(a: DeclaredR2, b: DeclaredR2, measured: V2) -> V2:
        return a.local(b) - measured

    rng = np.random.default_rng(seed)  # the draws of builtin_graph(n, "R2")
    pairs, priors = topology(n, links, prior_every)
    noise = Isotropic.sigma(2, 0.01)
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    P = DeclaredR2.Value
    truth = [rng.normal(size=2) for _ in range(n)]
    for i, j in pairs:
        m = truth[j] - truth[i] + 0.01 * rng.normal(size=2)
        graph.add(declared_r2_between(key("u", i), key("u", j), m, loss=noise))
    for i in priors:
        graph.add(fgopt.PriorFactor(key("u", i), P(truth[i]), noise))
    for i, t in enumerate(truth):
        initial.add(key("u", i), P(t + 0.2 * rng.normal(size=2)))
    return graph, initial


def python_graph(n: int, links=(1, 5), prior_every: int = 10, seed: int = 0):
    """The same Unit3 graph with a plain-Python manifold class and NumericalFactors."""
    import fgopt
    from fgopt import key
    from fgopt.symbolic import Unit3

    U = Unit3.Value

    class PyUnit3:
        """Unit3 as a duck-typed class (numpy, GTSAM's chart via the declared value's code)."""

        def __init__(self, p):
            self.u = p if isinstance(p, U) else U(p)

        def dim(self):
            return 2

        def retract(self, v):
            return PyUnit3(self.u.retract(v))

        def local(self, other):
            return self.u.local(other.u)

    class Direction(fgopt.NumericalFactor):
        def __init__(self, a, b, R, loss):
            super().__init__([a, b], 2, loss)
            self.R = R.matrix()

        def error(self, values):
            a, b = values.at(self.keys[0]).u, values.at(self.keys[1]).u
            return b.local(U(self.R @ a.to_storage()))

    class Prior(fgopt.NumericalFactor):
        def __init__(self, k, m, loss):
            super().__init__([k], 2, loss)
            self.m = U(m)

        def error(self, values):
            return self.m.local(values.at(self.keys[0]).u)

    g, _, truth, rots, starts = unit3_graph(n, links, prior_every, seed)
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    pairs, priors = topology(n, links, prior_every)
    noise = g[0].loss
    for (i, j), R in zip(pairs, rots):
        graph.add(Direction(key("u", i), key("u", j), R, noise))
    for i in priors:
        graph.add(Prior(key("u", i), truth[i], noise))
    for i, s in enumerate(starts):
        initial.add(key("u", i), PyUnit3(s))
    return graph, initial


def per_iteration(graph, initial, reps: int, iterations: int = 5) -> dict:
    """Seconds per LM iteration (tolerances off): median over reps after one warm-up."""
    import fgopt
    from fgopt.solvers import LMParams

    p = LMParams(max_iterations=iterations, relative_tolerance=0.0, absolute_tolerance=0.0,
                 gradient_tolerance=0.0, step_tolerance=0.0)
    fgopt.optimize(graph, initial, params=p)  # warm-up: kernels loaded / compiled
    samples, setups, costs = [], [], []
    for _ in range(reps):
        r = fgopt.optimize(graph, initial, params=p)
        samples.append((r.timing["total"] - r.timing["setup"]) / r.iterations)
        setups.append(r.timing["setup"])
        costs.append(r.final_cost)
    return {"per_iteration_s": float(np.median(samples)), "setup_s": float(np.median(setups)),
            "samples": samples, "final_cost": costs[-1], "factors": len(graph)}


def interleaved_per_iteration(graphs: dict, reps: int, iterations: int = 5) -> dict:
    """:func:`per_iteration` of several graphs, their samples taken in turn (one sample of each
    per round), so that every graph sees the same machine load."""
    import fgopt
    from fgopt.solvers import LMParams

    p = LMParams(max_iterations=iterations, relative_tolerance=0.0, absolute_tolerance=0.0,
                 gradient_tolerance=0.0, step_tolerance=0.0)
    for g, init in graphs.values():
        fgopt.optimize(g, init, params=p)  # warm-up: kernels loaded / compiled
    samples = {k: [] for k in graphs}
    setups = {k: [] for k in graphs}
    out = {}
    for _ in range(reps):
        for k, (g, init) in graphs.items():
            r = fgopt.optimize(g, init, params=p)
            samples[k].append((r.timing["total"] - r.timing["setup"]) / r.iterations)
            setups[k].append(r.timing["setup"])
            out[k] = {"final_cost": r.final_cost, "factors": len(g)}
    for k in graphs:
        out[k].update(per_iteration_s=float(np.median(samples[k])),
                      setup_s=float(np.median(setups[k])), samples=samples[k])
    return out


def per_solve(graph, initial, reps: int) -> dict:
    import fgopt

    fgopt.optimize(graph, initial)
    samples, its = [], []
    for _ in range(reps):
        t = time.perf_counter()
        r = fgopt.optimize(graph, initial)
        samples.append(time.perf_counter() - t)
        its.append(r.iterations)
    return {"solve_s": float(np.median(samples)), "samples": samples, "iterations": its[-1],
            "final_cost": r.final_cost, "factors": len(graph)}


CHILD = textwrap.dedent('''
    import json, sys, time
    t0 = time.perf_counter()
    import numpy as np
    import fgopt
    t_import = time.perf_counter() - t0
    from fgopt import SO3, key
    from fgopt.noise import Isotropic
    from fgopt.symbolic import V2, V3, Abs, Matrix, Rot3, atan2, cos, sin, where
    t = time.perf_counter()
    SO3.identity().retract(np.zeros(3))  # numba's per-process start (any fgopt solve pays it)
    t_numba = time.perf_counter() - t
    t1 = time.perf_counter()
    c1 = time.process_time()
    M32 = Matrix.shaped(3, 2)

    @fgopt.manifold
    class NAME:
        storage_dim = 3
        dim = 2

        def identity():
            return V3(0, 0, 1)

        def point3(x):
            return V3(x[0], x[1], x[2])

        def basis(x):
            p = x.point3()
            ax, ay, az = Abs(p[0]), Abs(p[1]), Abs(p[2])
            hx = where((ax <= ay) & (ax <= az), 1, 0)
            hy = (1 - hx) * where((ay <= ax) & (ay <= az), 1, 0)
            b1 = p.cross(V3(hx, hy, 1 - hx - hy))
            b1 = b1 / b1.norm(0)
            b2 = p.cross(b1)
            return M32([[b1[0], b2[0]], [b1[1], b2[1]], [b1[2], b2[2]]])

        def retract(x, v):
            p = x.point3()
            xi = x.basis() * v
            theta = xi.norm()
            return cos(theta) * p + (sin(theta) / theta) * xi

        def local(x, y):
            p, q = x.point3(), y.point3()
            s = p.cross(q).norm()
            return (atan2(s, p.dot(q), epsilon=0) / s) * (x.basis().T * q)

        def normalize(x):
            p = x.point3()
            return p / p.norm(0)

    @fgopt.factor
    def between_NAME(a: NAME, b: NAME, b_R_a: Rot3) -> V2:
        return b.local(NAME(b_R_a * a.point3()))

    t_declared = time.perf_counter() - t1
    c_declared = time.process_time() - c1
    rng = np.random.default_rng(0)
    U = NAME.Value
    truth = [U(rng.normal(size=3)) for _ in range(20)]
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    noise = Isotropic.sigma(2, 0.01)
    for i in range(19):
        for j in (i + 1, i + 3):
            if j < 20:
                a, b = truth[i].to_storage(), truth[j].to_storage()
                ax = np.cross(a, b)
                R = SO3.from_axis_angle(ax / np.linalg.norm(ax), np.arctan2(np.linalg.norm(ax), a @ b))
                graph.add(between_NAME(key("u", i), key("u", j), R, loss=noise))
    graph.add(fgopt.PriorFactor(key("u", 0), truth[0], noise))
    for i, t in enumerate(truth):
        initial.add(key("u", i), t.retract(0.1 * rng.normal(size=2)))
    r = fgopt.optimize(graph, initial)
    t_first = time.perf_counter() - t1
    c_first = time.process_time() - c1
    print(json.dumps({"import_s": t_import, "numba_init_s": t_numba, "declaration_s": t_declared,
                      "declaration_to_first_result_s": t_first,
                      "declaration_cpu_s": c_declared, "first_result_cpu_s": c_first,
                      "iterations": r.iterations,
                      "success": r.success, "factors": len(graph),
                      "sympy_imported": "sympy" in sys.modules}))
''')


def first_solve(runs: int = 2) -> dict:
    """Cold then warm processes sharing one fresh cache dir and a new manifold name."""
    name = f"Sphere{os.getpid()}x{int(time.time()) % 100000}"
    code = CHILD.replace("NAME", name)
    out = {}
    with tempfile.TemporaryDirectory(prefix="fgopt-declared-bench-") as cache:
        env = dict(os.environ, FGOPT_CACHE_DIR=cache, PYTHONPATH=str(ROOT))
        # a new user's process: the default NumPy-twin budget (not this script's warm-process
        # 0) and the bytecode an installed package has
        env.pop("FGOPT_NUMPY_BUDGET", None)
        if _GIVEN_BUDGET is not None:
            env["FGOPT_NUMPY_BUDGET"] = _GIVEN_BUDGET
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        for label in ["cold"] + [f"warm{i}" for i in range(1, runs)]:
            p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                               text=True, cwd=ROOT, timeout=1800)
            if p.returncode != 0:
                raise RuntimeError(p.stderr[-3000:])
            out[label] = json.loads(p.stdout.strip().splitlines()[-1])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=4760, help="directions in the large graph")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--skip-cold", action="store_true")
    ap.add_argument("--skip-python-large", action="store_true")
    ap.add_argument("--json", type=str, default=None)
    args = ap.parse_args()
    res: dict = {"load_avg_start": os.getloadavg()[0]}
    g, init, *_ = unit3_graph(args.n)
    graphs = {"large_unit3": (g, init), "large_R2": builtin_graph(args.n, "R2"),
              "large_declared_R2": declared_vector_graph(args.n),
              "large_SO3": builtin_graph(args.n, "SO3")}
    res.update(interleaved_per_iteration(graphs, args.reps))
    for k in graphs:
        print(f"{k}:", res[k]["per_iteration_s"], flush=True)
    if not args.skip_python_large:
        g3, i3 = python_graph(args.n)
        res["large_python"] = per_iteration(g3, i3, 1, iterations=2)
        print("large Python:", res["large_python"]["per_iteration_s"], flush=True)
    small = dict(n=150, links=(1, 5), prior_every=14)
    g, init, *_ = unit3_graph(**small)
    res["small_unit3"] = per_solve(g, init, max(args.reps, 5))
    g3, i3 = python_graph(**small)
    res["small_python"] = per_solve(g3, i3, args.reps)
    print("small:", res["small_unit3"]["solve_s"], res["small_python"]["solve_s"], flush=True)
    if not args.skip_cold:
        res["first_solve"] = first_solve()
    res["load_avg_end"] = os.getloadavg()[0]
    print(report(res))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


def report(res: dict) -> str:
    u = res["large_unit3"]["per_iteration_s"]
    lines = ["| large graph (%d factors) | s / LM iteration | declared Unit3's time / this |"
             % res["large_unit3"]["factors"], "|---|---|---|",
             f"| Unit3 (@fgopt.manifold, batched) | {u:.4f} | 1 |"]
    for k, label in (("large_R2", "R^2 vectors (built-in, dim 2)"),
                     ("large_declared_R2", "R^2 declared with @fgopt.manifold (same math)"),
                     ("large_SO3", "SO3 (built-in group, dim 3)"),
                     ("large_python", "Unit3 as a Python class (slow path)")):
        if k in res:
            v = res[k]["per_iteration_s"]
            lines.append(f"| {label} | {v:.4f} | {u / v:.3g} |")
    su, sp = res["small_unit3"], res["small_python"]
    lines += ["", f"| small graph ({su['factors']} factors) | s / solve | iterations |",
              "|---|---|---|",
              f"| Unit3 (@fgopt.manifold, batched) | {su['solve_s']:.4f} | {su['iterations']} |",
              f"| Unit3 as a Python class | {sp['solve_s']:.4f} | {sp['iterations']} |",
              f"| speed-up | {sp['solve_s'] / su['solve_s']:.1f}x | |"]
    if "first_solve" in res:
        lines += ["", "| new manifold, first solve | import fgopt (s) | numba init (s) | "
                  "declaration (s, CPU s) | declaration to first result (s, CPU s) | "
                  "SymPy imported |", "|---|---|---|---|---|---|"]
        for k, v in res["first_solve"].items():
            lines.append(f"| {k} | {v['import_s']:.2f} | {v['numba_init_s']:.2f} | "
                         f"{v['declaration_s']:.2f} "
                         f"({v['declaration_cpu_s']:.2f}) | "
                         f"{v['declaration_to_first_result_s']:.2f} "
                         f"({v['first_result_cpu_s']:.2f}) | {v['sympy_imported']} |")
    if "large_declared_R2" in res:
        d, b = res["large_declared_R2"]["per_iteration_s"], res["large_R2"]["per_iteration_s"]
        lines.append(f"\nThe declaration path itself (declared R^2 / built-in R^2, same math): "
                     f"{d / b:.2f}x")
    lines.append(f"\nload average {res['load_avg_start']:.1f} -> {res['load_avg_end']:.1f}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
