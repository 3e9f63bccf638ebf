"""Many problems: serial in one process vs ``fgopt.solve_many`` on the default LocalCluster.

    python -m benchmarks.many [--problems 64] [--workers 2] [--out benchmarks/results/many-<date>.md]

The problems are M3500 and sphere2500 (alternating) from perturbed initial guesses (each pose
retracted by a seeded random tangent vector: 0.05 rad rotation, 0.1 m translation sigmas), solved
with LM to convergence. Each problem is a zero-argument builder, so both sides read and perturb
the file themselves (nothing large is shipped) and the two runs do the same work. Reported:

- serial: one warm process solving them one after another (after one warm-up solve of each file);
- cluster: ``solve_many`` wall time including the cluster's start and its workers' first kernel
  loads, and without them (a warm-up round on the same cluster first);
- throughput ratio = serial time / cluster time, and the per-problem overhead
  (cluster time * workers / problems - mean serial time per problem);
- that every cluster result equals its serial result exactly (cost and iterations).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
           "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_v] = "1"
# The serial baseline runs numba as solve_many's workers do (same results bit for bit).
os.environ.setdefault("FGOPT_NUMPY_BUDGET", "0")

import argparse  # noqa: E402
import datetime as dt  # noqa: E402
import functools  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

FILES = {"m3500": "pose2d/input_M3500_g2o.g2o", "sphere2500": "pose3d/sphere2500.g2o"}


def data_dir() -> Path:
    return Path(os.environ.get("FGOPT_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def perturbed(name: str, seed: int):
    """``(graph, initial)`` of a file with every pose moved by a seeded random tangent step."""
    import fgopt
    from fgopt.manifolds.base import ops_for

    graph, initial = fgopt.io.read(str(data_dir() / FILES[name]))
    rng = np.random.default_rng(seed)
    out = fgopt.Variables()
    for k in initial.keys():
        x = initial.at(k)
        ops = ops_for(x)
        d = ops.dim(x)
        sig = np.r_[np.full(1 if d == 3 else 3, 0.05), np.full(d - (1 if d == 3 else 3), 0.1)]
        out.add(k, ops.retract(x, rng.normal(0.0, sig)))
    return graph, out


def builders(n: int) -> list:
    return [functools.partial(perturbed, "m3500" if i % 2 == 0 else "sphere2500", i)
            for i in range(n)]


def _cpu() -> float:
    """CPU seconds (user + system) this process has used."""
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run(n: int, workers: int) -> dict:
    import fgopt
    from dask.distributed import Client

    from fgopt.distributed.many import local_cluster

    load_start = os.getloadavg()[0]
    problems = builders(n)
    for name in FILES:  # warm-up: kernels compiled/loaded, files in the page cache
        fgopt.optimize(*perturbed(name, 10_000))
    t0, c0 = time.perf_counter(), _cpu()
    serial = [fgopt.optimize(*b()) for b in problems]
    t_serial, cpu_serial = time.perf_counter() - t0, _cpu() - c0

    t0 = time.perf_counter()
    cold = fgopt.solve_many(problems, workers=workers, progress=False)
    t_cold = time.perf_counter() - t0

    cluster = local_cluster(workers)  # the cluster solve_many starts (cold run above)
    client = Client(cluster)
    try:
        fgopt.solve_many(builders(2 * workers), client=client, progress=False)  # warm workers
        w0, c0, t0 = client.run(_cpu), _cpu(), time.perf_counter()
        warm = fgopt.solve_many(problems, client=client, progress=False)
        t_warm = time.perf_counter() - t0
        c1, w1 = _cpu(), client.run(_cpu)
        cpu_workers, cpu_client = sum(w1[w] - w0[w] for w in w0), c1 - c0
    finally:
        client.close()
        cluster.close()

    equal = all(a.final_cost == s.final_cost and a.iterations == s.iterations
                for res in (cold, warm) for a, s in zip(res, serial))
    per_serial = t_serial / n
    return {
        "problems": n, "workers": workers, "serial_s": t_serial, "cluster_cold_s": t_cold,
        "cluster_warm_s": t_warm, "ratio_cold": t_serial / t_cold, "ratio_warm": t_serial / t_warm,
        "overhead_per_problem_s": t_warm * workers / n - per_serial,
        "serial_per_problem_s": per_serial, "results_equal": equal,
        "iterations_median": statistics.median(r.iterations for r in serial),
        "loadavg_1min": os.getloadavg()[0], "loadavg_start": load_start,
        "cpu_serial_s": cpu_serial, "cpu_workers_s": cpu_workers, "cpu_client_s": cpu_client,
    }


def markdown(r: dict, commit: str) -> str:
    return "\n".join([
        f"# solve_many: {r['problems']} problems, serial vs LocalCluster ({r['workers']} workers)",
        "",
        f"Commit {commit}; `python -m benchmarks.many --problems {r['problems']} --workers "
        f"{r['workers']}`; load average (1 min) {r['loadavg_start']:.2f} at the start, "
        f"{r['loadavg_1min']:.2f} at the end (2 cores, shared).",
        "",
        "| | seconds | throughput vs serial |",
        "|---|---|---|",
        f"| serial (one warm process) | {r['serial_s']:.2f} | 1 |",
        f"| solve_many, new LocalCluster (start + first kernel loads included) | "
        f"{r['cluster_cold_s']:.2f} | x{r['ratio_cold']:.2f} |",
        f"| solve_many, warm cluster | {r['cluster_warm_s']:.2f} | x{r['ratio_warm']:.2f} |",
        "",
        f"Serial time per problem {r['serial_per_problem_s'] * 1e3:.0f} ms (median "
        f"{r['iterations_median']:.0f} LM iterations); overhead per problem on the warm cluster "
        f"{r['overhead_per_problem_s'] * 1e3:.0f} ms. Every cluster result equals its serial "
        f"result exactly: {r['results_equal']}.",
        "",
        (f"CPU seconds (less sensitive to other load than wall time): serial "
        f"{r['cpu_serial_s']:.2f}; warm cluster: workers {r['cpu_workers_s']:.2f} + client and "
        f"scheduler {r['cpu_client_s']:.2f} = {r['cpu_workers_s'] + r['cpu_client_s']:.2f} "
        f"(x{(r['cpu_workers_s'] + r['cpu_client_s']) / r['cpu_serial_s']:.3f} the serial CPU; "
        f"on {r['workers']} idle cores the warm throughput ratio would be at most "
        f"x{r['workers'] * r['cpu_serial_s'] / (r['cpu_workers_s'] + r['cpu_client_s']):.2f})."),
        "",
    ])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", type=int, default=64)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 2)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    r = run(args.problems, args.workers)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    md = markdown(r, commit)
    print(md)
    out = args.out or str(Path(__file__).parent / "results" / f"many-{dt.date.today()}.md")
    Path(out).write_text(md)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
