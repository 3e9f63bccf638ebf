"""Many independent problems on Dask: :func:`solve_many`.

Each problem is solved by one task on a Dask worker. What travels is the problem itself (graphs,
values and factor types pickle; generated kernels are loaded or derived on the worker, once per
worker process - see :mod:`fgopt.factors.portable`), or a zero-argument callable that builds the
problem on the worker, so large problems are never shipped.

Without ``client=`` an embedded :class:`dask.distributed.LocalCluster` is started (one
single-threaded worker process per core) and closed afterwards, Ctrl-C included. Without
``dask[distributed]`` installed the problems are solved serially in this process, with a note.
"""

from __future__ import annotations

import contextlib
import os
import time
import traceback
import warnings
from collections.abc import Callable, Iterable
from typing import Any

from ..errors import FgoptError
from ._main_guard import check_main_guard

INSTALL_HINT = "pip install 'fgopt[distributed]'"


def _as_fgopt_error(exc: BaseException, where: str) -> FgoptError:
    if isinstance(exc, FgoptError):
        return exc
    tb = "".join(traceback.format_exception_only(type(exc), exc)).strip()
    return FgoptError(f"{where}: {tb}")


#: Environment of the worker processes of the cluster :func:`local_cluster` starts, set before
#: they start (Dask's ``distributed.nanny.pre-spawn-environ``, which a Nanny also writes into this
#: process's ``os.environ``). One thread for every BLAS / OpenMP pool (Dask's own values): a
#: worker is one core. And not Dask's default ``MALLOC_TRIM_THRESHOLD_=65536`` (``None`` unsets
#: it): setting it turns glibc's dynamic mmap threshold off, so every array over 128 KiB is a
#: fresh ``mmap`` whose pages fault in on first touch (16 M3500 / sphere2500 solves in one
#: process: 139,000 page faults instead of 1,100, and 0.30 s of system time instead of 0.02 s).
WORKER_ENVIRON = {"MALLOC_TRIM_THRESHOLD_": None, "OMP_NUM_THREADS": "1",
                  "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

#: Set inside each worker process as it starts (Nanny ``env=``), never in this one: numba refuses
#: a changed ``NUMBA_NUM_THREADS`` once its threads run, so it must not leak into the caller.
WORKER_PROCESS_ENV = {"NUMBA_NUM_THREADS": "1"}

#: Dask settings of that cluster (its scheduler runs in this process): no statistical profiler
#: on the workers (it samples the solving thread's stack every 10 ms, for a dashboard nobody
#: looks at here), and slower housekeeping polls (event-loop tick 20 ms -> 1 s, system monitor
#: 0.5 -> 2 s, memory monitor 0.1 -> 1 s). Idle, a 2-worker cluster then costs 9 ms of CPU per
#: second in this process and 3 ms per worker instead of 42 and 18: the cores are the workers'.
CLUSTER_CONFIG = {"distributed.worker.profile.enabled": False,
                  "distributed.admin.tick.interval": "1s",
                  "distributed.admin.system-monitor.interval": "2s",
                  "distributed.worker.memory.monitor-interval": "1s"}


@contextlib.contextmanager
def _without_dask_malloc_trim():
    """A Nanny writes its pre-spawn environment into this process's ``os.environ`` (and spawned
    workers inherit it): hide a ``MALLOC_TRIM_THRESHOLD_`` an earlier Dask cluster left there
    (Dask's value) while ours start; a value of the user's own stays."""
    import dask

    configured = dask.config.get("distributed.nanny.pre-spawn-environ", {})
    left = os.environ.get("MALLOC_TRIM_THRESHOLD_")
    hide = left is not None and left in {"65536", str(configured.get("MALLOC_TRIM_THRESHOLD_"))}
    if hide:
        del os.environ["MALLOC_TRIM_THRESHOLD_"]
    try:
        yield
    finally:
        if hide and "MALLOC_TRIM_THRESHOLD_" not in os.environ:
            os.environ["MALLOC_TRIM_THRESHOLD_"] = left


def local_cluster(workers: int | None = None) -> Any:
    """The :class:`dask.distributed.LocalCluster` :func:`solve_many` starts without ``client=``:
    ``workers`` (default: one per core) single-threaded worker processes, set up for numeric
    work (:data:`WORKER_ENVIRON`, :data:`WORKER_PROCESS_ENV`, :data:`CLUSTER_CONFIG`)."""
    import dask
    from dask.distributed import Client, LocalCluster

    n = workers or os.cpu_count() or 1
    settings = {**CLUSTER_CONFIG, "distributed.nanny.pre-spawn-environ": WORKER_ENVIRON}
    with dask.config.set(settings), _without_dask_malloc_trim():
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=":0", env=WORKER_PROCESS_ENV)
    try:
        with Client(cluster) as client:
            client.run(settle_worker)
    except BaseException:
        cluster.close()
        raise
    return cluster


def settle_worker() -> None:
    """Import what the tasks use, then freeze everything alive into the garbage collector's
    permanent generation: its full collections, triggered by the many small objects a solve
    makes, then stop walking the ~65,000 objects of Dask, NumPy, numba and fgopt's modules (a
    worker process holds ~150,000 objects after its first solves, a plain serial one ~118,000;
    freezing them all took the collector from 0.35 to 0.06 s per 32 solves). Only at start-up:
    frozen objects that later die in a reference cycle are never freed, so no task's data."""
    import gc

    from .. import io, solvers  # noqa: F401  (what every task imports)

    gc.collect()
    gc.freeze()


