"""Small problems in one compiled call: a dense LM driver per set of kernels.

On a problem of a few dozen variables the general path's fixed costs dominate: dozens of
NumPy calls of 1-5 us to set up the sparse structure and ordering, the solver's analysis, and
per iteration the Python around kernels that take a few microseconds (a 2-pose graph took
0.69 ms where GTSAM takes 0.075). :func:`optimize_small` skips all of it for problems of
tangent dimension at most :data:`SMALL_DENSE_SIZE` (or up to :data:`SMALL_MAX_SIZE` when H's
envelope keeps the work within :data:`SMALL_MAX_WORK`) whose kernels have a
:class:`~fgopt.factors.kernel.CompiledCall`: one generated driver per *set of kernels* (not per
structure) takes the problem's layout as arrays, linearizes
every batch with the kernels' own numba functions into a dense H (smart factors add their Schur
complements themselves: a ``hessian`` :class:`~fgopt.factors.kernel.CompiledCall`) and runs
:class:`~fgopt.solvers.lm.LevenbergMarquardt`'s iteration (same damping, gain ratio, lambda
rules and stopping tests, from the same :func:`~fgopt.solvers.lm.auto_policy`) with a dense
Cholesky. Its result is the general path's up to rounding; iteration records carry no wall time
(``IterationRecord.time`` is NaN: the loop runs compiled).

``LevenbergMarquardt.optimize`` takes this path by itself when the problem qualifies and the
run needs nothing only the general path gives (a callback, ``verbose``, a chosen
``linear_solver``, robust losses, Python factors or manifolds, the NumPy backend of a process
that has not loaded numba). A driver is generated and compiled once per machine and set of
kernels (14-16 s measured), in the foreground with a one-line notice, once the process has spent
about that long on the general path for its problems (:data:`COMPILE_AFTER_SECONDS`); then it is
loaded from fgopt's cache. A file's tiny
graph (a reader's batches over one bulk block of values) goes to its driver without a compiled
:class:`~fgopt.problem.Problem` at all: :func:`optimize_file` (:mod:`._file`).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..._jit import numpy_budget_left
from ...manifolds.base import is_vector_kind
from ...manifolds.lie import group_id
from ...problem import State
from .._lm_loop import MESSAGES, loop_params
from ..diagnostics import clamp_hits, warn_clamps
from ..result import Result, compiled_result
from . import _common, _driver

#: Largest tangent dimension the driver takes (its dense H, a damped copy and a Cholesky factor
#: are ``N x N`` each) ...
SMALL_MAX_SIZE = 400
#: ... if its Cholesky's work (:func:`envelope_work`) plus ``3 N^2`` (the per-iteration passes
#: over H's rows) is within this: the envelope Cholesky skips what lies before each row's first
#: nonzero, but from some size on the general path's sparse factorization wins. Set from 5 LM
#: iterations on the first 70-130 poses of ``manhattan_2d(400)`` and pose3example-grid, driver
#: vs general path in one process (ad-hoc runs): 70 poses (N 210, work 83k + 132k) 0.52-0.56x
#: the general path's time, pose3example-grid (162, 122k + 79k) 0.67-0.73x, 80 poses (240,
#: 168k + 173k) 0.75x, 100 poses (300, 100k + 270k) 0.8-1.3x, 90 poses (270, 178k + 219k)
#: 1.4x, 130 poses (390, 836k + 456k) 1.35-1.56x. Problems up to :data:`SMALL_DENSE_SIZE` are taken without
#: computing it (their dense work is below).
SMALL_MAX_WORK = 350_000
SMALL_DENSE_SIZE = 60

#: Counters (tests): drivers ``generated`` (source written and compiled) or ``loaded``.
STATS = {"generated": 0, "loaded": 0, "solves": 0}


def qualifies(problem: Any, params: Any) -> bool:
    """Whether :func:`optimize_small` can solve ``problem`` under LM ``params``."""
    if problem.backend != "numba" or (numpy_budget_left() and params.backend != "numba"):
        return False  # a process still on NumPy twins for small batches (fgopt._jit)
    if (problem._slow or len(problem._slow_vars)
            or getattr(params, "verbose", False) or params.linear_solver != "auto"
            or problem.size > SMALL_MAX_SIZE or problem.threads != 1):
        return False
    for b in problem.batches:
        call = b.kernel.compiled_call
        if call is None or b.source.loss_code != 0:
            return False
        if call.hessian and not (b.unit and len({k.storage_dim for k in b.kernel.arg_kinds}) == 1):
            return False  # the kernel's own J^T J assumes both (CompiledCall)
    return _kind_tables(problem.kinds)[3] and (
        problem.size <= SMALL_DENSE_SIZE
        or envelope_work(problem) + 3.0 * problem.size ** 2 <= SMALL_MAX_WORK)


def envelope_work(problem: Any) -> float:
    """Multiply-adds of the driver's envelope Cholesky on ``problem``'s H: ``sum_i w_i^2 / 2``
    with ``w_i`` the width of row ``i`` from its first column a factor can fill (the driver's
    own envelope, :func:`._common.envelope_of` / :func:`._common.widen_envelope`, with tangents
    in variable order as it lays them out; a dense H gives ``N^3 / 6``)."""
    dims = problem.var_dim
    toff = np.zeros(len(dims) + 1, dtype=np.int64)
    np.cumsum(dims, out=toff[1:])
    first = _common.envelope_of(toff[:-1], dims, int(toff[-1]))
    for b in problem.batches:
        _common.widen_envelope(first, toff[b.var_idx], dims[b.var_idx])
    width = np.arange(1, toff[-1] + 1) - first
    return 0.5 * float(width @ width)


#: Seconds a process spends on the general path solving problems a set of kernels' driver could
#: take, before it compiles that driver (once per machine; about what the compile takes: 14-16 s
#: measured). Rent-or-buy: a script that solves a few small problems never waits for it, a loop
#: of many small solves pays at most twice what knowing the future would have cost. A driver
#: already in fgopt's cache is used at once; ``FGOPT_SMALL_COMPILE=1`` compiles at first sight.
COMPILE_AFTER_SECONDS = 15.0
COMPILE_IN_FOREGROUND = os.environ.get("FGOPT_SMALL_COMPILE", "0") == "1"


class _Plan:
    """What a set of kernels needs, found once per process: its driver, the slot of each kernel
    (by signature, so one driver serves any order of batches)."""

    def __init__(self, kernels: list):
        self.kernels = kernels  # kept: the plan is found by their ids
        sigs = [_driver.signature(k) for k in kernels]
        order = sorted(range(len(kernels)), key=lambda j: repr(sigs[j]))
        self.slot_of = {id(kernels[j]): s for s, j in enumerate(order)}
        self.signatures = tuple(sigs[j] for j in order)
        self.names = tuple(kernels[j].name for j in order)
        self.residual_dims = tuple(kernels[j].residual_dim for j in order)
        self.key = _driver.module_key(self.signatures)
        self.name = f"small_{len(sigs)}k"
        #: Whether some kernel clamps a function's argument (else no clamp check after a solve)
        self.clamps = any(k.clamp_arguments is not None and len(k.clamps) for k in kernels)
        self.module: Any = None
        self.compiled = False  # machine code known to be in numba's cache (the marker exists)
        #: Seconds this process spent on the general path on problems this driver could take.
        self.general_seconds = 0.0

    def marker(self) -> Path:
        from ...symbolic import cache as _cache

        return _cache.module_path(self.name, self.key).with_suffix(".ready")

    def ready(self) -> bool:
        """Whether the driver runs now: loaded, known to be in numba's cache (its marker), or
        worth compiling here (:data:`COMPILE_AFTER_SECONDS`, :data:`COMPILE_IN_FOREGROUND`)."""
        if self.module is not None:
            return True
        from ...symbolic import cache as _cache

        try:
            self.compiled = self.compiled or self.marker().exists()
        except OSError:
            return False
        buy = COMPILE_IN_FOREGROUND or self.general_seconds >= COMPILE_AFTER_SECONDS
        if not (self.compiled or buy):
            return False
        m = _cache.load(self.name, self.key, required=_driver.REQUIRED)
        if m is not None:
            STATS["loaded"] += 1
        elif buy:
            m = _cache.store(self.name, self.key,
                             _driver.module_source(self.signatures, self.names))
            STATS["generated"] += 1
        else:
            return False
        if not self.compiled:
            import sys

            print(f"fgopt: compiling the small-problem LM driver for {', '.join(self.names)} "
                  "(once per machine, ~15 s)", file=sys.stderr, flush=True)
        self.module = m
        return True

    def mark_compiled(self) -> None:
        if not self.compiled:
            try:
                self.marker().touch()
            except OSError:
                pass
            self.compiled = True


_PLANS: dict[tuple, _Plan] = {}


def _plan(batches: list) -> _Plan:
    """The plan of the kernels of ``batches`` (a problem's or a graph's)."""
    seen = tuple([id(b.kernel) for b in batches])  # (the batches' order: a shortcut)
    plan = _PLANS.get(seen)
    if plan is None:
        kernels = list({id(b.kernel): b.kernel for b in batches}.values())
        ids = tuple(sorted(id(k) for k in kernels))  # any order of batches: one plan
        plan = _PLANS.get(ids)
        if plan is None:
            plan = _PLANS[ids] = _Plan(kernels)
        _PLANS[seen] = plan
    return plan


def _inputs(problem: Any, plan: _Plan) -> tuple:
    """The driver's ``problem`` argument (see :mod:`._driver`): the variables' numbers, kinds,
    rows and dims, the kinds' storage dims and group ids, and one ``(var_idx, consts, R)`` per
    kernel."""
    per_kind = _kind_tables(problem.kinds)
    per_slot: list[list] = [[] for _ in plan.names]
    for b in problem.batches:
        per_slot[plan.slot_of[id(b.kernel)]].append(
            (b.var_idx, b.source.constants, None if b.unit else b.sqrt_info))
    return (_numbers(problem.var_kind.shape[0]), problem.var_kind, problem.var_row,
            problem.var_dim, per_kind[1], per_kind[2],
            tuple([_slot(bs, plan.residual_dims[s]) for s, bs in enumerate(per_slot)]))


#: ``arange(V)`` per ``V``: the "keys" of a compiled problem's variables, numbered by themselves
#: (its factors' variable indices go in as their keys; read-only for the driver)
_NUMBERS: dict[int, np.ndarray] = {}


def _numbers(V: int) -> np.ndarray:
    a = _NUMBERS.get(V)
    if a is None:
        if len(_NUMBERS) > 256:
            _NUMBERS.clear()
        a = _NUMBERS[V] = np.arange(V, dtype=np.int64)
    return a


def _slot(parts: list, r: int) -> tuple:
    """One kernel's ``(keys, consts, R)`` from its batches' ``(keys, consts, R or None)``
    (None: unit noise; keys: variable indices or a file's keys, see :mod:`._driver`)."""
    if len(parts) == 1:
        var_idx, consts, R = parts[0]
        return var_idx, consts, _NO_R[r] if R is None else R
    # one kernel in several batches (a reader's and factors added one by one)
    return (np.concatenate([v for v, _, _ in parts]), np.concatenate([c for _, c, _ in parts]),
            _NO_R[r] if all(R is None for _, _, R in parts) else np.concatenate(
                [np.broadcast_to(_NO_EYE[r] if R is None else R, (v.shape[0], r, r))
                 for v, _, R in parts]))


#: Per tuple of kinds (by id): the kinds (kept, so the ids stay theirs), their storage dims and
#: Lie group ids (the per-kind half of :func:`_inputs`), whether the driver can retract them all
#: (Lie groups and vectors), and LM's problem class when the kinds alone decide it (else None:
#: Lie groups mixed with vectors, see :func:`~fgopt.solvers.lm.problem_class_for`).
_KIND_TABLES: dict[tuple, tuple] = {}


def _kind_tables(kinds: list) -> tuple:
    ids = tuple(map(id, kinds))
    t = _KIND_TABLES.get(ids)
    if t is None:
        gids = [group_id(k) for k in kinds]
        t = _KIND_TABLES[ids] = (
            list(kinds), np.array([k.storage_dim for k in kinds], dtype=np.int64),
            np.array([-1 if g is None else g for g in gids], dtype=np.int64),
            all(g is not None or is_vector_kind(k) for g, k in zip(gids, kinds)),
            None)
        vectors = [is_vector_kind(k) for k in kinds]
        if all(vectors) or not any(vectors):
            from ..lm import problem_class_for

            t = _KIND_TABLES[ids] = t[:4] + (problem_class_for(kinds, False, None),)
    return t


class _NoR(dict):
    """``(0, r, r)`` arrays: the driver's "unit noise" square-root information."""

    def __missing__(self, r: int) -> np.ndarray:
        self[r] = np.zeros((0, r, r))
        return self[r]


_NO_R = _NoR()


class _Eye(dict):
    """``(1, r, r)`` identities: a unit-noise batch's square-root information among others."""

    def __missing__(self, r: int) -> np.ndarray:
        self[r] = np.eye(r)[None]
        return self[r]


_NO_EYE = _Eye()


#: The driver's parameter array per (LMParams by id, problem class): the params are frozen; the
#: entry keeps them, so the id stays theirs.
_PRMS: dict[tuple, tuple] = {}



_lm_module: Any = None  # fgopt.solvers.lm, once optimize_small has run


def charge_general(problem: Any, seconds: float) -> None:
    """Count ``seconds`` of a general-path solve of ``problem`` (one the driver could take)
    towards compiling its driver (:data:`COMPILE_AFTER_SECONDS`)."""
    _plan(problem.batches).general_seconds += seconds


def optimize_small(problem: Any, params: Any, t0: float, start: State | None = None
                   ) -> Result | None:
    """LM on ``problem`` (a :class:`~fgopt.problem.Problem`, structure not needed) in one call of
    its kernel set's driver, from its initial values or ``start``. ``None``: the driver is not
    compiled yet (see :data:`COMPILE_AFTER_SECONDS`), or the initial linearization is not
    finite (the general path then names the factor). ``t0``: when the solve started
    (``perf_counter``)."""
    global _lm_module
    if _lm_module is None:
        from .. import lm as _lm_module
    plan = _plan(problem.batches)
    if not plan.ready():
        return None
    inputs = _inputs(problem, plan)
    cls = _kind_tables(problem.kinds)[4] or _lm_module.problem_class_for(
        problem.kinds, False, lambda: problem.ensure_structure().pattern)
    storages = problem._initial_storages if start is None else start.storages
    # (the driver writes the final storage into x0: a copy)
    x0 = np.concatenate([s.reshape(-1) for s in storages]) if len(storages) > 1 else \
        storages[0].reshape(-1).copy()
    out = _run_driver(plan, x0, inputs, cls, params, t0, problem.size)
    if out is None:
        return None
    x, result = out
    state = State([x.reshape(storages[0].shape)] if len(storages) == 1 else _split(x, storages),
                  {})
    clamps, num_clamped = clamp_hits(problem, state) if plan.clamps else ((), 0)
    warn_clamps(clamps, num_clamped)
    result.problem, result.state = problem, state
    result.unused_keys, result.clamps, result.num_clamped = (
        tuple(problem.unused_keys), tuple(clamps), num_clamped)
    result.timing["total"] = time.perf_counter() - t0
    return result


def _params_array(p: Any, cls: str) -> tuple[np.ndarray, float]:
    """The driver's ``prm`` array for LM params ``p`` on a problem of class ``cls``
    (:func:`~fgopt.solvers._lm_loop.loop_params`, the policy from
    :func:`~fgopt.solvers.lm.auto_policy`) and the relative tolerance it holds: made once per
    params object and class, kept."""
    prm = _PRMS.get((id(p), cls))
    if prm is not None and prm[0] is p:
        return prm[1], prm[2]
    if len(_PRMS) > 64:
        _PRMS.clear()
    global _lm_module
    if _lm_module is None:  # (lm imports this module)
        from .. import lm as _lm_module
    identity, by_factor = _lm_module.auto_policy(cls, p)
    prm, rel_tol = loop_params(p, identity, by_factor)
    prm = _PRMS[(id(p), cls)] = (p, np.array(prm), rel_tol)
    return prm[1], rel_tol


def _run_driver(plan: _Plan, x0: np.ndarray, inputs: tuple, cls: str, p: Any,
                t0: float, n: int) -> tuple[np.ndarray, Result] | None:
    """One call of ``plan``'s driver on a problem of tangent dimension ``n``: ``x0`` (the
    caller's scratch copy of the initial storage), now the final storage, and a
    :class:`Result` without its problem, state, unused keys and clamps (the caller's); None
    when the initial linearization is not finite or the keys do not number the variables."""
    prm, rel_tol = _params_array(p, cls)
    ni, nf = plan.module.arena_sizes(inputs[0].shape[0], inputs[4].shape[0], n, x0.shape[0],
                                     [s[0].shape[0] for s in inputs[6]])
    iw, fw = arenas(ni, nf)
    hist = np.empty((max(p.max_iterations, 1), 8))
    t1 = time.perf_counter()
    out = plan.module._solve(x0, inputs, prm, iw, fw, hist)
    t2 = time.perf_counter()
    result = _driver_result(plan, out, hist, p, rel_tol, t0, t1, t2)
    return None if result is None else (x0, result)


def arenas(ints: int, floats: int) -> tuple[np.ndarray, np.ndarray]:
    """A driver call's scratch ``iw`` and ``fw`` (contents undefined; sizes from its module's
    ``arena_sizes``, see :mod:`._driver`)."""
    return np.empty(ints, dtype=np.int64), np.empty(floats)


_pc = time.perf_counter


def _driver_result(plan: _Plan, out: tuple, hist: np.ndarray, p: Any, rel_tol: float,
                   t0: float, t1: float, t2: float, values: Any = None, state: Any = None,
                   problem: Any = None) -> Result | None:
    """The :class:`Result` of a driver call that returned ``out`` and wrote ``hist`` (started
    at ``t0``, the driver called at ``t1``, returned at ``t2``; total time to now), or None for
    status -1 / -2 (see :func:`_run_driver`)."""
    status, msg, val, its, cost, init = out
    if not plan.compiled:
        plan.mark_compiled()
    if status < 0:  # -1: not finite at the start; -2: keys that do not number the variables
        return None
    STATS["solves"] += 1
    return compiled_result(hist, its, status, MESSAGES[msg](val, p, rel_tol), cost, init,
                           {"setup": t1 - t0, "lm": t2 - t1, "total": _pc() - t0}, "lm",
                           "dense cholesky (small-problem driver)", {"backend": "numba"},
                           values, state, problem)


def _split(x: np.ndarray, storages: list) -> list[np.ndarray]:
    """``x`` cut into per-kind storage arrays shaped as ``storages``."""
    out, o = [], 0
    for s in storages:
        out.append(x[o:o + s.size].reshape(s.shape))
        o += s.size
    return out


from ._file import optimize_file as optimize_file  # (last: it reads the names above)
