"""``solve_many`` called from a script: at top level without ``if __name__ == "__main__":`` it
raises one FgoptError before any worker starts (the body runs once); guarded, it solves.
Real scripts, run in a subprocess (spawned workers re-import the script's file)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from fgopt.distributed._main_guard import _guarded

pytest.importorskip("dask.distributed")

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

BODY = """
import fgopt
from fgopt import SE2, key
from fgopt.factors import PriorFactor
from fgopt.noise import Diagonal

print("BODY RUN", flush=True)

def problem():
    g = fgopt.FactorGraph([PriorFactor(key("x", 0), SE2.from_xytheta(1, 2, 0.3),
                                       Diagonal.sigmas([1, 1, 1]))])
    return g, fgopt.Variables({key("x", 0): SE2.identity()})
"""


def _run(tmp_path, text: str) -> subprocess.CompletedProcess:
    script = tmp_path / "script.py"
    script.write_text(textwrap.dedent(BODY) + textwrap.dedent(text))
    env = {**os.environ, "PYTHONPATH": ROOT + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          env=env, timeout=300, cwd=tmp_path)


def test_unguarded_script_raises_fgopt_error_and_runs_once(tmp_path):
    """Top-level solve_many: an FgoptError naming the script line and the guard to add; the
    body ran once, and no worker process started (no freeze_support / Nanny message)."""
    r = _run(tmp_path, """
        out = fgopt.solve_many([problem()], workers=1, progress=False)
        print("RESULT", out[0].final_cost)
    """)
    assert r.returncode != 0
    assert r.stdout.count("BODY RUN") == 1
    assert "fgopt.errors.FgoptError" in r.stderr
    assert 'if __name__ == "__main__":' in r.stderr and "script.py:" in r.stderr
    assert "freeze_support" not in r.stderr and "Nanny" not in r.stderr


def test_unguarded_call_through_a_function_is_caught(tmp_path):
    """A top-level ``main()`` call (no guard) that calls solve_many is refused the same way."""
    r = _run(tmp_path, """
        def main():
            return fgopt.solve_many([problem()], workers=1, progress=False)
        main()
    """)
    assert r.returncode != 0 and r.stdout.count("BODY RUN") == 1
    assert "FgoptError" in r.stderr and "freeze_support" not in r.stderr


def test_guarded_script_solves_with_body_run_once(tmp_path):
    """Under ``if __name__ == "__main__":`` the same call solves; the guarded body ran once
    (spawned workers re-import the module part only)."""
    r = _run(tmp_path, """
        if __name__ == "__main__":
            out = fgopt.solve_many([problem()], workers=1, progress=False)
            print("RESULT", out[0].final_cost)
    """)
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("RESULT ") == 1


def test_guard_detection():
    """Lines inside ``if __name__ == "__main__":`` (either operand order) are guarded; others,
    and lines in other ``if`` blocks, are not."""
    src = textwrap.dedent("""
        a = 1
        if __name__ == "__main__":
            b = 2
            c = 3
        if "__main__" == __name__:
            d = 4
        if x == "__main__":
            e = 5
    """)
    lines = {name: i + 1 for i, line in enumerate(src.splitlines())
             for name in "abcde" if line.strip().startswith(name + " =")}
    assert not _guarded(src, lines["a"])
    assert _guarded(src, lines["b"]) and _guarded(src, lines["c"]) and _guarded(src, lines["d"])
    assert not _guarded(src, lines["e"])
