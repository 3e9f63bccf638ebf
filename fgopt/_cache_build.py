"""``fgopt cache build``: compile, once per machine, the machine code of fgopt's built-in families.

fgopt's kernels are numba functions compiled on their first call and then loaded from fgopt's
cache (:mod:`fgopt._cache_root`). Left to itself, a fresh install pays that compile inside the
first script that uses a family: 10-100 s of CPU the first time a script adds IMU factors or
an incremental smoother. This command pays it up front, in parallel, with a line per family:
each family runs a small problem of its kind in a child process (started because the user
asked for it) with the NumPy twins switched off (``FGOPT_NUMPY_BUDGET=0`` in the child only),
so every kernel that family's scripts call is compiled and cached. ``make demo`` runs
it; running it again loads everything from the cache in a few seconds.

A user's own ``@fgopt.factor`` or ``@fgopt.manifold`` still derives and compiles its own
kernel on first use (~2-3 s); the generic machinery around it (assembly, orderings, the sparse
solvers) is what this command prepares.

Families (``--only``): :data:`FAMILIES`.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .errors import FgoptError


def _geometry(tmp: Path) -> None:
    """The element operations of every built-in Lie group's values (a script's ``pose *
    step``, ``between``, ``log``, ...)."""
    from fgopt import SE2, SE3, SO2, SO3, Sim3

    rng = np.random.default_rng(1)
    for group in (SO2, SE2, SO3, SE3, Sim3):
        a, b = (group.exp(0.3 * rng.normal(size=group.dim())) for _ in range(2))
        (a.compose(b) * a.inverse()).adjoint()
        a.between(b).log(), a.local(a.retract(0.1 * np.ones(group.dim())))
        group.from_matrix(a.matrix())
        if group in (SE2, SE3, Sim3):
            a.rotation().matrix(), a.translation()
        a.act(rng.normal(size=(4, 2 if group in (SO2, SE2) else 3)))


def _pose_graphs(tmp: Path) -> None:
    """g2o files in 2-D and 3-D through ``fgopt solve`` (reader, chordal test, LM, writer), then
    on each graph Gauss-Newton, Dogleg and marginals (a few keys, and all of them)."""
    import fgopt
    from fgopt.cli import main as cli
    from fgopt.datasets import grid_3d, manhattan_2d
    from fgopt.io import write_g2o

    for name, data in (("2d", manhattan_2d(300, seed=1)), ("3d", grid_3d(125, seed=1))):
        path = tmp / f"{name}.g2o"
        write_g2o(path, data.graph, data.initial)
        cli(["solve", str(path), "--out", str(tmp / f"{name}-solved.g2o"), "--quiet"])
        result = fgopt.optimize(data.graph, data.initial, method="gn")
        fgopt.optimize(data.graph, data.initial, method="dogleg")
        data.graph.error(result.values)
        fgopt.marginals(result, data.initial.keys()[-1:])  # solves with identity columns
        fgopt.marginals(result)  # every key: the selected inverse


def _bundle_adjustment(tmp: Path) -> None:
    """A BAL file through ``fgopt solve`` (Snavely cameras, Schur complement)."""
    from fgopt.cli import main as cli
    from fgopt.datasets import bal_synthetic

    path = tmp / "problem.txt"
    bal_synthetic(cameras=6, points=120, observations_per_point=4, seed=1).write(path)
    cli(["solve", str(path), "--out", str(tmp / "solved.txt"), "--quiet"])


def _cameras(tmp: Path) -> None:
    """GTSAM's SFMExample scene with projection factors (LM and Dogleg) and with smart
    factors."""
    import fgopt
    from fgopt.datasets import sfm_cube

    scene = sfm_cube(smart=False, seed=1)
    fgopt.optimize(scene.graph, scene.initial)
    result = fgopt.optimize(scene.graph, scene.initial, method="dogleg")
    scene.graph.error(result.values)
    smart = sfm_cube(smart=True, seed=1)
    result = fgopt.optimize(smart.graph, smart.initial)
    smart.graph.error(result.values)
    for factor in smart.graph:
        if hasattr(factor, "point"):
            factor.point(result.values)  # the landmark triangulated at the optimum


def _navigation(tmp: Path) -> None:
    """IMU factors with position fixes on a simulated constant-twist flight."""
    import fgopt
    from fgopt import SE3, PriorFactor, key
    from fgopt.navigation import (ConstantTwistScenario, GpsFactor, ImuFactor,
                                  PreintegrationParams, ScenarioRunner)
    from fgopt.noise import Isotropic

    scenario = ConstantTwistScenario(omega_b=[0.3, -0.3, 0.1], velocity_b=[2.0, 0.0, 0.0])
    params = PreintegrationParams.make_u(9.81, gyro_sigma=1e-3, accel_sigma=1e-3,
                                         integration_sigma=1e-7)
    runner = ScenarioRunner(scenario, params, dt=0.01, rng=1)
    graph, initial = fgopt.FactorGraph(), fgopt.Variables()
    rng = np.random.default_rng(1)
    graph.add(PriorFactor(key("x", 0), scenario.pose(0.0), Isotropic.sigma(6, 0.1)))
    graph.add(PriorFactor(key("v", 0), scenario.velocity_n(0.0), Isotropic.sigma(3, 0.1)))
    initial.add(key("b", 0), np.zeros(6))
    for i in range(6):
        initial.add(key("x", i), scenario.pose(float(i)) * SE3.exp(0.05 * rng.normal(size=6)))
        initial.add(key("v", i), scenario.velocity_n(float(i)) + 0.1 * rng.normal(size=3))
        if i:
            graph.add(ImuFactor(key("x", i - 1), key("v", i - 1), key("x", i), key("v", i),
                                key("b", 0), runner.integrate(1.0, start=i - 1.0)))
            graph.add(GpsFactor(key("x", i), scenario.pose(float(i)).translation(),
                                Isotropic.sigma(3, 0.5)))
    fgopt.optimize(graph, initial)


def _incremental(tmp: Path) -> None:
    """The incremental smoother on a 2-D pose stream and on camera frames (GTSAM's
    Pose2ISAM2Example and VisualISAM2Example), reading the estimate after every update."""
    from fgopt import key
    from fgopt.datasets import manhattan_2d, sfm_cube

    poses = manhattan_2d(60, seed=1)
    _stream(poses.graph, poses.initial, poses.initial.keys(), first=1)
    cube = sfm_cube(seed=1)
    frames = [key("x", i) for i in range(8)]
    order = frames[:2] + [key("l", j) for j in range(8)] + frames[2:]
    _stream(cube.graph, cube.initial, order, first=10)  # two frames fix the corners


def _stream(graph, initial, order: list, first: int) -> None:
    """Update with the first ``first`` variables of ``order``, then one variable at a time,
    each with the factors whose last variable it is; the whole estimate after each update."""
    from fgopt import IncrementalParams, IncrementalSmoother

    position = {k: i for i, k in enumerate(order)}
    factors_at: dict[int, list] = {}
    for factor in graph:
        at = max(first - 1, max(position[k] for k in factor.keys))
        factors_at.setdefault(at, []).append(factor)
    isam = IncrementalSmoother(IncrementalParams(relinearize_threshold=0.01, relinearize_skip=1))
    for at in range(first - 1, len(order)):
        keys = order[:first] if at == first - 1 else [order[at]]
        isam.update(factors_at.get(at, []), {k: initial.at(k) for k in keys})
        isam.update()
        isam.estimate()
    isam.marginal(order[-1])


#: name -> (what it prepares, the workload that compiles it)
FAMILIES: dict[str, tuple[str, Callable[[Path], None]]] = {  # the longest first
    "incremental": ("incremental smoothing", _incremental),
    "cameras": ("projection and smart factors", _cameras),
    "pose-graphs": ("g2o pose graphs, marginals", _pose_graphs),
    "navigation": ("IMU and GPS factors", _navigation),
    "geometry": ("Lie-group values", _geometry),
    "bundle-adjustment": ("BAL bundle adjustment", _bundle_adjustment),
}


def run_family(name: str) -> int:
    """Run family ``name``'s workload in this process; the number of fgopt functions numba
    compiled for it (0 when everything came from the cache)."""
    from numba.core import event

    from ._first_use import _name

    compiled = [0]

    class _Count(event.Listener):
        def on_start(self, ev) -> None:
            compiled[0] += _name(ev.data) is not None

        def on_end(self, ev) -> None:
            pass

    with event.install_listener("numba:compile", _Count()):
        with tempfile.TemporaryDirectory(prefix="fgopt-cache-build-") as tmp:
            FAMILIES[name][1](Path(tmp))
    return compiled[0]


def build(only: list[str] | None = None, jobs: int | None = None,
          out=None) -> dict[str, dict]:
    """Compile the families ``only`` (default: all of :data:`FAMILIES`), ``jobs`` child
    processes at a time (default: one per core); a line on ``out`` (default: standard output)
    per family. Returns, per family, its wall seconds and the number of functions compiled.

    Raises :class:`FgoptError` naming the family whose child process failed (its last lines of
    output included); the families that finished stay cached.
    """
    from ._cache_root import root

    names = list(FAMILIES) if only is None else list(only)
    unknown = [n for n in names if n not in FAMILIES]
    if unknown:
        raise FgoptError(f"fgopt cache build: unknown famil{'ies' if len(unknown) > 1 else 'y'} "
                         f"{', '.join(unknown)}; choose from {', '.join(FAMILIES)}")
    jobs = max(1, min(jobs or os.cpu_count() or 1, len(names)))
    out = sys.stdout if out is None else out
    env = dict(os.environ, FGOPT_NUMPY_BUDGET="0")
    print(f"fgopt: compiling the kernels of {len(names)} famil{'ies' if len(names) > 1 else 'y'}"
          f" into {root()} with {jobs} process{'es' if jobs > 1 else ''} (once per machine; "
          f"a few minutes when nothing is cached, seconds when everything is)", file=out,
          flush=True)
    waiting, running, done = list(names), {}, {}
    while waiting or running:
        while waiting and len(running) < jobs:
            name = waiting.pop(0)
            cmd = [sys.executable, "-m", "fgopt._cache_build", name]
            running[name] = (subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE,
                                              stderr=subprocess.PIPE, text=True),
                             time.perf_counter())
        finished = next((n for n, (p, _) in running.items() if p.poll() is not None), None)
        if finished is None:
            time.sleep(0.05)
            continue
        proc, start = running.pop(finished)
        stdout, stderr = proc.communicate()
        if proc.returncode != 0:
            for p, _ in running.values():
                p.kill()
            tail = "\n".join((stderr or stdout).strip().splitlines()[-15:])
            raise FgoptError(f"fgopt cache build: family {finished!r} failed (exit "
                             f"{proc.returncode}):\n{tail}")
        seconds = time.perf_counter() - start
        done[finished] = {"seconds": seconds,
                          "compiled": json.loads(stdout.strip().splitlines()[-1])["compiled"]}
        print(f"  [{len(done)}/{len(names)}] {finished:<18} {FAMILIES[finished][0]:<32} "
              f"{seconds:6.1f} s, {done[finished]['compiled']} functions compiled",
              file=out, flush=True)
    return done


if __name__ == "__main__":  # the child process of one family (see build)
    print(json.dumps({"compiled": run_family(sys.argv[1])}))
