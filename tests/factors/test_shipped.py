"""Shipped generated kernels of the built-in factors: regenerating gives the committed bytes,
and a fresh cache uses them (no SymPy at first use)."""

import os
import subprocess
import sys
from pathlib import Path

from fgopt.factors.library.shipped import SHIPPED_DIR, builtin_kernels
from fgopt.symbolic.cache import module_name

REPO = Path(__file__).resolve().parents[2]


def test_regenerating_gives_the_committed_bytes(tmp_path):
    """``python -m fgopt.factors.library.shipped`` is deterministic and the committed files are
    current: same names (cache keys) and the same bytes."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    subprocess.run([sys.executable, "-m", "fgopt.factors.library.shipped", str(tmp_path)],
                   env=env, cwd=REPO, check=True, capture_output=True)
    written = list(tmp_path.glob("*.py.txt"))
    committed = sorted(p.name for p in SHIPPED_DIR.glob("*.py.txt"))
    assert sorted(p.name for p in written) == committed, (
        "shipped kernels are stale: run python -m fgopt.factors.library.shipped")
    for p in written:
        assert p.read_bytes() == (SHIPPED_DIR / p.name).read_bytes(), p.name


def test_every_builtin_kernel_is_shipped():
    """Each built-in (type, pattern) has a shipped file under its current cache key."""
    for ftype, pattern in builtin_kernels():
        name = module_name(ftype.name, ftype.cache_key(pattern))
        assert (SHIPPED_DIR / f"{name}.py.txt").is_file(), name


def test_fresh_cache_uses_shipped_source_without_sympy(tmp_path):
    """With an empty kernel cache, a Pose2 prior + between graph is built from shipped sources:
    nothing is derived and SymPy is never imported."""
    code = ("import sys, numpy as np, fgopt\n"
            "from fgopt import SE2, PriorFactor, BetweenFactor, key\n"
            "from fgopt.noise import Isotropic\n"
            "n = Isotropic.sigma(3, 0.1)\n"
            "g = fgopt.FactorGraph()\n"
            "g.add(PriorFactor(key('x', 1), SE2(), n))\n"
            "g.add(BetweenFactor(key('x', 1), key('x', 2), SE2.from_xytheta(1, 0, 0), n))\n"
            "from fgopt.symbolic import cache\n"
            "print(cache.STATS['shipped'], cache.STATS['derived'], 'sympy' in sys.modules)\n")
    env = dict(os.environ, FGOPT_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         cwd=REPO, check=True)
    assert out.stdout.split() == ["2", "0", "False"], out.stdout + out.stderr
