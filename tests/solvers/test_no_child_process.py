"""``optimize`` starts no process: not on a small problem whose small-problem driver is not
compiled yet, not on a large sparse one, not on a long NumPy-backend solve with cold caches."""

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

_CODE = """
import multiprocessing, os, subprocess, sys
started = []
class NoPopen(subprocess.Popen):
    def __init__(self, *a, **k):
        started.append(a[0] if a else k.get('args'))
        super().__init__(*a, **k)
subprocess.Popen = NoPopen
_start = multiprocessing.Process.start
multiprocessing.Process.start = lambda self: (started.append('multiprocessing'), _start(self))
_fork = os.fork
os.fork = lambda: (started.append('fork'), _fork())[1]
import fgopt, pathlib
from fgopt.datasets import manhattan_2d
from fgopt.solvers import small
small.COMPILE_IN_FOREGROUND = False  # the small problem's driver: as if not compiled yet
small._Plan.marker = lambda self: pathlib.Path(sys.argv[1]) / 'not-compiled.ready'
for n, backend in ((4, 'numba'), (1200, 'numba'), (1200, 'numpy')):
    m = manhattan_2d(n)
    r = fgopt.optimize(m.graph, m.initial, backend=backend, max_iterations=4)
    assert r.final_cost <= r.initial_cost
print(started)
"""


def test_optimize_starts_no_process(tmp_path):
    """Solves of 4 poses (its small-problem driver not compiled) and 1200 poses on both
    backends call neither ``subprocess``, ``multiprocessing`` nor ``os.fork``."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", _CODE, str(tmp_path)], capture_output=True,
                         text=True,
                         cwd=REPO, env=env, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"
