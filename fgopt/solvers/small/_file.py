"""The small-problem driver's file lane: a file's tiny graph solved without a Problem.

What a reader makes (batches only, the values one bulk block of one kind) goes to the kernel set's
driver (:mod:`fgopt.solvers.small`) directly: the driver numbers the variables itself (the block's
rows, as :class:`~fgopt.problem.Problem` numbers them), and ``Result.problem`` is compiled only
when first read. On a few-pose graph the compilation it skips was ~15 us, a third of the solve's
Python; the result is the compiled problem's, bit for bit. A graph solved again reuses the driver
inputs built for it while its batches, their arrays and the values block are the same objects
(:class:`_Inputs`, checked every solve), with the driver's scratch and its compiled entry point
(no typing of the arguments).
"""

from __future__ import annotations

import time
import weakref
from typing import Any

import numpy as np

from ..._jit import numpy_budget_left
from ...problem import SMALL_COLLECT_MAX, State, _kind_of_rows
from ...variables import Variables, _Rows
from .. import small as _pkg  # (its names read at call time: tests patch the sizes)
from ..result import Deferred, Result


def optimize_file(graph: Any, initial: Any, params: Any, t0: float) -> Result | None:
    """:func:`~fgopt.solvers.small.optimize_small` of what a file reader makes, without compiling a
    :class:`~fgopt.problem.Problem` first: a graph of batches only and values that are one bulk
    block of one kind with strictly ascending keys, every one of them used, and a tangent
    dimension of at most :data:`SMALL_DENSE_SIZE`. The variables are the block's rows in order
    (what ``Problem`` numbers them), each factor's found by the driver itself; the result's
    ``problem`` is compiled when first read (from the graph's batches and the values as they
    were). ``None`` for anything else (the caller compiles the problem and takes the usual
    path, which also names any error): a Python factor, robust loss, another kind, a missing,
    repeated or unused key, a driver not compiled yet, a non-finite start.

    Same iterations and result as :func:`~fgopt.solvers.small.optimize_small` on the compiled
    problem, bit for bit; it saves that compilation's ~15 us on a few-pose graph (a third of its
    Python)."""
    batches, pending = graph.batches, initial._pending
    if graph.factors or initial._dict or len(pending) != 1 or not batches:
        return None
    ok = _PARAMS_OK.get(id(params))
    if ok is None or ok[0] is not params:
        ok = _params_ok(params)
    if not (ok[1] or (ok[2] and not numpy_budget_left())):
        return None  # (verbose, a linear solver chosen...; or still on NumPy twins)
    blk = pending[0]
    memo = _MEMOS.get(id(graph))
    if memo is None or not memo.holds(graph, blk, batches):
        memo = _prepare(graph, blk, batches)
        if memo is None:
            return None
    lane = memo.lane
    plan, n = lane.plan, memo.dims[1]
    if n > _pkg.SMALL_DENSE_SIZE or n > _pkg.SMALL_MAX_SIZE or not plan.ready():
        return None  # (too large for the driver; or warming it up: the usual path's)
    rows = blk.rows
    # (the driver's, written in place: what a Problem holds as its initial storage; float64
    # C-contiguous whatever the rows are, as the kept entry point reads it)
    x0 = rows.astype(np.float64, order="C").reshape(-1)
    prm, rel_tol = _pkg._params_array(params, lane.tables[4])
    # (the driver numbers the variables: each factor's keys among the block's, status -2 for a
    # missing, repeated or unused key, or keys not ascending)
    # (list.pop is one step: a solve of this graph in another thread cannot take the same
    # scratch, it makes its own)
    try:
        work = memo.work.pop()
    except IndexError:
        work = memo.sizes
        if work is None:  # (the driver's own function: known once the plan is ready)
            work = memo.sizes = plan.module.arena_sizes(
                blk.keys.shape[0], 1, n, x0.shape[0], [s[0].shape[0] for s in memo.inputs[6]])
        work = _pkg.arenas(*work)
    hist = np.empty((max(params.max_iterations, 1), 8))  # (kept by the result)
    solve = memo.entry
    t1 = _pc()
    out = (solve or plan.module._solve)(x0, memo.inputs, prm, work[0], work[1], hist)
    t2 = _pc()
    if not memo.work:
        memo.work.append(work)  # (scratch only: the next solve may reuse it)
    if solve is None and memo.graph is not None:  # (kept: the next solve calls it directly)
        memo.entry = _entry_point(plan.module._solve, (x0, memo.inputs, prm, *work, hist))
    if out[0] < 0:
        return _pkg._driver_result(plan, out, hist, params, rel_tol, t0, t1, t2)  # (None)
    x = x0.reshape(rows.shape)
    final = x.copy()  # the values' rows (read-only), apart from the state's
    final.setflags(write=False)
    state = _new(State)  # (State([x], {}) without the dataclass' __init__: ~0.2 us)
    state.storages, state.objects = [x], {}
    return _pkg._driver_result(plan, out, hist, params, rel_tol, t0, t1, t2,
                               Variables._of_rows(_Rows(blk.keys, lane.kind, final)), state,
                               Deferred(_compiled_problem, memo.dims, (list(batches), blk, params)))


