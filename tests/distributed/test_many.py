"""``solve_many`` on a real 2-worker Dask LocalCluster (no mock), its serial fallback, and
``fgopt solve-many`` on a mix of good and malformed files."""

from __future__ import annotations

import builtins
import functools
import os

import numpy as np
import pytest

import fgopt
from fgopt.cli import main
from fgopt.errors import FgoptError, FileFormatError
from fgopt.io import read

pytest.importorskip("dask.distributed")

#: This process's NUMBA_NUM_THREADS before any cluster started (a cluster must not change it).
NUMBA_THREADS_BEFORE = os.environ.get("NUMBA_NUM_THREADS")


def _raises_fgopt_error():
    raise FgoptError("this problem cannot be built")


@pytest.fixture(scope="module")
def client():
    from dask.distributed import Client

    from fgopt.distributed.many import local_cluster

    cluster = local_cluster(2)  # the cluster solve_many starts without client=
    c = Client(cluster)
    yield c
    c.close()
    cluster.close()


def test_cluster_results_equal_serial_and_errors_stay_in_their_slot(client, data_file, tmp_path):
    """Pairs and worker-side builders are solved on two worker processes to exactly the serial
    results; a problem that raises returns its FgoptError in its slot (file:line for a malformed
    file) while the others finish."""
    bad = tmp_path / "bad.g2o"
    bad.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 x 1\n")
    pose2 = str(data_file("small/pose2example.txt"))
    problems = [read(pose2),                                         # shipped pair
                functools.partial(read, str(data_file("pose2d/intel.g2o"))),  # built on worker
                functools.partial(read, str(bad)),
                _raises_fgopt_error,
                functools.partial(read, str(data_file("small/pose3example.txt")))]
    # one backend on both sides: "auto" picks NumPy in a fresh worker but numba in a test
    # process that already loaded it (another linear solver: last-bit differences)
    results = fgopt.solve_many(problems, client=client, progress=False, max_iterations=50,
                               backend="numba")
    assert isinstance(results[2], FileFormatError) and "bad.g2o:3" in str(results[2])
    assert isinstance(results[3], FgoptError) and "cannot be built" in str(results[3])
    for i in (0, 1, 4):
        graph, initial = problems[i] if i == 0 else problems[i]()
        serial = fgopt.optimize(graph, initial, max_iterations=50, backend="numba")
        assert results[i].final_cost == serial.final_cost
        assert results[i].iterations == serial.iterations
        k = initial.keys()[-1]
        assert np.array_equal(results[i].values.at(k).to_storage(),
                              serial.values.at(k).to_storage())


def test_generated_factor_types_solve_on_workers(client):
    """A graph of @fgopt.factor factors (a type defined in this test module) solves on a worker
    to the same cost as here."""
    from tests.distributed.test_pickling import _problem

    graph, initial = _problem()
    [remote] = fgopt.solve_many([(graph, initial)], client=client, progress=False)
    assert remote.final_cost == fgopt.optimize(graph, initial, backend="numba").final_cost


def test_without_dask_it_runs_serially_with_a_note(monkeypatch, data_file):
    """With dask.distributed missing, solve_many warns (naming the extra) and solves serially."""
    real_import = builtins.__import__

    def no_dask(name, *args, **kwargs):
        if name.startswith("dask"):
            raise ImportError("no dask here")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_dask)
    problem = read(str(data_file("small/pose2example.txt")))
    with pytest.warns(UserWarning, match=r"fgopt\[distributed\]"):
        [r] = fgopt.solve_many([problem], progress=False)
    assert r.final_cost == fgopt.optimize(*problem, backend="numba").final_cost


def test_cli_solve_many_writes_results_and_a_summary(data_file, tmp_path, capsys):
    """`fgopt solve-many` writes each optimized file and summary.md; the malformed file's row
    names file:line, the others are solved; the exit code says one failed."""
    bad = tmp_path / "broken.g2o"
    bad.write_text("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 7 1 0 0 1 0 0 1 0 1\n")
    out = tmp_path / "out"
    files = [str(data_file("small/pose2example.txt")), str(bad),
             str(data_file("bal/dubrovnik-3-7-pre.txt"))]
    code = main(["solve-many", *files, "--workers", "2", "--out-dir", str(out), "--quiet"])
    assert code == 1
    summary = (out / "summary.md").read_text()
    assert "broken.g2o:2" in summary
    assert (out / "pose2example.txt").is_file() and (out / "dubrovnik-3-7-pre.txt").is_file()
    g, v = read(str(out / "pose2example.txt"))
    assert g.error(v) < g.error(read(files[0])[1])
    assert summary.count("| converged |") == 2, summary


