"""``fgopt cache build``: the families compile into the cache once and load from it afterwards."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fgopt._cache_build import FAMILIES, build
from fgopt.errors import FgoptError

REPO = Path(__file__).resolve().parents[1]


def _fresh_cache(tmp_path: Path, monkeypatch) -> Path:
    cache = tmp_path / "fgopt-cache"
    cache.mkdir(mode=0o700)
    monkeypatch.setenv("FGOPT_CACHE_DIR", str(cache))
    monkeypatch.setenv("PYTHONPATH", str(REPO))
    return cache


def test_a_family_compiles_once_then_loads_and_a_script_of_it_compiles_nothing(tmp_path,
                                                                               monkeypatch):
    """The geometry family compiles its functions into an empty cache and reports them; built
    again it compiles none; a new script using a group's values (new and stored ones mixed)
    then compiles nothing either: it loads what the build compiled."""
    _fresh_cache(tmp_path, monkeypatch)
    out = io.StringIO()
    first = build(["geometry"], jobs=1, out=out)
    assert first["geometry"]["compiled"] > 10
    assert "[1/1] geometry" in out.getvalue()
    assert build(["geometry"], jobs=1, out=io.StringIO())["geometry"]["compiled"] == 0
    script = (
        "import json, numpy as np\n"
        "from numba.core import event\n"
        "from fgopt import SE3, SO3, Variables\n"
        "from fgopt._first_use import _name\n"
        "names = []\n"
        "class Count(event.Listener):\n"
        "    def on_start(self, ev):\n"
        "        if _name(ev.data): names.append(_name(ev.data))\n"
        "    def on_end(self, ev): pass\n"
        "event.register('numba:compile', Count())\n"
        "v = Variables(); v.add(0, SE3(SO3.exp([0.1, 0.2, 0.3]), [1.0, 2.0, 3.0]))\n"
        "step = SE3.exp(np.full(6, 0.1))\n"
        "(v.at(0) * step).between(v.at(0)).log(); v.at(0).matrix(); step.inverse().adjoint()\n"
        "print(json.dumps(names))\n")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         cwd=tmp_path, env=dict(os.environ, FGOPT_NUMPY_BUDGET="0"), check=True)
    assert json.loads(run.stdout.strip().splitlines()[-1]) == []


def test_an_unknown_family_is_an_error_naming_it_and_the_choices(tmp_path, monkeypatch):
    """A misspelt family is refused before any process starts, naming it and the families."""
    _fresh_cache(tmp_path, monkeypatch)
    with pytest.raises(FgoptError, match="unknown family posegraphs; choose from .*pose-graphs"):
        build(["posegraphs"], out=io.StringIO())


def test_a_failing_family_is_an_error_naming_it_with_its_output(tmp_path, monkeypatch):
    """A family whose child process fails raises an FgoptError naming the family and quoting
    the end of the child's error output (here the child finds a broken numpy first on its
    path; this process has already imported the real one)."""
    cache = _fresh_cache(tmp_path, monkeypatch)
    broken = tmp_path / "broken" / "numpy"
    broken.mkdir(parents=True)
    (broken / "__init__.py").write_text("raise ImportError('simulated broken numpy')\n")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(broken.parent), str(REPO)]))
    with pytest.raises(FgoptError, match="(?s)family 'geometry' failed.*simulated broken numpy"):
        build(["geometry"], jobs=1, out=io.StringIO())
    assert cache.is_dir()


def test_the_command_line_reports_a_bad_family_as_one_error_line(capsys):
    """``fgopt cache build --only`` with an unknown family exits with status 2 and one error
    line naming it, no traceback."""
    from fgopt.cli import main

    assert main(["cache", "build", "--only", "geometry,nope"]) == 2
    err = capsys.readouterr().err
    assert "unknown family nope" in err and "Traceback" not in err

