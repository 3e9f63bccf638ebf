"""Shared fixtures: the real-data folder (skips with a reason when it is absent), one kernel
cache for the whole session, and GTSAM comparisons that must run where GTSAM is installable.

With ``FGOPT_REQUIRE_GTSAM=1`` (set by ``.ci/run``) a test skipped because ``gtsam`` could not be
imported (``pytest.importorskip("gtsam")``) is reported as a failure: CI installs gtsam with the
``[test]`` extra, so a skipped comparison there means a broken install, not a missing wheel.

With ``FGOPT_HIDE_EXTRAS=sksparse`` (comma-separated package names; ``make test-no-cholmod``) the
suite runs as if those optional packages were not installed, in the pytest process and in every
subprocess a test starts (``tests/_hide_extras/sitecustomize.py``): the check that ``make test``
stays green without the ``fgopt[cholmod]`` extra, without a second environment.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _hide_extras() -> None:
    """Apply ``FGOPT_HIDE_EXTRAS`` here (before any test imports fgopt) and in subprocesses."""
    names = os.environ.get("FGOPT_HIDE_EXTRAS", "")
    if not names.strip():
        return
    import importlib.util
    import sys

    if any(type(f).__name__ == "HiddenExtras" for f in sys.meta_path):
        return  # a subprocess of a hiding run: the sitecustomize on PYTHONPATH did it already
    folder = Path(__file__).resolve().parent / "_hide_extras"
    spec = importlib.util.spec_from_file_location("_fgopt_hide_extras", folder / "sitecustomize.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.hide(names)
    path = os.environ.get("PYTHONPATH", "")
    if str(folder) not in path.split(os.pathsep):
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(folder), path) if p)
    sys.modules.setdefault("_fgopt_hide_extras", module)


_hide_extras()


def pytest_report_header(config):
    names = os.environ.get("FGOPT_HIDE_EXTRAS", "").strip()
    return f"FGOPT_HIDE_EXTRAS={names}: running as if these were not installed" if names else None


def pytest_configure(config):
    """One kernel cache for every test and every subprocess a test starts (under .pytest_cache:
    warm on reruns, away from the user's ~/.cache). Set before any test runs: generated kernels
    are memoized per process, so a cache directory switched mid-session would leave subprocesses
    looking in a directory the parent never wrote."""
    if "FGOPT_CACHE_DIR" not in os.environ:
        path = config.cache.mkdir("fgopt-kernels")
        path.chmod(0o700)  # fgopt refuses a cache root others can write (a umask of 002)
        os.environ["FGOPT_CACHE_DIR"] = str(path)


#: ``make test``'s ``--dist loadfile`` queues files by number of tests, most first, so these files
#: of a few long tests (their own virtual env and cold caches, notebook kernels) would start last
#: and run alone on one core at the end; they start first instead.
LONG_FIRST = ("tests/test_install.py", "tests/test_notebooks.py::test_notebook_runs",
              "benchmarks/tests/test_startup_ports.py")
#: Scheduled one test at a time rather than as a file: each notebook runs in its own kernel
#: process, so the workers can share them.
ONE_BY_ONE = ("tests/test_notebooks.py::test_notebook_runs",)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadfile`` with :data:`LONG_FIRST` queued first and :data:`ONE_BY_ONE` split."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class LongFirst(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            if nodeid.startswith(ONE_BY_ONE):
                return nodeid
            return super()._split_scope(nodeid)

        def _assign_work_unit(self, node) -> None:
            if not getattr(self, "_long_first_done", False):
                self._long_first_done = True
                rank = {s: next(i for i, p in enumerate(LONG_FIRST) if s.startswith(p))
                        for s in self.workqueue if s.startswith(LONG_FIRST)}
                for scope in sorted(rank, key=rank.get, reverse=True):
                    self.workqueue.move_to_end(scope, last=False)
            super()._assign_work_unit(node)

    return LongFirst(config, log)


REQUIRE_GTSAM = os.environ.get("FGOPT_REQUIRE_GTSAM", "") not in ("", "0")


def _skipped_for_gtsam(report) -> str | None:
    """The skip reason if ``report`` is a skip caused by gtsam being unavailable."""
    if not report.skipped or not isinstance(report.longrepr, tuple):
        return None
    reason = str(report.longrepr[2])
    return reason if "gtsam" in reason.lower() else None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Under ``FGOPT_REQUIRE_GTSAM=1`` a GTSAM comparison that skipped fails instead."""
    outcome = yield
    report = outcome.get_result()
    reason = _skipped_for_gtsam(report) if REQUIRE_GTSAM else None
    if reason is not None:
        report.outcome = "failed"
        report.longrepr = (f"{item.nodeid}: FGOPT_REQUIRE_GTSAM=1 but this GTSAM comparison was "
                           f"skipped ({reason}); install the test extra: "
                           "pip install -e '.[test]'")


def data_dir() -> Path:
    return Path(os.environ.get("FGOPT_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def data():
    d = data_dir()
    if not d.is_dir():
        pytest.skip(f"benchmark data folder {d} is absent (set FGOPT_DATA to ../shared/data)")
    return d


def _data_file(relpath: str) -> Path:
    p = data_dir() / relpath
    if not p.is_file():
        pytest.skip(f"data file {p} is absent (set FGOPT_DATA to the shared data folder)")
    return p


@pytest.fixture(scope="session")
def data_file():
    """``data_file("pose2d/intel.g2o")`` -> path, or skip the test with a reason."""
    return _data_file


@pytest.fixture(autouse=True)
def fresh_numpy_budget():
    """Each test starts with a new process's NumPy-twin budget (``fgopt._jit``): small batches
    run their twins as in a fresh script, whatever the tests before it solved."""
    from fgopt import _jit

    _jit._numpy_seconds[0] = 0.0
    yield