_pc, _new = time.perf_counter, object.__new__


class _Inputs:
    """A graph's driver inputs as :func:`_prepare` built them from its batches and values block,
    with what they were built from: reused by the next solve of the same graph while every one
    of those is the same object (:meth:`holds`: ~0.3 us a batch instead of ~1 us to rebuild).
    Only inputs that are the batches' own arrays are kept (no copies of read-only keys or
    non-contiguous R), and those go to the driver as the entry's own views of them: in-place
    changes of the data reach it, but no one else can change their shapes or types.
    ``sizes``: the driver's arena sizes (:func:`~fgopt.solvers.small.arenas`), known at the first
    solve; ``work``: the arenas themselves (scratch, at most one pair), reused by the next
    solve that takes them (one that runs while another holds them makes its own); ``entry``:
    the driver's compiled entry point for these inputs' types (:func:`_entry_point`), once a
    solve has run."""

    __slots__ = ("dims", "entry", "graph", "inputs", "lane", "parts", "block", "keys", "sizes",
                 "work")

    def holds(self, graph: Any, blk: Any, batches: list) -> bool:
        if (self.graph() is not graph or blk is not self.block or blk.keys is not self.keys
                or len(batches) != len(self.parts)):
            return False
        for b, (b0, kernel, keys, consts, R) in zip(batches, self.parts):
            if (b is not b0 or b.kernel is not kernel or b.keys is not keys
                    or b.constants is not consts or b.sqrt_information is not R
                    or b.loss_code != 0):
                return False
        return True


#: Per graph (by id, the entry holding a weak reference to it): its last :class:`_Inputs`.
_MEMOS: dict[int, _Inputs] = {}


def _prepare(graph: Any, blk: Any, batches: list) -> _Inputs | None:
    """The driver's inputs for ``graph``'s batches and values block ``blk`` (kept in
    :data:`_MEMOS` when they are the batches' own arrays), or None where the lane does not
    apply."""
    _MEMOS.pop(id(graph), None)  # (an earlier entry for this graph no longer holds)
    V = blk.keys.shape[0]
    size = V
    ids = [id(blk.kind)]
    for b in batches:
        size += b.keys.shape[0]
        ids.append(id(b.kernel))
    if size > SMALL_COLLECT_MAX:
        return None  # (a Problem would number the variables by its general collection)
    lane = _LANES.get(tuple(ids))
    if lane is None:
        lane = _lane(blk, batches, tuple(ids))
    if lane.plan is None:
        return None
    slots: list = []
    residuals = 0
    own = blk.keys.flags.writeable
    for b, (r, hessian) in zip(batches, lane.per_batch):
        R = b.sqrt_information
        n = b.keys.shape[0]
        if b.loss_code != 0 or (hessian and R is not None) or n == 0:
            return None  # (a hessian call's own J^T J assumes unit noise: CompiledCall)
        residuals += n * r
        keys, Rc = _writeable(b.keys), _pkg._NO_R[r] if R is None else np.ascontiguousarray(R)
        own = own and keys is b.keys and (R is None or Rc is R)
        slots.append((keys, b.constants, Rc))
    if lane.merge is not None:  # (one kernel in several batches: one slot of them all)
        own = False
        slots = [_pkg._slot([(k, c, None if R.shape[0] == 0 else R) for k, c, R in
                             (slots[i] for i in bs)], r) for bs, r in lane.merge]
    tables = lane.tables
    memo = _Inputs()
    memo.lane, memo.dims, memo.sizes, memo.work = lane, (residuals, V * lane.dim), None, []
    memo.graph = memo.entry = None
    block_keys = _writeable(blk.keys)
    if own:  # (kept: the driver gets views of the arrays, whose types no one else can change)
        block_keys = block_keys.view()
        slots = [(k.view(), c.view(), R if R.shape[0] == 0 else R.view()) for k, c, R in slots]
    memo.inputs = (block_keys, *_one_kind_tables(V, lane.dim), tables[1], tables[2],
                   tuple(slots))
    if own:
        if len(_MEMOS) > 64:
            _MEMOS.clear()
        key = id(graph)
        memo.graph = weakref.ref(graph, lambda _, key=key: _MEMOS.pop(key, None))
        memo.block, memo.keys = blk, blk.keys
        memo.parts = [(b, b.kernel, b.keys, b.constants, b.sqrt_information) for b in batches]
        _MEMOS[key] = memo
    return memo


