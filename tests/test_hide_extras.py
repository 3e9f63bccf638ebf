"""``FGOPT_HIDE_EXTRAS`` (tests/conftest.py, ``make test-no-cholmod``) really hides a package:
in a subprocess started with it, ``import sksparse`` fails, ``have_extra`` agrees, the default
linear solver is the CHOLMOD-free one, and a grandchild process hides it too."""

import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

PROBE = """
import importlib.util, subprocess, sys
from fgopt.errors import have_extra
from fgopt.solvers.linear.base import choose_linear_solver
try:
    import sksparse.cholmod
    imported = True
except ImportError:
    imported = False
child = subprocess.run([sys.executable, "-c", "import importlib.util as u; "
                        "print(u.find_spec('sksparse') is None)"],
                       capture_output=True, text=True, check=True).stdout.strip()
print(imported, have_extra("sksparse"), importlib.util.find_spec("sksparse") is None, child,
      choose_linear_solver(None))
"""


def test_hidden_extra_is_absent_in_the_process_and_its_children():
    """With FGOPT_HIDE_EXTRAS=sksparse and the helper folder on PYTHONPATH (what the conftest sets
    up), scikit-sparse is absent by every test fgopt and a test can make, in children too."""
    env = dict(os.environ, FGOPT_HIDE_EXTRAS="sksparse",
               PYTHONPATH=os.pathsep.join([str(HERE / "_hide_extras"), str(HERE.parent)]))
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "False", "True", "True", "block"]
