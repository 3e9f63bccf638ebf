"""The one-line notice of first-use work (fgopt._first_use): said once while kernels are
derived or compiled the first time, never when they come from the cache."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

SCRIPT = textwrap.dedent('''
    import numpy as np
    import fgopt
    import fgopt._first_use as fu
    from fgopt.symbolic import V2, atan2

    fu.NOTICE_AFTER_SECONDS = 0.0  # every first-use step counts as long here

    @fgopt.factor
    def notice_probe(p: V2, q: V2) -> V2:
        d = q - p
        return V2(d.norm(), atan2(d[1], d[0]))

    m = notice_probe.generated_module()
    rng = np.random.default_rng(0)
    n = 2000  # above the NumPy-twin batch size: the numba kernel runs
    res, jac = m.linearize((rng.normal(size=(n, 2)), rng.normal(size=(n, 2))), np.empty((n, 0)))
    assert np.all(np.isfinite(jac))
''')


def _run(cache: Path) -> list[str]:
    env = dict(os.environ, FGOPT_CACHE_DIR=str(cache), PYTHONPATH=str(REPO),
               FGOPT_NUMPY_BUDGET="0")
    p = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True,
                       timeout=900)
    assert p.returncode == 0, p.stderr[-3000:]
    return [ln for ln in p.stderr.splitlines() if ln.startswith("fgopt:")]


def test_notice_once_when_derived_or_compiled_and_silent_when_cached(tmp_path):
    """Empty cache: exactly one line, naming the factor being derived and saying it happens once
    per machine; same cache again: no line; machine code removed: one line naming the kernel
    being compiled."""
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    first = _run(cache)
    assert len(first) == 1, first
    assert "deriving the kernels of notice_probe" in first[0]
    assert "first use on this machine" in first[0] and str(cache) in first[0]
    assert _run(cache) == []
    shutil.rmtree(cache / "numba")
    third = _run(cache)
    assert len(third) == 1 and "compiling machine code for notice_probe" in third[0], third