def _entry_point(dispatcher: Any, args: tuple) -> Any:
    """The machine code ``dispatcher`` runs for ``args`` (numba's compiled wrapper): called
    directly, it skips the dispatcher's typing of the arguments (~0.7 us of a 2-pose solve's
    ~11). Only for arguments whose types cannot change: it reads each as the type it was
    compiled for (a kept :class:`_Inputs` holds its own views of the arrays, and the rest are
    the lane's). None when numba has no such entry."""
    try:
        sig = tuple(dispatcher.typeof_pyval(a) for a in args)
        return dispatcher.overloads[sig].entry_point
    except (AttributeError, KeyError, TypeError, ValueError):
        return None


def _writeable(keys: np.ndarray) -> np.ndarray:
    """``keys`` (int64, C-contiguous) as the driver was compiled for them: a read-only array
    would be another argument type for numba (a new compilation of ``_solve``), so it is copied."""
    return keys if keys.flags.writeable else keys.copy()


#: Per LM params object (by id; the params are frozen and kept in the entry): ``(params, the
#: lane may run, it may once the process's twin budget is spent)``.
_PARAMS_OK: dict[int, tuple] = {}


def _params_ok(p: Any) -> tuple:
    if len(_PARAMS_OK) > 64:
        _PARAMS_OK.clear()
    usual_only = p.verbose or p.linear_solver != "auto" or p.threads != 1
    ok = _PARAMS_OK[id(p)] = (p, not usual_only and p.backend == "numba",
                              not usual_only and p.backend == "auto")
    return ok


class _Lane:
    """What :func:`optimize_file` knows of a value kind and a graph's kernels (in batch order):
    the kind, its tables, the kernels' driver plan (None: the lane never applies -- kinds differ,
    a kernel without a compiled call or one that clamps...) and per batch its residual
    dimension and whether the kernel adds its own ``J^T J``, ``merge``: None when each batch is
    its own slot in slot order, else per slot its batches' indices and residual dimension;
    ``keep``: the objects the cache key's ids name."""

    __slots__ = ("dim", "keep", "kind", "merge", "per_batch", "plan", "tables")

    def __init__(self, blk: Any, batches: list):
        self.keep = (blk.kind, [b.kernel for b in batches])
        self.plan = None
        kind = _kind_of_rows(blk)
        if kind is None or kind.wrap is None:
            return
        tables = _pkg._kind_tables([kind])
        kernels = self.keep[1]
        if not (tables[3] and tables[4] is not None
                and all(k.compiled_call is not None and all(a is kind for a in k.arg_kinds)
                        for k in kernels)):
            return
        plan = _pkg._plan(batches)
        if plan.clamps:  # (clamp reports: the usual path's)
            return
        self.kind, self.dim, self.tables, self.plan = kind, kind.dim, tables, plan
        self.per_batch = tuple((k.residual_dim, k.compiled_call.hessian) for k in kernels)
        slot = [plan.slot_of[id(k)] for k in kernels]
        # batches in slot order, one each (a reader's graph), or per slot its batches' indices
        self.merge = None if slot == list(range(len(plan.names))) else tuple(
            (tuple(i for i, s in enumerate(slot) if s == j), r)
            for j, r in enumerate(plan.residual_dims))


#: Per (value kind, kernels in batch order) by id: a :class:`_Lane`.
_LANES: dict[tuple, _Lane] = {}


def _lane(blk: Any, batches: list, ids: tuple) -> _Lane:
    if len(_LANES) > 256:
        _LANES.clear()
    lane = _LANES[ids] = _Lane(blk, batches)
    return lane


def _compiled_problem(batches: list, block: Any, params: Any) -> Any:
    """The :class:`~fgopt.problem.Problem` ``LevenbergMarquardt.optimize`` would have compiled
    from a graph of ``batches`` and values of one bulk ``block`` (:func:`optimize_file`'s
    deferred ``Result.problem``; bulk blocks are read-only, so this is the block as solved)."""
    from ...graph import FactorGraph
    from .._run import compile_problem

    graph = FactorGraph()
    graph._batches = batches
    initial = Variables()
    initial._pending.append(block)
    return compile_problem(graph, initial, params, params.linear_solver, build_structure=False)


#: ``(var_kind, var_row, var_dim)`` of ``V`` variables of one kind of tangent dimension ``d``
#: (read-only for the driver: shared by every solve of that size)
_ONE_KIND: dict[tuple, tuple] = {}


def _one_kind_tables(V: int, d: int) -> tuple:
    t = _ONE_KIND.get((V, d))
    if t is None:
        if len(_ONE_KIND) > 256:
            _ONE_KIND.clear()
        dims = np.empty(V, dtype=np.int64)
        dims.fill(d)
        t = _ONE_KIND[(V, d)] = (np.zeros(V, dtype=np.int64), _pkg._numbers(V), dims)
    return t