def _kills_its_worker():
    import os

    os._exit(17)


def test_a_worker_that_dies_is_reported_in_its_slot(data_file):
    """A problem that kills its worker process is retried by Dask on a fresh worker; when that
    dies too, its slot holds an FgoptError saying so and the other problems are solved."""
    import dask
    from dask.distributed import Client, LocalCluster

    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                               dashboard_address=":0")
        client = Client(cluster)
        try:
            problem = read(str(data_file("small/pose2example.txt")))
            results = fgopt.solve_many([problem, _kills_its_worker, problem], client=client,
                                       progress=False)
        finally:
            client.close()
            cluster.close()
    assert isinstance(results[1], FgoptError) and "worker died" in str(results[1])
    serial = fgopt.optimize(*problem, backend="numba")
    assert results[0].final_cost == results[2].final_cost == serial.final_cost


def test_ctrl_c_closes_the_cluster_it_started(monkeypatch, data_file):
    """An interrupt while waiting propagates (nothing partial is returned) and the embedded
    LocalCluster and its client are closed."""
    import dask.distributed as dd

    made = []

    class RecordingCluster(dd.LocalCluster):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    def interrupted(futures):
        raise KeyboardInterrupt

    monkeypatch.setattr(dd, "LocalCluster", RecordingCluster)
    monkeypatch.setattr(dd, "as_completed", interrupted)
    problem = read(str(data_file("small/pose2example.txt")))
    with pytest.raises(KeyboardInterrupt):
        fgopt.solve_many([problem, problem], workers=1, progress=False)
    assert len(made) == 1 and made[0].status.name == "closed"


def _worker_setup() -> tuple:
    import gc
    import os

    import dask

    return (os.environ.get("MALLOC_TRIM_THRESHOLD_"), os.environ.get("OPENBLAS_NUM_THREADS"),
            os.environ.get("NUMBA_NUM_THREADS"),
            dask.config.get("distributed.worker.profile.enabled"),
            dask.config.get("distributed.admin.tick.interval"), gc.get_freeze_count() > 10_000)


def test_own_cluster_workers_are_set_up_for_numeric_work(client, monkeypatch):
    """The workers solve_many starts run one thread per pool, without Dask's
    MALLOC_TRIM_THRESHOLD_ (every large array a fresh mmap), without the stack profiler, with
    slow housekeeping polls and their start-up objects frozen out of the collector's way; a
    value an earlier Dask cluster left in this process's environment is hidden while they start,
    a user's own value is kept."""
    from fgopt.distributed import many

    assert set(client.run(_worker_setup).values()) == {(None, "1", "1", False, "1s", True)}
    # numba in this process would refuse a changed NUMBA_NUM_THREADS
    assert os.environ.get("NUMBA_NUM_THREADS") == NUMBA_THREADS_BEFORE
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")  # what a Nanny writes into os.environ
    with many._without_dask_malloc_trim():
        assert "MALLOC_TRIM_THRESHOLD_" not in os.environ
    assert os.environ["MALLOC_TRIM_THRESHOLD_"] == "65536"
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "1000000")
    with many._without_dask_malloc_trim():
        assert os.environ["MALLOC_TRIM_THRESHOLD_"] == "1000000"


def test_malformed_problems_and_methods_are_refused_before_any_worker_starts(monkeypatch):
    """A problem that is neither a (graph, initial) pair nor a callable, or an unknown method,
    is an FgoptError naming it, raised before a cluster starts (it used to come back per
    problem as "TypeError: cannot unpack non-iterable int object" after the cluster ran)."""
    import fgopt.distributed.many as many

    def no_cluster(*args, **kwargs):
        raise AssertionError("a cluster was started")

    monkeypatch.setattr(many, "run_tasks", no_cluster)
    s = fgopt.datasets.manhattan_2d(num_poses=5, seed=0)
    with pytest.raises(FgoptError, match="problem 1 must be a .graph, initial. pair.*got int"):
        fgopt.solve_many([(s.graph, s.initial), 3], progress=False)
    with pytest.raises(FgoptError, match="problem 0 .* got tuple"):
        fgopt.solve_many([(s.graph,)], progress=False)
    with pytest.raises(FgoptError, match="unknown method 'zzz'"):
        fgopt.solve_many([(s.graph, s.initial)], method="zzz", progress=False)
