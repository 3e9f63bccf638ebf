"""SymForce paper Sec. VIII-B: the inverse-compose experiment, ``pose.inverse() * point``.

Jacobian w.r.t. the pose's tangent space (SE(3), right perturbation ``x * Exp(d)``), computed

* **flattened**: one function ``res, d res / d pose`` differentiated as a whole, then CSE;
* **chained** (what automatic differentiation does at run time): ``inverse`` with its 6x6
  Jacobian, ``compose(pose_inv, point)`` with its 3x6 Jacobian, and a (3, 6) x (6, 6) product.

Op counts use ``sympy.count_ops`` after CSE, as the paper (which reports 91 flattened vs
73 + 85 + 198 = 356 chained for SymForce's Pose3). Timings: ns per instance of batched numba
kernels over ``n`` instances (flattened = the generated ``@fgopt.factor`` kernel; chained = two
generated per-instance functions and the 3x6x6 product inside one numba loop).

    .venv/bin/python -m benchmarks.symbolic_inverse_compose [--n 200000]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
             "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # single thread, as the other benchmarks (README)

import argparse
import time

import numpy as np


def op_counts() -> dict:
    from fgopt.symbolic import V3, Pose3
    from fgopt.symbolic.cse import total_ops
    from fgopt.symbolic.linearize import linearization_program

    pose, point = Pose3.symbolic("pose"), V3.symbolic("point")
    out = {}
    for engine in ("tree", "auto"):
        prog = linearization_program(pose.inverse() * point, [pose], engine=engine)
        out[f"flattened ({engine})"] = total_ops(prog)
    for method in ("retraction", "chain"):
        prog = linearization_program(pose.inverse() * point, [pose], method=method, engine="tree")
        out[f"flattened tree/{method}"] = total_ops(prog)
    inv = linearization_program(pose.inverse(), [pose], engine="tree")
    other = Pose3.symbolic("inv")
    comp = linearization_program(other * point, [other, point], engine="tree")
    out["inverse + jacobian"] = total_ops(inv)
    out["compose + jacobians"] = total_ops(comp)
    out["(3,6)x(6,6) product"] = 3 * 6 * (6 + 5)
    out["chained total"] = out["inverse + jacobian"] + out["compose + jacobians"] + 198
    return out


def symforce_counts() -> dict | None:
    """The same flattened count with SymForce itself (its Pose3 tangent: SO(3) x R^3)."""
    try:
        import symforce

        symforce.set_epsilon_to_symbol()
        import symforce.symbolic as sf
        from symforce import ops
    except Exception:  # noqa: BLE001 - optional peer, any import failure means absent
        return None
    pose, point = sf.Pose3.symbolic("pose"), sf.V3.symbolic("point")
    res = pose.inverse() * point
    jac = res.jacobian(pose)
    exprs = list(res) + list(jac)
    import sympy

    repl, red = sympy.cse([sympy.sympify(e) for e in exprs])
    del ops
    return {"symforce flattened (its own tangent)": int(sum(sympy.count_ops(e) for _, e in repl)
                                                         + sum(sympy.count_ops(e) for e in red))}


def _chained_kernel():
    """numba loop calling generated inverse/compose functions + a 3x6x6 product."""
    import numba

    from fgopt.symbolic import V3, Pose3
    from fgopt.symbolic.linearize import linearization_program
    from fgopt.symbolic.printer import to_source

    pose, point, inv = Pose3.symbolic("pose"), V3.symbolic("point"), Pose3.symbolic("inv")
    progs = {"_inverse": (linearization_program(pose.inverse(), [pose], engine="tree"),
                          pose.to_storage()),
             "_compose": (linearization_program(inv * point, [inv], engine="tree"),
                          inv.to_storage() + list(point))}
    src = ["import math", "import numba", "import numpy as np", "EPSILON = 2.220446049250313e-15"]
    for name, (prog, syms) in progs.items():
        src.append("@numba.njit(inline='always')")
        src.append(f"def {name}(x, res, jac):")
        src += [f"    {s.name} = x[{k}]" for k, s in enumerate(syms)]
        src += [f"    {s.name} = {to_source(e)}" for s, e in prog.stmts]
        d = 6
        src += [f"    res[{k}] = {to_source(e)}" for k, e in enumerate(prog.outputs["res"])]
        src += [f"    jac[{k // d}, {k % d}] = {to_source(e)}"
                for k, e in enumerate(prog.outputs["jac"])]
    src.append('''
@numba.njit(cache=False)
def chained(poses, points, res, jac):
    inv = np.empty(7)
    j_inv = np.empty((6, 6))
    x = np.empty(10)
    r = np.empty(3)
    j_c = np.empty((3, 6))
    for i in range(poses.shape[0]):
        _inverse(poses[i], inv, j_inv)
        x[:7] = inv
        x[7:] = points[i]
        _compose(x, r, j_c)
        res[i] = r
        for a in range(3):
            for b in range(6):
                acc = 0.0
                for k in range(6):
                    acc += j_c[a, k] * j_inv[k, b]
                jac[i, a, b] = acc
''')
    env: dict = {}
    exec(compile("\n".join(src), "<chained>", "exec"), env)  # noqa: S102 - generated code
    return env["chained"], numba


def timings(n: int, repeats: int = 20) -> dict:
    import fgopt
    from fgopt.manifolds import SE3
    from fgopt.symbolic import V3, Pose3

    @fgopt.factor
    def inverse_compose(pose: Pose3, point: V3) -> V3:
        return pose.inverse() * point

    rng = np.random.default_rng(0)
    poses = np.array([SE3.random(rng).to_storage() for _ in range(n)])
    points = rng.normal(size=(n, 3))
    kernel = inverse_compose.kernel(("pose",))
    kernel.linearize((poses,), points)
    t = time.perf_counter()
    for _ in range(repeats):
        _, jac = kernel.linearize((poses,), points)
    flat = (time.perf_counter() - t) / repeats / n * 1e9
    chained, _ = _chained_kernel()
    r2, j2 = np.empty((n, 3)), np.empty((n, 3, 6))
    chained(poses, points, r2, j2)
    np.testing.assert_allclose(j2, jac, atol=1e-9)
    t = time.perf_counter()
    for _ in range(repeats):
        chained(poses, points, r2, j2)
    chain = (time.perf_counter() - t) / repeats / n * 1e9
    import sys

    ops = sys.modules[kernel.linearize.__module__].META["ops"]
    return {"flattened kernel ns/instance": flat, "chained kernel ns/instance": chain,
            "generated kernel ops (linearize)": ops["linearize"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200_000)
    args = ap.parse_args()
    print("## Inverse compose: pose.inverse() * point, Jacobian w.r.t. the pose\n")
    print("| quantity | value | paper (SymForce) |\n|---|---|---|")
    paper = {"flattened (tree)": 91, "inverse + jacobian": 73, "compose + jacobians": 85,
             "(3,6)x(6,6) product": 198, "chained total": 356}
    for k, v in op_counts().items():
        print(f"| ops: {k} | {v} | {paper.get(k, '')} |")
    sf = symforce_counts()
    for k, v in (sf or {}).items():
        print(f"| ops: {k} | {v} | 91 |")
    for k, v in timings(args.n).items():
        print(f"| {k} | {v:.1f} | |")


if __name__ == "__main__":
    main()
