"""Fuzz the file readers at scale: 10,000+ mutated inputs per format against reference parsers.

The mutation strategies, base files and reference parsers are the test suite's
(``tests/io/_fuzz.py``); the tests run a small derandomized set, this script the large one::

    .venv/bin/python -m benchmarks.fuzz_readers                      # 10,000 per format
    .venv/bin/python -m benchmarks.fuzz_readers --n 20000 --formats toro,gz --seed 3

Formats: ``g2o2d g2o3d toro bal`` (mutated text, read from memory) and ``gz bz2`` (any base,
mutated and / or damaged after compression, read from a file by ``fgopt.io.read``). Each input
must give an ``FgoptError`` where the reference finds it invalid, or exactly the reference's
graph; an input running longer than ``--hang`` seconds counts as a hang. Prints, per format,
inputs run, distinct inputs, accepted / refused, time, the slowest input (and that input timed
again, best of 3: a genuinely slow input or a stall of the machine); exits 1 if a format failed
(hypothesis shrinks the failing input and it is printed).
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import signal
import sys
import tempfile
import time
from pathlib import Path

from hypothesis import HealthCheck, Phase, given, seed, settings

from tests.io import _fuzz as F

FORMATS = ("g2o2d", "g2o3d", "toro", "bal", "gz", "bz2")


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang()


def fuzz(fmt: str, n: int, rng_seed: int, tmp: Path, hang: float) -> dict:
    """Run ``n`` inputs of one format; returns counts and times."""
    if fmt in ("gz", "bz2"):
        strategy = F.compressed(fmt)

        def check(case):
            return F.check_compressed(tmp / case[1], fmt, case[2])

        def digest(case):
            return case[2]
    else:
        strategy = F.mutated_toro() if fmt == "toro" else F.mutated(F.BASES[fmt][0])
        check = F.check_bal if fmt == "bal" else F.check_g2o

        def digest(text):
            return text.encode("utf-8", "surrogatepass")

    stats = {"format": fmt, "inputs": 0, "distinct": set(), "accepted": 0, "refused": 0,
             "slowest": 0.0}

    @seed(rng_seed)
    @settings(max_examples=n, deadline=None, database=None, derandomize=False,
              phases=[Phase.generate, Phase.shrink], suppress_health_check=list(HealthCheck))
    @given(strategy)
    def run(case):
        signal.setitimer(signal.ITIMER_REAL, hang)
        t = time.perf_counter()
        try:
            accepted = check(case)
        except Hang:
            raise AssertionError(f"{fmt}: input ran longer than {hang} s: {case!r}") from None
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        dt = time.perf_counter() - t
        stats["inputs"] += 1
        stats["distinct"].add(hashlib.sha1(digest(case)).digest())
        stats["accepted" if accepted else "refused"] += 1
        if dt > stats["slowest"]:
            stats["slowest"], stats["slowest_case"] = dt, case

    t0 = time.perf_counter()
    run()
    stats["seconds"] = time.perf_counter() - t0
    stats["distinct"] = len(stats["distinct"])
    # the slowest input again (best of 3): a slow input, or a stall of a loaded machine?
    again = []
    for _ in range(3):
        t = time.perf_counter()
        check(stats["slowest_case"])
        again.append(time.perf_counter() - t)
    stats["slowest_again"] = min(again)
    return stats


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=10_000, help="inputs per format (default 10000)")
    ap.add_argument("--formats", default=",".join(FORMATS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--hang", type=float, default=10.0, help="seconds before an input is a hang")
    args = ap.parse_args(argv)
    signal.signal(signal.SIGALRM, _alarm)
    logging.getLogger("fgopt.io").setLevel(logging.ERROR)  # skipped-EQUIV notes, guesses
    F.check_g2o(F.POSE2), F.check_g2o(F.POSE3), F.check_bal(F.BAL)  # compile the scanner first
    print(f"{'format':<7} {'inputs':>7} {'distinct':>8} {'accepted':>8} {'refused':>8} "
          f"{'seconds':>8} {'ms/input':>8} {'slowest ms':>10} {'(re-run)':>8}")
    failed = False
    with tempfile.TemporaryDirectory(prefix="fgopt-fuzz-") as tmp:
        for fmt in args.formats.split(","):
            try:
                s = fuzz(fmt, args.n, args.seed, Path(tmp), args.hang)
            except Exception as exc:  # noqa: BLE001 - report the shrunk failure and go on
                print(f"{fmt:<7} FAILED: {type(exc).__name__}: {exc}")
                failed = True
                continue
            print(f"{fmt:<7} {s['inputs']:>7} {s['distinct']:>8} {s['accepted']:>8} "
                  f"{s['refused']:>8} {s['seconds']:>8.1f} "
                  f"{1000 * s['seconds'] / max(s['inputs'], 1):>8.2f} "
                  f"{1000 * s['slowest']:>10.1f} {1000 * s['slowest_again']:>8.1f}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