#: Methods whose parameters take ``backend=`` (see :func:`solve_many`).
WORKER_NUMBA_METHODS = ("lm", "gn", "dogleg")


def solve_problem(problem: Any, index: int, method: str, options: dict) -> Any:
    """Worker task: build (when ``problem`` is callable) and solve one problem. Returns the
    :class:`~fgopt.Result`, or the :class:`FgoptError` that stopped it (never raises)."""
    from ..solvers import optimize

    try:
        graph, initial = problem() if callable(problem) else problem
        return optimize(graph, initial, method=method, **options)
    except Exception as exc:  # one problem's failure is that problem's result
        return _as_fgopt_error(exc, f"problem {index}")


def _progress_bar(total: int, enabled: bool, label: str):
    if not enabled:
        return None
    try:
        from tqdm.auto import tqdm  # a widget in Jupyter, a text bar in a terminal
    except ImportError:
        return None
    return tqdm(total=total, desc=label, unit="problem")


def run_tasks(task: Callable, items: list, *, client: Any = None, workers: int | None = None,
              progress: bool = True, label: str = "fgopt", args: tuple = ()) -> list:
    """``[task(item, i, *args) for i, item in enumerate(items)]`` on Dask, in order.

    ``task`` must not raise (it returns its error); a worker that dies is retried once by Dask,
    then its slot holds an :class:`FgoptError` saying so.
    """
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        warnings.warn(f"dask.distributed is not installed: solving {len(items)} problems serially "
                      f"in this process ({INSTALL_HINT} runs them in parallel)", stacklevel=3)
        bar = _progress_bar(len(items), progress, label)
        out = []
        for i, item in enumerate(items):
            out.append(task(item, i, *args))
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
        return out

    own_cluster = client is None
    cluster = None
    if own_cluster:
        check_main_guard(label)
        cluster = local_cluster(workers)
        client = Client(cluster)
    futures: list = []
    try:
        futures = [client.submit(task, item, i, *args, pure=False, retries=1,
                                 key=f"{label}-{i}-{time.monotonic_ns()}")
                   for i, item in enumerate(items)]
        slot = {f.key: i for i, f in enumerate(futures)}
        out: list = [None] * len(items)
        bar = _progress_bar(len(items), progress, label)
        for fut in as_completed(futures):
            i = slot[fut.key]
            if fut.status == "finished":
                out[i] = fut.result()
            else:  # the task itself never raises: a dead worker (KilledWorker) or a lost task
                exc = fut.exception()
                out[i] = FgoptError(f"problem {i}: its worker died and the retry failed too "
                                    f"({type(exc).__name__}: {exc})")
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
        return out
    except BaseException:
        for f in futures:  # Ctrl-C or a scheduler failure: nothing runs on, nothing partial
            f.cancel()
        raise
    finally:
        if own_cluster:
            client.close()
            cluster.close()


def solve_many(problems: Iterable[Any], *, method: str = "lm", client: Any = None,
               workers: int | None = None, progress: bool = True, **options: Any) -> list:
    """Solve many independent problems, in parallel on Dask.

    Args:
        problems: ``(graph, initial)`` pairs, or zero-argument callables returning one (built on
            the worker, so large problems are never shipped).
        method: as :func:`fgopt.optimize`; ``options`` are passed to it too.
        client: a :class:`dask.distributed.Client` (any cluster). Default: start a
            ``LocalCluster`` with one single-threaded worker process per core (``workers=``),
            and close it afterwards.
        progress: a progress bar over problems (``tqdm``: a widget in Jupyter).

    Workers are long-lived and solve many problems, so LM, Gauss-Newton and Dogleg run on the
    numba backend unless ``backend=`` says otherwise: numba's start-up is paid once per worker,
    and each result equals an in-process numba solve bit for bit (``backend="auto"`` in a fresh
    worker would pick the NumPy backend, whose sums round differently in the last digit).

    Returns:
        One entry per problem, in order: its :class:`~fgopt.Result`, or the
        :class:`~fgopt.FgoptError` that stopped it (the other problems still finish).

    Example:

    >>> def problem():
    ...     s = fgopt.datasets.manhattan_2d(num_poses=50, seed=0)
    ...     return s.graph, s.initial
    ...
    >>> results = fgopt.solve_many([problem, problem], workers=1, progress=False)  # doctest: +SKIP
    >>> [r.success for r in results]  # doctest: +SKIP
    """
    items = list(problems)
    from ..solvers import _METHODS

    if method not in _METHODS:  # before any worker starts
        raise FgoptError(f"solve_many: unknown method {method!r}: choose one of "
                         f"{', '.join(_METHODS)}")
    for i, item in enumerate(items):
        if not callable(item) and not (isinstance(item, (tuple, list)) and len(item) == 2):
            raise FgoptError(f"solve_many: problem {i} must be a (graph, initial) pair or a "
                             f"zero-argument callable returning one, got {type(item).__name__}")
    if method in WORKER_NUMBA_METHODS and "backend" not in options:
        options = {**options, "backend": "numba"}
    return run_tasks(solve_problem, items, client=client, workers=workers, progress=progress,
                     label="solve_many", args=(method, options))
