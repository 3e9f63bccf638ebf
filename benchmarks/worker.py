"""One library x problem x mode, in a fresh process (``benchmarks.run`` spawns it).

    python -m benchmarks.worker --peer gtsam --problem m3500 --mode 5it --repeats 3 --out r.json

Pins every thread pool to one thread *before* numpy (or anything that imports it) is loaded, then:
load the problem the library's way (a warm-up load, then ``repeats`` timed loads; median), solve
once as warm-up (JIT compilation, caches), then ``repeats`` timed solves (median), each from the
file's initial guess. Tiny problems are solved several times per sample so one sample lasts at
least ``--min-sample`` seconds. Writes JSON to ``--out`` after every stage, so a run the parent kills
at its time cap still reports what it finished.
"""

import os

THREAD_VARS = ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT", "OPENBLAS_NUM_THREADS",
               "MKL_NUM_THREADS", "NUMBA_NUM_THREADS",
               "VECLIB_MAXIMUM_THREADS", "BLIS_NUM_THREADS")
for _v in THREAD_VARS:
    os.environ[_v] = "1"
# Warm-process figures: small batches on the compiled kernels from the first timed call (a
# process reaches this after 0.5 s of NumPy-twin work; see fgopt/_jit.py).
os.environ.setdefault("FGOPT_NUMPY_BUDGET", "0")
# ... and the small-problem driver (fgopt.solvers.small) compiled by the warm-up solve when its
# set of kernels is new on this machine, not in a background process while the timed solves
# take the general path (robot localization's "5 it" at 4ab30dc: 1.94 ms on the general path,
# its driver compiled during that run; 1.13 ms for the same 5 iterations on it, next run)
os.environ.setdefault("FGOPT_SMALL_COMPILE", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", required=True)
    ap.add_argument("--problem", required=True)
    ap.add_argument("--mode", required=True, choices=["5it", "converge"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--min-sample", type=float, default=0.05,
                    help="seconds: tiny problems are solved repeatedly within one sample")
    ap.add_argument("--long", type=float, default=30.0,
                    help="seconds: a warm-up solve longer than this is the only sample")
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)

    rec = {"peer": args.peer, "problem": args.problem, "mode": args.mode, "status": "started",
           "threads": {v: os.environ[v] for v in THREAD_VARS}}

    def dump():
        rec["peak_rss_mb"] = peak_rss_mb()
        rec["loadavg_1min"] = os.getloadavg()[0]  # other processes on the machine
        tmp = args.out + ".tmp"
        with open(tmp, "w") as fh:
            json.dump(rec, fh, indent=1, default=float)
        os.replace(tmp, args.out)

    try:
        from benchmarks import problems, yardstick
        from benchmarks.peers import get_runner

        spec = problems.PROBLEMS[args.problem]
        runner = get_runner(args.peer)
        rec["version"] = runner.version()
        rec["pinning"] = runner.pinning
        rec["rss_after_import_mb"] = peak_rss_mb()
        why = runner.supports(spec)
        if why:
            rec["status"] = "unsupported"
            rec["error"] = why
            dump()
            return 0
        dump()

        if getattr(runner, "self_timed", False):  # e.g. the C++ Ceres program times itself
            res = runner.run_self_timed(spec, args.mode, args.repeats)
            est = res.pop("estimate")
            rec.update(res)
            rec["peak_rss_solve_mb"] = resource.getrusage(
                resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
            data = problems.load(args.problem)
            rec["initial_cost"] = yardstick.cost(data, yardstick.initial_estimate(data))
            rec["final_cost"] = yardstick.cost(data, est)
            rec["status"] = "ok"
            dump()
            return 0

        # ---- load: warm-up + repeats -------------------------------------------------------
        load_times = []
        state = None
        for k in range(1 + args.repeats):
            state = None
            t0 = time.perf_counter()
            state = runner.load(spec)
            dt = time.perf_counter() - t0
            if k == 0:
                rec["load_first_s"] = dt  # includes one-off costs (imports, codegen, JIT)
            else:
                load_times.append(dt)
            if dt > args.long:  # slow loader: one sample is enough
                load_times = [dt]
                break
        rec["load_s"] = statistics.median(load_times)
        rec["load_samples"] = load_times
        rec["status"] = "loaded"
        dump()

        # ---- solve: warm-up, then timed samples --------------------------------------------
        runner.reset(state)
        t0 = time.perf_counter()
        out = runner.solve(state, args.mode)
        warm = time.perf_counter() - t0
        rec["warmup_s"] = warm
        rec["status"] = "warmed-up"
        dump()
        samples = []
        inner = 1
        if warm > args.long:
            samples = [warm]
            rec["timing_note"] = "single run (the warm-up run is the sample)"
        else:
            if warm < 2.0:  # probe again: the warm-up may include JIT/codegen
                runner.reset(state)
                t0 = time.perf_counter()
                runner.solve(state, args.mode)
                probe = time.perf_counter() - t0
                if probe < args.min_sample:
                    inner = int(min(1000, max(1, args.min_sample / max(probe, 1e-6))))
            for _ in range(args.repeats):
                tot = 0.0
                for _ in range(inner):
                    runner.reset(state)
                    t0 = time.perf_counter()
                    out = runner.solve(state, args.mode)
                    tot += time.perf_counter() - t0
                samples.append(tot / inner)
        rec["solve_s"] = statistics.median(samples)
        rec["solve_samples"] = samples
        rec["solves_per_sample"] = inner
        rec["iterations"] = out.iterations
        rec["lib_initial_cost"] = out.lib_initial_cost
        rec["lib_final_cost"] = out.lib_final_cost
        rec["lib_status"] = out.status
        rec["extra"] = out.extra
        rec["peak_rss_solve_mb"] = peak_rss_mb()

        # ---- one yardstick for every library ------------------------------------------------
        data = problems.load(args.problem)
        est = runner.estimate(state, out)
        rec["initial_cost"] = yardstick.cost(data, yardstick.initial_estimate(data))
        rec["final_cost"] = yardstick.cost(data, est)
        rec["status"] = "ok"
        dump()
    except Exception as exc:  # report, don't crash the whole benchmark
        rec["status"] = "error"
        rec["error"] = f"{type(exc).__name__}: {exc}"
        rec["traceback"] = traceback.format_exc()
        dump()
        print(rec["traceback"], file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
