"""A new custom factor from its decorated definition to the first optimized result (prints JSON).

``python custom_factor.py range_bearing|pose3_between [EDIT]``: the script writes the factor's
source into a module under ``$FGOPT_CACHE_DIR`` with ``EDIT`` spliced into the body (a term
SymPy removes, so every edit is a new function with the same math, as a user editing it in a
notebook), imports it, builds a small graph and optimizes. Reported: seconds from the
definition to the result, and whether SymPy ran (cold/edited) or the cached kernel was loaded.
"""

import importlib.util
import json
import os
import sys
import time
from pathlib import Path

t_start = time.perf_counter()
import numpy as np  # noqa: E402

import fgopt  # noqa: E402
from fgopt import SE2, SE3, SO3, BetweenFactor, PriorFactor, key  # noqa: E402
from fgopt.noise import Diagonal  # noqa: E402

t_import = time.perf_counter() - t_start

SOURCES = {
    "range_bearing": '''
import fgopt
from fgopt.symbolic import Pose2, V2, atan2


@fgopt.factor
def range_bearing(pose: Pose2, landmark: V2, measured: V2) -> V2:
    d = pose.inverse() * landmark
    return V2(d.norm() + 0.0 * EDIT, atan2(d[1], d[0])) - measured
''',
    "pose3_between": '''
import fgopt
from fgopt.symbolic import Pose3, V6


@fgopt.factor
def pose3_between(a: Pose3, b: Pose3, measured: Pose3) -> V6:
    return (measured.inverse() * (a.inverse() * b)).log() * (1.0 + 0.0 * EDIT)
''',
}


def define(kind: str, edit: str):
    folder = Path(os.environ["FGOPT_CACHE_DIR"]) / "custom_factor_scripts"
    folder.mkdir(parents=True, exist_ok=True)
    name = f"user_{kind}_{abs(hash(edit)) % 10**8}"
    path = folder / f"{name}.py"
    path.write_text(SOURCES[kind].replace("EDIT", edit))
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return getattr(module, kind)


def range_bearing_problem(factor):
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    noise = Diagonal.sigmas([0.05, 0.1, 0.1])
    graph.add(PriorFactor(key("x", 1), SE2.from_xytheta(0, 0, 0), noise))
    for i in range(1, 3):
        graph.add(BetweenFactor(key("x", i), key("x", i + 1), SE2.from_xytheta(2, 0, 0), noise))
    landmarks = {1: np.array([2.0, 2.0]), 2: np.array([4.0, -2.0])}
    truth = [SE2.from_xytheta(2.0 * i, 0, 0) for i in range(3)]
    for i, pose in enumerate(truth):
        for j, lm in landmarks.items():
            d = lm - pose.translation()
            graph.add(factor(pose=key("x", i + 1), landmark=key("l", j),
                             measured=np.array([np.hypot(*d), np.arctan2(d[1], d[0])])))
        initial.add(key("x", i + 1), SE2.from_xytheta(2.0 * i + 0.2, 0.1, 0.05))
    for j, lm in landmarks.items():
        initial.add(key("l", j), lm + 0.3)
    return graph, initial


def pose3_problem(factor):
    """20 poses climbing a square helix (2 m sides, 0.1 m up per side): 19 odometry factors and
    one loop closure, all of the new type (20 factors), a PriorFactor on the first pose."""
    def pose(yaw, x, y, z):
        return SE3(SO3.exp(np.array([0.0, 0.0, yaw])), np.array([x, y, z]))

    rng = np.random.default_rng(0)
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    noise = Diagonal.sigmas([0.05] * 3 + [0.2] * 3)
    graph.add(PriorFactor(key("x", 1), pose(0, 0, 0, 0), noise))
    step = pose(np.pi / 2, 2, 0, 0.1)
    truth = [pose(0, 0, 0, 0)]
    for i in range(19):
        graph.add(factor(a=key("x", i + 1), b=key("x", i + 2), measured=step))
        truth.append(truth[-1] * step)
    graph.add(factor(a=key("x", 20), b=key("x", 17), measured=step))
    for i, t in enumerate(truth):
        initial.add(key("x", i + 1), t * SE3(SO3.exp(0.1 * rng.standard_normal(3)),
                                             0.2 * rng.standard_normal(3)))
    return graph, initial


def main() -> None:
    kind = sys.argv[1]
    edit = sys.argv[2] if len(sys.argv) > 2 else "1"
    t0 = time.perf_counter()
    factor = define(kind, edit)
    graph, initial = (range_bearing_problem if kind == "range_bearing" else pose3_problem)(factor)
    result = fgopt.optimize(graph, initial)
    seconds = time.perf_counter() - t0
    from fgopt.symbolic import cache

    print(json.dumps({"definition to result": seconds, "import": t_import,
                      "final cost": result.final_cost, "derived": cache.STATS["derived"],
                      "loaded": cache.STATS["loaded"], "sympy imported": "sympy" in sys.modules}))


if __name__ == "__main__":
    main()
