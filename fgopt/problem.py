"""The compiled problem: a graph and its variables laid out for fast, repeated linearization.

``Problem(graph, values)`` runs once per optimization (ARCHITECTURE.md, "structure once"):

1. variables of each batch kind live in one ``(n, storage_dim)`` array; duck-typed manifolds
   stay Python objects (the slow path);
2. kernel factors are grouped into batches by (kernel, robust loss); Python factors form one
   fallback list linearized one by one;
3. a fill-reducing order of the variable graph fixes each variable's tangent offset, and the
   pattern of H plus the scatter map of every factor block are computed (``structure.py``).

Each iteration then calls ``linearize`` (kernels + numba scatter into H's data array),
``retract`` (one batched kernel per manifold kind) and ``cost``. A :class:`State` holds the
variable values; the problem never mutates a state in place, so the caller's values and any
accepted iterate stay intact.
"""

from __future__ import annotations

import functools
import math
import time
from itertools import chain
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from . import _assembly as asm
from . import _jit
from . import _assembly_np as asm_np
from .batch import FactorBatch, batch_from_factors
from .errors import (EmptyProblemError, FgoptError, KeyNotFoundError,
                     ManifoldError, NonFiniteError)
from .factors.base import Factor
from .noise.models import RobustLoss, base_noise, loss_code_and_param
from .key import Key, key_str
from .manifolds.base import SCALAR_KIND, BatchKind, is_vector_kind, ops_for
from .structure import (DENSE_MAX_SIZE, HessianPattern, ba_shaped_kind, build_pattern,
                        fill_reducing_order, kinds_by_count, schur_order,
                        scatter_positions, unique_int)
from ._jit import charge_numpy, numpy_budget_left
from ._scatter_fixed import specialize as specialized_scatter
from ._structure_kernels import block_var_idx
from ._threads import PARALLEL_MIN_BATCH, linearize_batch_threaded
from .variables import _MAX_LAZY_BLOCKS, Variables, _Rows, _runs


_UNSET = object()

#: Batches up to this size are assembled by the NumPy twins (no numba import or cache load)
#: while the process's twin budget lasts; the same rule as generated kernels' NumPy twins.
NUMPY_MAX_BATCH = 1000


def _asm(n: int):
    """The assembly kernels for a batch of ``n`` instances: NumPy on the NumPy backend
    (:func:`fgopt._jit.numpy_mode`) and for small batches while the process's twin budget lasts
    (:func:`fgopt._jit.numpy_budget_left`), else numba."""
    return asm_np if _jit.numpy_only() or (n <= NUMPY_MAX_BATCH and numpy_budget_left()) \
        else asm


BACKENDS = ("auto", "numba", "numpy")

#: ``backend="auto"`` runs a problem of at most this tangent dimension on the NumPy backend when
#: numba is not in use in the process yet (and every kernel and manifold has a NumPy form): in a
#: new process, numba's import, initialization and cache loads (0.7-1 s warm; 20-60 s of
#: compilation with an empty cache) cost more than the NumPy path's slower iterations
#: (measured: README, start-up section).
NUMPY_BACKEND_MAX_SIZE = 30000

#: Problems of at most this many factors (individually added and batch rows) plus values are
#: collected in plain Python (:meth:`Problem._collect_small`), larger ones by the vectorized
#: collection (measured: a 50-pose chain 0.22 vs 0.26 ms, 100 poses even, 400 poses 1.0 vs
#: 0.8 ms; 104 factors on 5 poses 0.16 vs 0.23 ms).
SMALL_COLLECT_MAX = 160
#: Batches of at most this many rows have their kinds and repeated keys checked in Python.
_PYTHON_CHECK_ROWS = 32


def _kernel_tables(kernel: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A kernel's argument tangent dims, Jacobian column offsets and ``(1, r, r)`` identity
    (the unit noise's square-root information), made once per kernel and shared by its batches
    (read only: GNC replaces a batch's ``sqrt_info``, never writes into it)."""
    # kept in the kernel's own __dict__ (a frozen dataclass): a WeakKeyDictionary lookup costs
    # ~1 us, a tenth of a small batch's collection
    t = kernel.__dict__.get("_problem_tables")
    if t is None:
        t = kernel.__dict__["_problem_tables"] = (
            np.array([k.dim for k in kernel.arg_kinds], dtype=np.int64),
            np.array(kernel.arg_offsets, dtype=np.int64), np.eye(kernel.residual_dim)[None])
    return t


#: ``_slow_vars`` of problems without slow-path variables (shared: empty, nothing to write).
_NO_VARIABLES = np.zeros(0, dtype=np.int64)
_NO_VARIABLES.flags.writeable = False

#: Bulk blocks' kinds (by id, kept alive here) -> the kind the per-key path finds for their
#: values (a block's kind wraps its rows into the values :func:`ops_for` knows).
_ROWS_KIND: dict[int, tuple] = {}


def _kind_of_rows(blk: Any) -> BatchKind | None:
    """The kind the per-key collection finds for the values of bulk block ``blk``."""
    hit = _ROWS_KIND.get(id(blk.kind))
    if hit is None:
        if len(_ROWS_KIND) > 1000:  # kinds made on the fly: do not keep them all
            _ROWS_KIND.clear()
        x = blk.kind.wrap(blk.rows[0])
        hit = _ROWS_KIND[id(blk.kind)] = (blk.kind, ops_for(x).batch_kind(x))
    return hit[1]


class _BulkRow(NamedTuple):
    """A variable's value as a row of a bulk block of :class:`~fgopt.variables.Variables`."""

    block: Any
    row: int


def numpy_backend_supported(kernels, kinds) -> bool:
    """Whether every kernel has NumPy twins and every manifold kind a NumPy retract."""
    return (all(getattr(k, "numpy_twin", False) for k in kernels)
            and all(getattr(kd.retract, "numpy", False) for kd in kinds))


def _all_finite(a: np.ndarray) -> bool:
    """No NaN / inf in ``a``. Its sum of squares is finite iff every entry is, unless it
    overflows (entries above ~1e154: then they are checked one by one): one pass without a
    temporary mask (H of 5M BA observations is 1.1 GB), ~0.6 us on the small arrays every
    iteration of a small problem checks. ``np.vdot``, unlike ``sum`` and ``@``, raises no
    floating-point warnings on the NaN / inf it is there to find."""
    if math.isfinite(float(np.vdot(a, a))):
        return True
    return _entries_finite(a)


def _entries_finite(a: np.ndarray) -> bool:
    """:func:`_all_finite` entry by entry: numba for large arrays, NumPy in slices for small
    ones (no numba import)."""
    a = a.reshape(-1)
    if a.shape[0] <= 1 << 16 or _jit.numpy_only() or not _jit.is_numba_loaded():
        step = 1 << 16
        return all(bool(np.isfinite(a[lo:lo + step]).all()) for lo in range(0, a.shape[0], step))
    return bool(asm.all_finite(a))


def _linearization_finite(total: float, H: np.ndarray, g: np.ndarray) -> bool:
    """Whether a linearization's cost, H and g are all finite (one sum of squares each, see
    :func:`_all_finite`)."""
    if math.isfinite(total + float(np.vdot(g, g)) + float(np.vdot(H, H))):
        return True
    return math.isfinite(total) and _entries_finite(g) and _entries_finite(H)


@dataclass(eq=False)
class State:
    """Variable values during optimization: one storage array per kind + slow-path objects."""

    storages: list[np.ndarray]
    objects: dict[int, Any]


class _MadeOnRead:
    """A ``_Batch`` field made by ``make(batch)`` when first read (a data descriptor: the
    dataclass' ``__init__`` stores what it is given, ``None`` meaning "make it"). For the
    arrays only the general path reads: the small-problem driver, which takes most solves of
    small graphs, never does (~1 us a batch each)."""

    def __init__(self, make: Any):
        self.make = make

    def __set_name__(self, owner: type, name: str) -> None:
        self.slot = "_" + name

    def __get__(self, b: "_Batch | None", owner: type | None = None):
        if b is None:
            return None  # the dataclass field's default
        v = b.__dict__.get(self.slot)
        if v is None:
            v = b.__dict__[self.slot] = self.make(b)
        return v

    def __set__(self, b: "_Batch", value: Any) -> None:
        b.__dict__[self.slot] = value


@dataclass(eq=False)
class _Batch:
    kernel: Any
    source: FactorBatch
    var_idx: np.ndarray          # (n, k) variable indices
    kind_ids: tuple[int, ...]    # kind of each argument
    sqrt_info: np.ndarray        # (n, r, r) or (1, r, r) identity when unit
    unit: bool
    arg_dims: np.ndarray
    arg_local_off: np.ndarray
    toff: np.ndarray = field(default=None)  # (n, k) tangent offsets
    pos: np.ndarray = field(default=None)   # (n, k, k) scatter map (structure.scatter_positions)
    sqrt_info0: np.ndarray = field(default=None)  # the factors' own noise (before GNC weights)
    unit0: bool = True
    plan: list | None = field(default=None)  # NumPy assembly: scatter plan per slice
    fixed: dict = field(default_factory=dict)  # unit flag -> specialized scatter (or None)
    rows2d: np.ndarray | None = field(default=None)  # (n, k) rows, for kernels' scatter_hessian
    var_row: np.ndarray | None = field(default=None, repr=False)  # the problem's (for rows)
    #: per argument, the (n,) rows of its variables in their kind's storage
    rows: list[np.ndarray] = _MadeOnRead(  # type: ignore[assignment]
        lambda b: list(np.ascontiguousarray(b.var_row[b.var_idx].T)))
    #: per factor, its weight (GNC); ones
    weights: np.ndarray = _MadeOnRead(  # type: ignore[assignment]
        lambda b: np.ones(b.var_idx.shape[0]))

    def gather(self, state: State, lo: int = 0, hi: int | None = None) -> tuple:
        """Storage rows of the arguments of instances ``lo:hi`` (default: all)."""
        # np.take, not fancy indexing: 4x faster on (n, s) storages (0.09 -> 0.023 ms for 9,500
        # rows of 3), the same rows
        st = state.storages
        return tuple([st[kid].take(rows[lo:hi], axis=0)
                      for kid, rows in zip(self.kind_ids, self.rows)])

    def chunks(self, size: int):
        """``(lo, hi)`` slices of at most ``size`` instances covering the batch."""
        n = len(self.source)
        return [(lo, min(n, lo + size)) for lo in range(0, n, size)] or [(0, 0)]

    def sqrt_info_of(self, lo: int, hi: int) -> np.ndarray:
        return self.sqrt_info if self.unit else self.sqrt_info[lo:hi]


@dataclass(eq=False)
class _SlowFactor:
    factor: Factor
    var_idx: np.ndarray          # (k,)
    sqrt_info: np.ndarray        # (1, r, r)
    unit: bool
    loss_code: int
    loss_param: float
    loss_shape: float
    arg_dims: np.ndarray
    arg_local_off: np.ndarray
    toff: np.ndarray = field(default=None)
    pos: np.ndarray = field(default=None)
    sqrt_info0: np.ndarray = field(default=None)
    unit0: bool = True


class _StateView:
    """``values.at(k)`` over a State, for Python factors (materializes values on demand)."""

    def __init__(self, problem: "Problem", state: State):
        self._p, self._s, self._cache = problem, state, {}

    def at(self, k: Any) -> Any:
        try:
            return self._cache[k]
        except KeyError:
            pass
        v = self._p._var_of_key.get(k)
        if v is None:
            return self._p._extra.at(k)
        value = self._p._value_of(self._s, v)
        self._cache[k] = value
        return value

    __getitem__ = at

    def __contains__(self, k: object) -> bool:
        return k in self._p._var_of_key or k in self._p._extra


#: Batches are linearized in slices of this many factors (threads: this many per thread).
CHUNK = 1 << 14
#: Trial steps are linearized into a second H while H's data takes at most this many bytes;
#: larger problems linearize them into H itself and re-linearize after a rejected step (the
#: same numbers: memory of one H saved, one linearization more per rejection). 100k-pose 3D
#: grid: H 50 MB; 5M BA observations: 1.1 GB.
SPARE_MAX_BYTES = 32 << 20


@functools.lru_cache(maxsize=None)
def _upper_pairs(k: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(k, 1)``, made once per ``k`` (it costs ~10 us a call)."""
    return np.triu_indices(k, 1)


def replaced_values(initial: Variables, groups: Any, unused: Any = None,
                    objects: dict | None = None) -> Variables:
    """A new ``Variables`` with ``initial``'s keys in their order: those of ``groups`` (``(kind,
    keys, storage rows)`` per kind; rows on the manifold, as a retraction leaves them) and of
    ``objects`` (key -> value) replaced, the ``unused`` ones (default: every other key) copied.
    Bulk rows of ``initial`` are not turned into objects only to be overwritten (a file's
    poses: ~1 us each); the new rows are an owned read-only copy wrapped row by row, as
    ``Variables.add_rows`` does."""
    out = Variables()
    values = out._dict = dict(initial._dict)  # assignments keep its Key objects
    for blk in initial._pending:
        values.update(dict.fromkeys(map(Key, blk.keys.tolist())))
    for kind, keys, rows in groups:
        if kind.wrap is None:
            values.update(zip(keys, map(kind.from_storage, rows)))
        else:
            rows = np.array(rows, dtype=float)
            rows.flags.writeable = False
            values.update(zip(keys, kind.wrap_all(rows)))
    if objects:
        values.update(objects)
    for k in (unused if unused is not None else [k for k, x in values.items() if x is None]):
        if values[k] is None:  # not optimized: returned unchanged
            values[k] = initial.at(k)
    return out


class Problem:
    """A graph compiled against initial values; see the module docstring. The solvers build
    one per solve; it is public for code that drives its own iterations.

    >>> from fgopt.noise import Isotropic
    >>> noise, step = Isotropic.sigma(3, 0.1), fgopt.SE2.from_xytheta(1.0, 0.0, 0.0)
    >>> graph = fgopt.FactorGraph([fgopt.PriorFactor(key('x', 0), fgopt.SE2(), noise),
    ...                            fgopt.BetweenFactor(key('x', 0), key('x', 1), step, noise)])
    >>> problem = fgopt.Problem(graph, fgopt.Variables({key('x', 0): fgopt.SE2(), key('x', 1): fgopt.SE2()}))
    >>> problem.size, problem.num_variables       # tangent dimension, variables
    (6, 2)
    >>> state = problem.initial_state()
    >>> round(problem.cost(state), 9)             # 0.5 * |(1 m) / (0.1 m)|^2
    50.0
    >>> problem.values(state).at(key('x', 1)).equals(fgopt.SE2())
    True
    """

    #: Per row of the initial values' one bulk block, the variable holding it, when
    #: :meth:`_collect_small` saw the values as that block alone (else None): :meth:`values`.
    _bulk_order: list[int] | None = None
    #: Constant variables / coordinates and bounds (:mod:`fgopt.bounds`), or None.
    restrictions: Any = None
    #: Rows of scratch space after H's data and g (constant variables' blocks), or 0.
    _trash = 0

    def __init__(self, graph: Any, values: Variables, ordering: str | None = "amd",
                 build_structure: bool = True, threads: int = 1, backend: str = "auto",
                 linear_solver: Any = None, constant: Any = None, bounds: Any = None):
        """``linear_solver``: the name of the solver that will factor H, when known: with a
        Schur-complement solver (a ``"schur..."`` name, or ``"auto"`` on a BA-shaped problem) the
        eliminated variables come first in H and no fill-reducing order is computed
        (:func:`fgopt.structure.schur_order`); otherwise ``ordering`` orders H. ``backend``:
        see :meth:`choose_backend`. ``constant`` / ``bounds``: variables and coordinates held
        fixed, box bounds on vector-valued variables (:mod:`fgopt.bounds`)."""
        if not graph.factors and not any(b.keys.shape[0] for b in graph.batches):
            raise EmptyProblemError("the factor graph is empty: add factors before optimizing")
        if backend not in BACKENDS:
            raise FgoptError(f"unknown backend {backend!r}: choose 'auto', 'numba' or 'numpy'")
        self.timing = {"linearize": 0.0, "assemble": 0.0, "retract": 0.0, "cost": 0.0}
        #: Threads for linearization (1 = serial). See :mod:`fgopt._threads`.
        self.threads = max(1, int(threads))
        if not self._collect_small(graph, values):
            self._collect_variables(graph, values)
            self._collect_factors(graph)
        #: Constant variables / coordinates and bounds (:mod:`fgopt.bounds`), or None.
        self.restrictions = None
        if constant is not None or bounds is not None:
            from .bounds import Restrictions

            self.restrictions = Restrictions(self, constant, bounds) or None
        #: ``"numpy"``: kernels' NumPy twins, NumPy assembly and retracts for every batch size
        #: (no numba in the solve); ``"numba"``: numba kernels for batches above
        #: ``NUMPY_MAX_BATCH``. See :meth:`choose_backend`.
        self.backend = self.choose_backend(backend)
        self.pattern: HessianPattern | None = None
        if build_structure:
            with self.kernel_mode():
                self._build_structure(ordering or "natural", linear_solver)

    def ensure_structure(self, ordering: str | None = "amd", linear_solver: Any = None) -> Problem:
        """Build the sparse structure (ordering, H's pattern, scatter maps) if this problem was
        made without it (``build_structure=False``: the small-problem driver needs none);
        returns self."""
        if self.pattern is None:
            with self.kernel_mode():
                self._build_structure(ordering or "natural", linear_solver)
        return self

    def choose_backend(self, backend: str = "auto") -> str:
        """``backend`` resolved: ``"auto"`` is ``"numpy"`` when numba is not loaded in the
        process yet, its twin budget is not spent (``fgopt._jit``), the problem's tangent
        dimension is at most ``NUMPY_BACKEND_MAX_SIZE``, linearization is serial and every
        kernel / manifold has a NumPy form; else ``"numba"``.
        ``"numpy"`` where some kernel has no NumPy form raises."""
        if backend == "numba" or (backend == "auto" and _jit.is_numba_loaded()):
            return "numba"
        ok = numpy_backend_supported([b.kernel for b in self.batches], self.kinds)
        if backend == "numpy":
            if not ok:
                bad = [b.kernel.name for b in self.batches if not b.kernel.numpy_twin]
                raise FgoptError("backend='numpy': not every kernel or manifold of this problem "
                                 f"has a NumPy form ({', '.join(bad) or 'a manifold retract'}); "
                                 "use backend='numba'")
            return "numpy"
        if (ok and self.threads == 1 and not _jit.is_numba_loaded() and numpy_budget_left()
                and int(self.var_dim.sum()) <= NUMPY_BACKEND_MAX_SIZE):
            return "numpy"
        return "numba"

    def kernel_mode(self):
        """Context in which this problem's kernels run (:func:`fgopt._jit.numpy_mode` on the
        NumPy backend)."""
        return _jit.numpy_mode() if self.backend == "numpy" else nullcontext()

    # ----------------------------------------------------------------- compile: small graphs
    def _collect_small(self, graph: Any, values: Variables) -> bool:
        """:meth:`_collect_variables` and :meth:`_collect_factors` for what a file reader makes
        (:meth:`_collect_file`, any size, once numba is in use) and for problems of at most
        :data:`SMALL_COLLECT_MAX` factors and values, in plain Python: the vectorized collection
        costs ~60 NumPy calls of 1-5 us whatever the size (150 us on a 2-pose graph). Same
        attributes, numbering and batches. Anything unusual -- Python factors or manifolds, a
        missing key, a large bulk block -- returns False: the general collection then runs (and
        raises its errors)."""
        factors, batches, pending = graph.factors, graph.batches, values._pending
        if (not factors and not values._dict and len(pending) == 1 and batches
                and _jit.is_numba_loaded() and self._collect_file(batches, pending[0], values)):
            return True  # (compiled calls: any size)
        num_values = len(values._dict)
        for blk in pending:
            num_values += blk.keys.shape[0]
        size = len(factors) + num_values
        for b in batches:
            size += b.keys.shape[0]
        if size > SMALL_COLLECT_MAX:
            return False
        var_of: dict = {}  # key -> variable: the factors' keys in order of first use, ...
        key_var: list[int] = []
        for f in factors:
            if f.kernel is None:
                return False
            for k in f.keys:
                v = var_of.get(k)
                if v is None:
                    v = var_of[k] = len(var_of)
                key_var.append(v)
        if batches:  # ... then the batches' other keys in ascending order
            more = {k for b in batches for k in b.keys.reshape(-1).tolist()}
            if var_of:
                for k in sorted(more.difference(var_of)):
                    var_of[k] = len(var_of)
            else:
                var_of = dict(zip(sorted(more), range(len(more))))
        value_of = values._dict
        blocks = [(blk, blk.row_index()) for blk in pending]
        if any(index is None for _, index in blocks):
            return False
        if not value_of and len(blocks) == 1:  # a file's poses: one bulk block, one kind
            blk, index = blocks[0]
            block_rows = [index.get(k) for k in var_of]
            kind = _kind_of_rows(blk)
            if kind is None or None in block_rows:
                return False
            kinds, kind_id = [kind], {id(kind): 0}
            var_kind, var_row = [0] * len(block_rows), None  # (one kind: rows made below)
            storages = [blk.rows[block_rows]]  # a new array: the block stays as it is
            if blk.keys.shape[0] == len(block_rows):
                # where values() finds each of the block's rows (its _vars_of costs ~4 us)
                order = [0] * len(block_rows)
                for v, r in enumerate(block_rows):
                    order[r] = v
                self._bulk_order = order
        else:
            found = self._small_variables(var_of, value_of, blocks)
            if found is None:
                return False
            kinds, kind_id, var_kind, var_row, members = found
            storages = [self._small_storage(kind, items) for kind, items in zip(kinds, members)]
        self.var_keys = np.array(list(var_of), dtype=np.int64)
        if len(kinds) == 1:
            self._one_kind(kinds[0])
        else:
            self.kinds = kinds
            self._kind_id = kind_id
            dims = [kind.dim for kind in kinds]
            self.var_kind = np.array(var_kind, dtype=np.int64)
            self.var_row = np.array(var_row, dtype=np.int64)
            var_dims = [dims[t] for t in var_kind]
            self.var_dim = np.array(var_dims, dtype=np.int64)
            self.__dict__["size"] = sum(var_dims)
            by_kind: list[list[int]] = [[] for _ in kinds]
            for v, t in enumerate(var_kind):
                by_kind[t].append(v)
            self._kind_vars = [np.array(vs, dtype=np.int64) for vs in by_kind]
        self._initial_storages = storages
        self._no_slow_parts(values)
        if num_values > len(var_of):
            have = chain(value_of, *(blk.keys.tolist() for blk, _ in blocks))
            self.unused_keys = [Key(k) for k in have if k not in var_of]
        if factors:  # for _add_factor_batch
            self._key_start = np.zeros(len(factors) + 1, dtype=np.int64)
            np.cumsum([len(f.keys) for f in factors], out=self._key_start[1:])
            self._key_var = np.array(key_var, dtype=np.int64)
        # batches: factors by kernel in order of first appearance, then by robust loss; then
        # the graph's batches
        groups: dict[int, list[int]] = {}
        for i, f in enumerate(factors):
            groups.setdefault(id(f.kernel), []).append(i)
        self.batches = []
        for rows in groups.values():
            for rs, fs in self._by_loss(np.array(rows, dtype=np.int64),
                                        [factors[i] for i in rows]):
                self._add_factor_batch(rs, fs)
        for b in batches:
            self.batches.append(self._small_batch(b, var_of, var_kind)
                                or self._make_batch(b, check_repeats=True))
        return True

    def _no_slow_parts(self, values: Variables) -> None:
        """What :meth:`_collect_small` sets when every factor and value has a kernel / kind (no
        Python-path variables or factors, no unused keys yet)."""
        self._slow_vars = _NO_VARIABLES
        self._slow_values = []
        self._extra = values
        self.unused_keys = []
        self._slow = []

    def _one_kind(self, kind: BatchKind) -> None:
        """The variables' tables when all are of one kind: every variable's row is its number."""
        self.kinds = [kind]
        self._kind_id = {id(kind): 0}
        V = self.var_keys.shape[0]
        self.var_kind = np.zeros(V, dtype=np.int64)
        self.var_row = np.arange(V, dtype=np.int64)
        self.var_dim = np.empty(V, dtype=np.int64)  # (np.full: ~0.5 us more)
        self.var_dim.fill(kind.dim)
        self.__dict__["size"] = V * kind.dim  # the cached property, known here
        self._kind_vars = [self.var_row]

    def _collect_file(self, batches: list, blk: Any, values: Variables) -> bool:
        """:meth:`_collect_small` of what a file reader makes: batches only, and values that are
        one bulk block with strictly ascending keys (checked in the compiled call), every one of
        them used. The variables are then the block's rows in order (the numbering of the sorted
        batch keys), each batch's variables found by one compiled call
        (:func:`~fgopt._structure_kernels.block_var_idx`) instead of a Python pass over its keys.
        False (nothing set) for anything else."""
        kind = _kind_of_rows(blk)
        if kind is None:
            return False
        used = np.zeros(blk.keys.shape[0], dtype=np.bool_)
        found, seen = [], 0
        for b in batches:
            var_idx, fresh = block_var_idx(blk.keys, b.keys, used)
            if fresh < 0:  # a missing or repeated key: the Python pass finds and names it
                return False
            found.append(var_idx)
            seen += fresh
        if seen != used.shape[0]:  # unused values: numbered without them
            return False
        self.var_keys = blk.keys.copy()
        self._one_kind(kind)
        self._initial_storages = [blk.rows.copy()]  # (the block stays as it is)
        self._bulk_order = list(range(seen))
        self._no_slow_parts(values)
        self.batches = []
        for b, var_idx in zip(batches, found):
            kind_ids = tuple([0 if a is kind else self._kind_id.get(id(a), -2)
                              for a in b.kernel.arg_kinds])
            self.batches.append(self._make_batch(b, check_repeats=True) if any(kind_ids)
                                else self._batch(b, var_idx, kind_ids))
        return True

    @staticmethod
    def _small_variables(var_of: dict, value_of: dict, blocks: list) -> tuple | None:
        """The variables of :meth:`_collect_small` (keys ``var_of``, values in ``value_of`` or
        the bulk ``blocks``): kinds numbered in order of first appearance, each variable's kind
        and row in its kind, and per kind its values (objects, or :class:`_BulkRow` s); None
        for anything the general collection must see."""
        kinds: list[BatchKind] = []
        kind_id: dict[int, int] = {}
        kind_of_type: dict = {}
        var_kind, var_row = [], []
        members: list[list] = []
        for k in var_of:
            x = value_of.get(k)
            if x is not None:
                tkey = (np.ndarray, x.shape) if type(x) is np.ndarray else type(x)
                kind = kind_of_type.get(tkey)
                if kind is None:
                    try:
                        kind = kind_of_type[tkey] = ops_for(x).batch_kind(x)
                    except FgoptError:
                        return None
                item = x
            else:
                for blk, index in blocks:
                    row = index.get(k)
                    if row is not None:
                        break
                else:
                    return None
                item = _BulkRow(blk, row)
                kind = kind_of_type.get(id(blk))
                if kind is None:
                    kind = kind_of_type[id(blk)] = _kind_of_rows(blk)
            if kind is None:
                return None
            kid = kind_id.get(id(kind))
            if kid is None:
                kid = kind_id[id(kind)] = len(kinds)
                kinds.append(kind)
                members.append([])
            var_kind.append(kid)
            var_row.append(len(members[kid]))
            members[kid].append(item)
        return kinds, kind_id, var_kind, var_row, members

    def _small_batch(self, b: FactorBatch, var_of: dict, var_kind: list) -> _Batch | None:
        """:meth:`_make_batch` of a graph's batch in :meth:`_collect_small`: variables, kinds and
        repeated keys in one Python pass over its few rows (NumPy's searchsorted and checks cost
        ~6 us whatever the size). None when a check fails: :meth:`_make_batch` then says which."""
        kind_id = self._kind_id
        kind_ids = tuple([kind_id.get(id(kind), -2) for kind in b.kernel.arg_kinds])
        k = len(kind_ids)
        idx = [[var_of[q] for q in row] for row in b.keys.tolist()]
        if len(self.kinds) == 1:  # every variable of kind 0
            if any(kind_ids):
                return None
        else:
            want = list(kind_ids)
            if any([var_kind[v] for v in vs] != want for vs in idx):
                return None
        if k == 2:
            if any(u == v for u, v in idx):
                return None
        elif k > 2 and any(len(set(vs)) < k for vs in idx):
            return None
        var_idx = np.array(idx, dtype=np.int64)
        return self._batch(b, var_idx if idx else var_idx.reshape(0, k), kind_ids)

    @classmethod
    def _small_storage(cls, kind: BatchKind, items: list) -> np.ndarray:
        """``(n, storage_dim)`` storage of one kind's variables in :meth:`_collect_small`:
        value objects, or :class:`_BulkRow` s taken as their block's rows."""
        if not any(type(x) is _BulkRow for x in items):
            return cls._storage_of(kind, items)
        S = np.empty((len(items), kind.storage_dim))
        for r, x in enumerate(items):
            S[r] = x.block.rows[x.row] if type(x) is _BulkRow else cls._storage_of(kind, [x])[0]
        return S

    # ----------------------------------------------------------------- compile: variables
    def _collect_variables(self, graph: Any, values: Variables) -> None:
        # Every key of the individually added factors in one flat array (one Python pass over
        # the factors), and the variable each one names: factor keys are numbered in order of
        # first use. _collect_factors reads the factors' variables from it.
        key_lists = [f.keys for f in graph.factors]
        counts = np.fromiter(map(len, key_lists), dtype=np.int64, count=len(key_lists))
        self._key_start = np.zeros(counts.shape[0] + 1, dtype=np.int64)
        np.cumsum(counts, out=self._key_start[1:])
        flat = np.fromiter(chain.from_iterable(key_lists), dtype=np.int64,
                           count=int(self._key_start[-1]))
        # np.unique(flat, return_index=True, return_inverse=True) by one stable sort (np.unique
        # costs ~3x more on a few hundred keys: a fixed per-call cost of small problems)
        order = np.argsort(flat, kind="stable")
        srt = flat[order]
        new = np.empty(srt.shape[0], dtype=bool)
        new[:1] = True
        np.not_equal(srt[1:], srt[:-1], out=new[1:])
        starts = np.flatnonzero(new)
        uniq, first = srt[starts], order[starts]  # stable: a key's first position comes first
        inverse = np.empty(srt.shape[0], dtype=np.int64)
        inverse[order] = np.cumsum(new) - 1
        by_use = np.argsort(first)  # first uses are distinct positions: any sort is stable
        use_rank = np.empty_like(by_use)
        use_rank[by_use] = np.arange(by_use.shape[0])
        self._key_var = use_rank[inverse.reshape(-1)]
        factor_keys = uniq[by_use]
        batch_keys = np.zeros(0, dtype=np.int64)
        if graph.batches:
            batch_keys = unique_int(np.concatenate([b.keys.reshape(-1) for b in graph.batches]))
            if factor_keys.shape[0]:
                batch_keys = batch_keys[~np.isin(batch_keys, factor_keys)]
        # variables: the factors' keys in order of appearance, then the batches' in key order
        var_keys = np.concatenate([factor_keys, batch_keys])
        V = var_keys.shape[0]
        # Values added in bulk (Variables.add_rows) are taken as arrays: no Python step per
        # variable (a BA problem has ~10^6); the others one by one, in comprehensions.
        block, brow = values._find_rows(var_keys)
        per_key = np.flatnonzero(block < 0)
        value_of = values._dict
        xs = [value_of.get(k) for k in var_keys[per_key].tolist()]
        missing = next((i for i, x in enumerate(xs) if x is None), None)
        if missing is not None:
            self._raise_missing(graph, values)
            k = int(var_keys[per_key[missing]])
            b, row = self._find_key_row(graph, k)
            raise KeyNotFoundError(
                f"{b.kernel.name} (factor {b._where(row)}) uses {key_str(Key(k))}, which is "
                "not in the initial values")
        ndarray = np.ndarray
        tkeys = [(ndarray, x.shape) if type(x) is ndarray else type(x) for x in xs]
        # traits looked up once per (type, shape) / bulk block; kinds numbered in order of
        # first appearance among the variables
        kinds: list[BatchKind] = []
        found: dict[int, int] = {}  # id(kind) -> provisional number

        def number(kind) -> int:
            if kind is None:
                return -1
            if id(kind) not in found:
                found[id(kind)] = len(kinds)
                kinds.append(kind)
            return found[id(kind)]

        tok = np.empty(V, dtype=np.int64)
        ops_of: dict = {}
        tok_of: dict = {}
        for tkey in dict.fromkeys(tkeys):
            x = xs[tkeys.index(tkey)]
            ops = ops_of[tkey] = ops_for(x)
            tok_of[tkey] = number(ops.batch_kind(x))
        tok[per_key] = np.fromiter(map(tok_of.__getitem__, tkeys), dtype=np.int64,
                                   count=len(tkeys))
        for b, blk in enumerate(values._pending):
            on = block == b
            if on.any():
                tok[on] = number(_kind_of_rows(blk))
        first = [int(np.argmax(tok == t)) for t in range(len(kinds))]
        renum = np.full(len(kinds) + 1, -1, dtype=np.int64)  # last entry: -1 -> -1
        renum[np.argsort(first, kind="stable")] = np.arange(len(kinds))
        self.kinds = [kinds[t] for t in np.argsort(first, kind="stable").tolist()]
        kind_id = {id(k): i for i, k in enumerate(self.kinds)}
        var_kind = renum[tok]
        var_row = np.zeros(V, dtype=np.int64)
        var_dim = np.zeros(V, dtype=np.int64)
        slot = np.full(V, -1, dtype=np.int64)  # position in xs of per-key variables
        slot[per_key] = np.arange(per_key.shape[0])
        storages = []
        # the variables of each kind (ascending), from one stable sort; -1 (slow path) first
        by_kind = np.argsort(var_kind, kind="stable")
        bounds = np.searchsorted(var_kind[by_kind], np.arange(len(self.kinds) + 1))
        kind_vars = [by_kind[bounds[kid]:bounds[kid + 1]] for kid in range(len(self.kinds))]
        for kid, kind in enumerate(self.kinds):
            idx = kind_vars[kid]
            var_row[idx] = np.arange(idx.shape[0])
            var_dim[idx] = kind.dim
            S = np.empty((idx.shape[0], kind.storage_dim))
            sl = slot[idx]
            pk = sl >= 0
            if pk.all():
                S[:] = self._storage_of(kind, list(map(xs.__getitem__, sl.tolist())))
            elif pk.any():
                S[pk] = self._storage_of(kind, list(map(xs.__getitem__, sl[pk].tolist())))
            for b, blk in enumerate(values._pending):
                on = block[idx] == b
                if on.any():
                    S[on] = blk.rows[brow[idx[on]]]
            storages.append(S)
        slow_idx = by_kind[:bounds[0]]
        var_row[slow_idx] = np.arange(slow_idx.shape[0])
        self._slow_values: list[Any] = [xs[i] for i in slot[slow_idx].tolist()]
        for i, x in zip(slow_idx.tolist(), self._slow_values):
            var_dim[i] = ops_of[tkeys[slot[i]]].dim(x)
        self._kind_id = kind_id
        self.var_keys = var_keys
        self.var_kind = var_kind
        self.var_row = var_row
        self.var_dim = var_dim
        self._initial_storages = storages
        self._kind_vars = kind_vars
        self._slow_vars = slow_idx
        self._extra = values  # for unused keys and the final Variables
        #: Keys of ``values`` that no factor uses (returned unchanged in the final values).
        self.unused_keys: list[Key] = []
        if len(values) > V:  # without turning bulk rows into per-key values
            have = np.concatenate(
                [np.fromiter(values._dict.keys(), dtype=np.int64, count=len(values._dict))]
                + [blk.keys for blk in values._pending])
            self.unused_keys = [Key(k) for k in have[~np.isin(have, var_keys)].tolist()]

    @functools.cached_property
    def _sorted(self) -> np.ndarray:
        """The variables in ascending key order (for :meth:`_vars_of`)."""
        return np.argsort(self.var_keys)

    @functools.cached_property
    def _var_of_key(self) -> dict:
        """Key -> variable index (built on first use: slow-path factors and marginals)."""
        return {Key(k): i for i, k in enumerate(self.var_keys.tolist())}

    @staticmethod
    def _storage_of(kind: BatchKind, xs: list) -> np.ndarray:
        """``(n, storage_dim)`` storage of a kind's values (vector values stacked directly)."""
        if is_vector_kind(kind) and kind is not SCALAR_KIND:
            return np.array(xs, dtype=float).reshape(len(xs), kind.storage_dim)
        if kind.wrap is not None:  # Lie groups and declared manifolds keep their row as _data
            try:
                return np.array([x._data for x in xs], dtype=float).reshape(
                    len(xs), kind.storage_dim)
            except AttributeError:
                pass
        return np.array([kind.to_storage(x) for x in xs], dtype=float).reshape(
            len(xs), kind.storage_dim)

    @staticmethod
    def _raise_missing(graph: Any, values: Variables) -> None:
        """Name the first individually added factor that uses a key without a value (if any)."""
        for f in graph.factors:
            for k in f.keys:
                if k not in values:
                    raise KeyNotFoundError(
                        f"{f.describe()} uses {key_str(k)}, which is not in the initial "
                        f"values: add it with Variables.add({key_str(k)}, value)")

    @staticmethod
    def _find_key_row(graph: Any, k: int) -> tuple[FactorBatch, int]:
        for b in graph.batches:
            hit = np.nonzero((b.keys == k).any(axis=1))[0]
            if hit.shape[0]:
                return b, int(hit[0])
        raise AssertionError("key not found in batches")

    def _vars_of(self, keys: np.ndarray) -> np.ndarray:
        at = np.searchsorted(self.var_keys, keys, sorter=self._sorted)
        return self._sorted[at]

    # ----------------------------------------------------------------- compile: factors
    def _collect_factors(self, graph: Any) -> None:
        factors = graph.factors
        # batches: factors grouped by kernel (in order of first appearance; ids numbered in
        # C-level passes), then by robust loss (:meth:`_by_loss`)
        kernel_ids = list(map(id, [f.kernel for f in factors]))
        number = {k: j for j, k in enumerate(dict.fromkeys(kernel_ids))}
        gid = np.fromiter(map(number.__getitem__, kernel_ids), dtype=np.int64,
                          count=len(kernel_ids))
        by_group = np.argsort(gid, kind="stable")
        ends = np.cumsum(np.bincount(gid, minlength=len(number)))
        self._slow: list[_SlowFactor] = []
        self.batches = []
        for kernel_id, rows in zip(number, np.split(by_group, ends[:-1])):
            if kernel_id == id(None):  # Python factors: the slow path, one by one
                self._slow += [self._make_slow(factors[i]) for i in rows.tolist()]
                continue
            for rows, fs in self._by_loss(rows, [factors[i] for i in rows.tolist()]):
                self._add_factor_batch(rows, fs)
        self.batches += [self._make_batch(b, check_repeats=True) for b in graph.batches]

    @staticmethod
    def _by_loss(rows: np.ndarray, fs: list) -> list[tuple[np.ndarray, list]]:
        """Factors of one kernel split by robust loss (code and parameters): one batch each."""
        losses = [f.loss for f in fs]
        if not any(issubclass(t, RobustLoss) for t in set(map(type, losses))):
            return [(rows, fs)]
        parts: dict[tuple, list[int]] = {}
        for j, code in enumerate(map(loss_code_and_param, losses)):
            parts.setdefault(code, []).append(j)
        return [(rows[js], [fs[j] for j in js]) for js in parts.values()]

    def _add_factor_batch(self, rows: np.ndarray, fs: list) -> None:
        """A batch of the individually added factors ``fs`` (positions ``rows`` in the graph)."""
        k = len(fs[0].kernel.arg_kinds)
        # the factors' variables, from the keys collected with the variables
        var_idx = self._key_var[self._key_start[rows][:, None] + np.arange(k)]
        source = batch_from_factors(fs[0].kernel, fs, self.var_keys[var_idx])
        # a Factor rejects a repeated key when it is made: no check per batch here
        self.batches.append(self._make_batch(source, var_idx))

    def _make_batch(self, b: FactorBatch, var_idx: np.ndarray | None = None,
                    check_repeats: bool = False) -> _Batch:
        """The compiled form of batch ``b`` (``var_idx``: its variables, when known)."""
        kernel = b.kernel
        if var_idx is None:
            var_idx = self._vars_of(b.keys)
        kind_ids = tuple(self._kind_id.get(id(kind), -2) for kind in kernel.arg_kinds)
        small = var_idx.shape[0] <= _PYTHON_CHECK_ROWS  # NumPy's fixed cost dominates
        found = self.var_kind[var_idx]
        if (any(r != list(kind_ids) for r in found.tolist()) if small
                else (found != np.array(kind_ids, dtype=np.int64)).any()):
            row, j = (int(x[0]) for x in np.nonzero(found != np.array(kind_ids, dtype=np.int64)))
            kind = kernel.arg_kinds[j]
            k = Key(int(b.keys[row, j]))
            x = self._extra.at(k)
            raise ManifoldError(
                f"{kernel.name}({', '.join(key_str(Key(int(q))) for q in b.keys[row])}) "
                f"(factor {b._where(row)}): argument {j} expects {kind.name}, but "
                f"{key_str(k)} is a {type(x).__name__}")
        if check_repeats and var_idx.shape[1] > 1:
            if small:
                k = var_idx.shape[1]
                row = next((i for i, r in enumerate(var_idx.tolist()) if len(set(r)) < k), None)
            elif var_idx.shape[1] == 2:  # (a pose graph's between factors: no sort)
                dup = np.flatnonzero(var_idx[:, 0] == var_idx[:, 1])
                row = int(dup[0]) if dup.shape[0] else None
            else:
                srt = np.sort(var_idx, axis=1)
                dup = np.any(srt[:, 1:] == srt[:, :-1], axis=1)
                row = int(np.nonzero(dup)[0][0]) if np.any(dup) else None
            if row is not None:
                raise FgoptError(f"{kernel.name} (factor {b._where(row)}) uses the same key twice")
        return self._batch(b, var_idx, kind_ids)

    def _batch(self, b: FactorBatch, var_idx: np.ndarray, kind_ids: tuple) -> _Batch:
        """The :class:`_Batch` of ``b`` over the checked variables ``var_idx``."""
        dims, offsets, identity = _kernel_tables(b.kernel)
        unit = b.sqrt_information is None
        R = identity if unit else np.ascontiguousarray(b.sqrt_information)
        # what _Batch(b.kernel, b, var_idx, kind_ids, R, unit, dims, offsets, sqrt_info0=R,
        # unit0=unit, var_row=self.var_row) makes, without its 17-argument __init__ (~1 us of
        # a small problem's ~6 us per batch); rows and weights: made on first read
        batch = object.__new__(_Batch)
        batch.__dict__.update(
            kernel=b.kernel, source=b, var_idx=var_idx, kind_ids=kind_ids, sqrt_info=R,
            unit=unit, arg_dims=dims, arg_local_off=offsets, toff=None, pos=None,
            sqrt_info0=R, unit0=unit, plan=None, fixed={}, rows2d=None, var_row=self.var_row,
            _rows=None, _weights=None)
        return batch

    def _make_slow(self, f: Factor) -> _SlowFactor:
        var_idx = np.array([self._var_of_key[k] for k in f.keys], dtype=np.int64)
        noise = base_noise(f.loss)
        code, param, shape = loss_code_and_param(f.loss)
        dims = self.var_dim[var_idx]
        R = np.ascontiguousarray(noise.sqrt_information)[None]
        return _SlowFactor(f, var_idx, R, bool(noise.is_unit), code, param, shape, dims,
                           np.concatenate([[0], np.cumsum(dims)[:-1]]).astype(np.int64),
                           sqrt_info0=R, unit0=bool(noise.is_unit))

    # ----------------------------------------------------------------- compile: structure
    def _schur_kind(self, linear_solver: Any, independent: tuple[int, ...]) -> int | None:
        """The kind a Schur solver named ``linear_solver`` would eliminate (None: no Schur)."""
        if not isinstance(linear_solver, str):
            return None
        if linear_solver == "auto":
            if int(self.var_dim.sum()) <= DENSE_MAX_SIZE:
                return None
            return ba_shaped_kind(self.var_kind, self.var_dim, independent)
        if linear_solver.startswith("schur"):  # SchurSolver(eliminate=None)'s choice
            return next((k for k in kinds_by_count(self.var_kind) if k in independent), None)
        return None

    def _independent_kinds(self) -> tuple[int, ...]:
        """:func:`fgopt.structure.independent_kinds` of the problem's pairs, read from the
        factors' argument kinds: a kind is joined iff some factor has two arguments of it (a
        factor's variables are distinct: repeated keys are rejected), so no pass over the pairs
        is needed."""
        joined: set[int] = set()
        for b in self.batches:
            ids = [k for k in b.kind_ids if k >= 0]
            if len(set(ids)) < len(ids):
                joined.update(k for k in ids if ids.count(k) > 1)
        for s in self._slow:
            ids = [k for k in self.var_kind[s.var_idx].tolist() if k >= 0]
            if len(set(ids)) < len(ids):
                joined.update(k for k in ids if ids.count(k) > 1)
        # every kind has variables (kinds are found from the variables)
        return tuple(k for k in range(len(self.kinds)) if k not in joined)

    def _coupled_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """``(pairs_i, pairs_j)``: every pair of variables a factor couples (repeats kept)."""
        pi, pj = [], []
        for b in self.batches:
            k = b.var_idx.shape[1]
            if k == 2:
                pi.append(b.var_idx[:, 0])
                pj.append(b.var_idx[:, 1])
            elif k > 2:  # pair by pair, each over all instances, in two gathers
                P, Q = _upper_pairs(k)
                pi.append(b.var_idx[:, P].T.reshape(-1))
                pj.append(b.var_idx[:, Q].T.reshape(-1))
        for s in self._slow:
            for p in range(len(s.var_idx)):
                for q in range(p + 1, len(s.var_idx)):
                    pi.append(s.var_idx[p:p + 1])
                    pj.append(s.var_idx[q:q + 1])
        pi = np.concatenate(pi) if pi else np.zeros(0, np.int64)
        pj = np.concatenate(pj) if pj else np.zeros(0, np.int64)
        return pi, pj

    def _build_structure(self, ordering: str, linear_solver: Any = None) -> None:
        pi, pj = self._coupled_pairs()
        V = self.var_keys.shape[0]
        independent = self._independent_kinds()
        eliminated = self._schur_kind(linear_solver, independent)
        R = self.restrictions
        free = R.free_variables() if R is not None else None
        var_kind, var_dim, fidx = self.var_kind, self.var_dim, None
        if free is not None:
            # constant variables leave H: the pattern is built over the free ones only
            if free.shape[0] == 0:
                raise FgoptError("every variable of the problem is constant: nothing to "
                                 "optimize")
            fidx = np.full(V, -1, dtype=np.int64)
            fidx[free] = np.arange(free.shape[0])
            keep = (fidx[pi] >= 0) & (fidx[pj] >= 0)
            pi, pj = fidx[pi[keep]], fidx[pj[keep]]
            var_kind, var_dim = var_kind[free], var_dim[free]
            if eliminated is not None and not (var_kind == eliminated).any():
                eliminated = None  # every variable of the kind is constant
        Vf = var_kind.shape[0]
        if eliminated is not None:
            order = schur_order(var_kind, eliminated)
        elif (linear_solver == "auto" and ordering == "amd" and numpy_budget_left()
              and int(var_dim.sum()) <= DENSE_MAX_SIZE):
            # "auto" factors it densely with LAPACK (solvers.linear.base.choose_linear_solver):
            # no fill to reduce, and no ordering's imports (scipy.sparse and CHOLMOD cost a new
            # process ~0.2 s)
            order = np.arange(Vf, dtype=np.int64)
        else:
            order = fill_reducing_order(Vf, pi, pj, ordering)
        self.pattern, lookup = build_pattern(var_dim, order, pi, pj)
        del pi, pj
        self.pattern.var_kind = var_kind
        self.pattern.kind_names = tuple(k.name for k in self.kinds)
        self.pattern.independent_kinds = independent
        if linear_solver == "auto" and self.pattern.size > DENSE_MAX_SIZE:  # computed above
            self.pattern.ba_kind = -1 if eliminated is None else eliminated
        rank = np.empty(Vf, dtype=np.int64)
        rank[order] = np.arange(Vf)
        N, nnz = self.pattern.size, self.pattern.nnz
        #: Tangent offset of every variable (constant ones: N, the start of g's scratch tail).
        self.var_offset = off = self.pattern.var_offset
        #: The column shifts the assembly kernels read (with a scratch tail, see below).
        self.assembly_shift = self.pattern.col_shift
        trash = 0
        if fidx is not None:
            # Constant arguments still come out of the kernels: their gradient goes to a
            # scratch tail of g (offset N), their diagonal block to a scratch tail of H's data
            # (p00 = nnz, column shift 0), their off-diagonal blocks nowhere (pos -1).
            trash = int(self.var_dim.max())
            off = np.full(V, N, dtype=np.int64)
            off[free] = self.pattern.var_offset
            self.var_offset = off
            self.assembly_shift = np.concatenate([self.pattern.col_shift,
                                                  np.zeros(trash, np.int64)])
        for b in self.batches:
            b.toff = np.ascontiguousarray(off[b.var_idx])
            b.pos = self._positions(lookup, rank, b.var_idx, fidx, nnz)
            b.plan = None
        for s in self._slow:
            s.toff = off[s.var_idx][None]
            s.pos = self._positions(lookup, rank, s.var_idx[None], fidx, nnz)
        del lookup
        # tangent indices of each kind's variables, row order (for batched retract)
        self._kind_tangent = []
        for kid, kind in enumerate(self.kinds):
            vars_ = self._kind_vars[kid]
            rows = self.var_row[vars_]
            order_rows = np.empty_like(vars_)
            order_rows[rows] = vars_
            idx = off[order_rows][:, None] + np.arange(kind.dim)[None, :]
            self._kind_tangent.append(idx)
        self._trash = trash
        self.H_data, self.g = self._buffers()
        self._spare: tuple[np.ndarray, np.ndarray] | None = None
        #: Linearize trial states into a second H (see :meth:`linearize_candidate`).
        self.spare_buffers = self.H_data.nbytes <= SPARE_MAX_BYTES
        self._holds_candidate = False
        if R is not None:
            R.attach(self)

    def _buffers(self) -> tuple[np.ndarray, np.ndarray]:
        """Zeroed H data and g; with constant variables, views of arrays ``_trash`` longer (the
        scratch tails the assembly writes constant arguments' blocks into)."""
        nnz, N, t = self.pattern.nnz, self.pattern.size, self._trash
        if not t:
            return np.zeros(nnz), np.zeros(N)
        return np.zeros(nnz + t)[:nnz], np.zeros(N + t)[:N]

    @staticmethod
    def _positions(lookup: dict, rank: np.ndarray, var_idx: np.ndarray,
                   fidx: np.ndarray | None, nnz: int) -> np.ndarray:
        """:func:`scatter_positions` of ``var_idx``; with constant variables (``fidx``: free
        index of each variable, -1 if constant) a constant argument's diagonal block goes to
        the scratch position ``nnz`` and its off-diagonal blocks nowhere."""
        if fidx is None:
            return scatter_positions(lookup, rank, var_idx)
        fv = fidx[var_idx]
        const = fv < 0
        if not const.any():
            return scatter_positions(lookup, rank, fv)
        # a constant argument looked up as a free one of its factor (any stored block will
        # do: it is overwritten below)
        stand_in = np.maximum(fv.max(axis=1), 0)
        pos = scatter_positions(lookup, rank, np.where(const, stand_in[:, None], fv))
        pos[const[:, :, None] | const[:, None, :]] = -1
        n, k = const.shape
        ii, pp = np.nonzero(const)
        pos[ii, pp, pp] = nnz
        return np.ascontiguousarray(pos)

    # ----------------------------------------------------------------- iteration API
    @functools.cached_property
    def size(self) -> int:
        """Total tangent dimension N."""
        return int(self.var_dim.sum())

    @property
    def num_variables(self) -> int:
        return int(self.var_keys.shape[0])

    def initial_state(self) -> State:
        return State([s.copy() for s in self._initial_storages],
                     {int(v): self._slow_values[self.var_row[v]] for v in self._slow_vars})

    def _value_of(self, state: State, v: int) -> Any:
        kid = self.var_kind[v]
        if kid < 0:
            return state.objects[v]
        return self.kinds[kid].from_storage(state.storages[kid][self.var_row[v]])

    @staticmethod
    def state_is_finite(state: State) -> bool:
        """True when every stored value of ``state`` is finite (Python-manifold values that
        expose no storage are not checked)."""
        if not all(_all_finite(s) for s in state.storages):
            return False
        for x in state.objects.values():
            try:
                data = ops_for(x).to_storage(x)
            except Exception:  # noqa: BLE001 - duck-typed manifolds have no storage
                continue
            if not np.all(np.isfinite(data)):
                return False
        return True

    def cost(self, state: State) -> float:
        """Total cost ``sum rho_i`` (``0.5 |r|^2`` without robust losses); NaN if not finite
        (also when a value of ``state`` is not finite)."""
        if not self.state_is_finite(state):
            return float("nan")
        with self.kernel_mode():
            return self._cost(state)

    def _cost(self, state: State) -> float:
        t0 = time.perf_counter()
        total = 0.0
        for b in self.batches:
            if _asm(len(b.source)) is asm_np:  # NumPy twins: small batch, budget left
                res = b.kernel.residual(b.gather(state), b.source.constants)
                t1 = time.perf_counter()
                total += asm_np.batch_cost(res, b.sqrt_info, b.unit, b.source.loss_code,
                                           b.source.loss_param, b.source.loss_shape)
                charge_numpy(time.perf_counter() - t1)
                continue
            cost = 0.0
            for lo, hi in b.chunks(CHUNK):
                res = b.kernel.residual(b.gather(state, lo, hi), b.source.constants[lo:hi])
                cost = asm.batch_cost(res, b.sqrt_info_of(lo, hi), b.unit, b.source.loss_code,
                                      b.source.loss_param, b.source.loss_shape, cost)
            total += cost
        if self._slow:
            view = _StateView(self, state)
            for s in self._slow:
                try:
                    e = s.factor.checked_error(view)
                except NonFiniteError:
                    total = np.nan
                    continue
                total += asm_np.batch_cost(e[None], s.sqrt_info, s.unit, s.loss_code,
                                           s.loss_param, s.loss_shape)
        self.timing["cost"] += time.perf_counter() - t0
        return float(total) if np.isfinite(total) else float("nan")

    def linearize(self, state: State) -> float:
        """Fill ``self.H_data`` (lower CSC of H) and ``self.g`` (J^T W r); return the cost."""
        if self.pattern is None:
            raise FgoptError("this Problem was built without structure")
        self._holds_candidate = False
        total = self._linearize_into(state, self.H_data, self.g)
        if not _linearization_finite(total, self.H_data, self.g):
            raise NonFiniteError(self.locate_nonfinite(state))
        return total

    def linearize_candidate(self, state: State) -> float:
        """Linearize a trial state; return its cost (NaN if not finite).

        Trust-region methods call this instead of ``cost`` so an accepted step needs no second
        evaluation of the residuals, then :meth:`accept_candidate` or :meth:`reject_candidate`.
        With ``spare_buffers`` the trial goes into a second H / g (swapped in on acceptance);
        without, into H itself, and a rejection re-linearizes the current state (same numbers:
        linearizing a state is deterministic). ``spare_buffers`` defaults to H's data taking at
        most ``SPARE_MAX_BYTES``: a second H costs as much memory as H again (1.1 GB for 5M BA
        observations), re-linearizing costs time only on rejected steps. A trial point with a
        non-finite value, cost, residual or Jacobian gives NaN: the caller rejects it as a step,
        and the current linearization stays (or is restored) as it was.
        """
        if not self.state_is_finite(state):
            return float("nan")
        if self.spare_buffers:
            if self._spare is None:
                self._spare = self._buffers()
            H, g = self._spare
        else:
            H, g = self.H_data, self.g
            self._holds_candidate = True
        try:
            total = self._linearize_into(state, H, g)
        except NonFiniteError:
            return float("nan")
        if not _linearization_finite(total, H, g):
            return float("nan")
        return total

    def accept_candidate(self) -> None:
        """Make the last :meth:`linearize_candidate` the current linearization."""
        if self.spare_buffers:
            H, g = self._spare
            self._spare = (self.H_data, self.g)
            self.H_data, self.g = H, g
        self._holds_candidate = False

    def reject_candidate(self, state: State) -> None:
        """Keep ``state`` (the current iterate) as the linearization point after a rejected
        :meth:`linearize_candidate`."""
        if self._holds_candidate:
            self._linearize_into(state, self.H_data, self.g)
            self._holds_candidate = False

    def _linearize_into(self, state: State, H: np.ndarray, g: np.ndarray) -> float:
        with self.kernel_mode():
            if not self._trash:
                total = self._linearize_batches(state, H, g)
            else:  # the whole buffers: constant arguments write into their scratch tails
                total = self._linearize_batches(state, H.base, g.base)
        if self.restrictions is not None:
            self.restrictions.clamp(self, state, H, g)
        return total

    def _linearize_batches(self, state: State, H: np.ndarray, g: np.ndarray) -> float:
        H[:] = 0.0
        g[:] = 0.0
        total = 0.0
        t_lin = t_asm = 0.0
        shift = self.assembly_shift
        for b in self.batches:
            src = b.source
            n = src.keys.shape[0]
            kernels = _asm(n)
            hessian = b.kernel.scatter_hessian if b.unit and src.loss_code == 0 else None
            if hessian is not None and kernels is asm:
                # the kernel adds its own J^T J / J^T r blocks (structure the scatter cannot see);
                # serial, before threads: 8,000 smart tracks 0.16 s vs 0.55 s on two threads of
                # the parallel dense J^T J
                t0 = time.perf_counter()
                st = state.storages
                args = tuple([st[kid] for kid in b.kind_ids])
                if b.rows2d is None:
                    b.rows2d = np.ascontiguousarray(np.stack(b.rows, axis=1))
                for lo, hi in ([(0, n)] if n <= CHUNK else b.chunks(CHUNK)):
                    total += hessian(args, b.rows2d[lo:hi], src.constants[lo:hi],
                                     b.toff[lo:hi], b.pos[lo:hi], shift, H, g,
                                     b.weights[lo:hi], 0.0)
                t_lin += time.perf_counter() - t0
                continue
            if self.threads > 1 and n >= PARALLEL_MIN_BATCH and self.backend == "numba":
                t0 = time.perf_counter()
                for lo, hi in b.chunks(CHUNK * self.threads):
                    total += linearize_batch_threaded(self, b, state, H, g, lo, hi)
                t_lin += time.perf_counter() - t0
                continue
            if n <= CHUNK and kernels is asm:
                # one slice on numba (most batches): no slicing or per-slice bookkeeping
                fixed = b.fixed.get(b.unit, _UNSET)
                if fixed is _UNSET:
                    fixed = b.fixed[b.unit] = specialized_scatter(b)
                t0 = time.perf_counter()
                st = state.storages
                # the kernel's entry without argument checks where it has one: the gathered rows
                # and the batch's constants are C-contiguous float64 by construction
                res, jac = (b.kernel.trusted_linearize or b.kernel.linearize)(
                    tuple([st[kid].take(rows, axis=0) for kid, rows in zip(b.kind_ids, b.rows)]),
                    src.constants)
                t1 = time.perf_counter()
                if fixed is not None:
                    total += fixed(res, jac, b.sqrt_info, src.loss_code, src.loss_param,
                                   src.loss_shape, b.toff, b.pos, shift, H, g, b.weights, 0.0)
                else:
                    total += asm.scatter_batch(res, jac, b.sqrt_info, b.unit, src.loss_code,
                                               src.loss_param, src.loss_shape, b.arg_dims,
                                               b.arg_local_off, b.toff, b.pos, shift, H, g,
                                               b.weights, 0.0)
                t_lin += t1 - t0
                t_asm += time.perf_counter() - t1
                continue
            # in slices: the kernels' residual / Jacobian / gathered arguments stay a few MB
            # instead of ~300 bytes per factor at once (1.5 GB for 5M BA observations)
            chunks = b.chunks(CHUNK)
            if kernels is asm_np:
                # NumPy backend, or a small batch while the twin budget lasts: bincount assembly
                # with a scatter plan per slice (made on first use, kept)
                if b.plan is None:
                    b.plan = [None] * len(chunks)
                fixed = None
            else:
                # numba: the shape-specialized kernel where one applies
                fixed = b.fixed.get(b.unit, _UNSET)
                if fixed is _UNSET:
                    fixed = b.fixed[b.unit] = specialized_scatter(b)
            cost = 0.0
            for c, (lo, hi) in enumerate(chunks):
                t0 = time.perf_counter()
                res, jac = b.kernel.linearize(b.gather(state, lo, hi), b.source.constants[lo:hi])
                t1 = time.perf_counter()
                toff, pos = b.toff[lo:hi], b.pos[lo:hi]
                if kernels is asm_np:
                    if b.plan[c] is None:
                        b.plan[c] = asm_np.scatter_plan(b.arg_dims, b.arg_local_off, toff, pos,
                                                        shift, H.shape[0])
                    cost = asm_np.scatter_batch(
                        res, jac, b.sqrt_info_of(lo, hi), b.unit, b.source.loss_code,
                        b.source.loss_param, b.source.loss_shape, b.arg_dims, b.arg_local_off,
                        toff, pos, shift, H, g, b.weights[lo:hi], cost, b.plan[c])
                    charge_numpy(time.perf_counter() - t1)
                elif fixed is not None:
                    cost = fixed(res, jac, b.sqrt_info_of(lo, hi), b.source.loss_code,
                                 b.source.loss_param, b.source.loss_shape, toff, pos, shift, H,
                                 g, b.weights[lo:hi], cost)
                else:
                    cost = asm.scatter_batch(res, jac, b.sqrt_info_of(lo, hi), b.unit,
                                             b.source.loss_code, b.source.loss_param,
                                             b.source.loss_shape, b.arg_dims, b.arg_local_off,
                                             toff, pos, shift, H, g, b.weights[lo:hi], cost)
                t_lin += t1 - t0
                t_asm += time.perf_counter() - t1
            total += cost
        if self._slow:
            t0 = time.perf_counter()
            view = _StateView(self, state)
            for s in self._slow:
                e = s.factor.checked_error(view)
                Js = s.factor.checked_jacobians(view)
                J = np.concatenate(Js, axis=1)[None]
                total += asm_np.scatter_batch(e[None], J, s.sqrt_info, s.unit, s.loss_code,
                                              s.loss_param, s.loss_shape, s.arg_dims,
                                              s.arg_local_off, s.toff, s.pos, shift, H, g,
                                              np.ones(1))
            t_lin += time.perf_counter() - t0
        self.timing["linearize"] += t_lin
        self.timing["assemble"] += t_asm
        return float(total)

    def retract(self, state: State, delta: np.ndarray) -> State:
        """A new state ``x (+) delta`` (delta in the problem's tangent order)."""
        t0 = time.perf_counter()
        storages = []
        R = self.restrictions
        if self._trash:  # constant variables read their (zero) step from the tail
            delta = np.concatenate([delta, np.zeros(self._trash)])
        with self.kernel_mode():
            for kid, kind in enumerate(self.kinds):
                d = np.ascontiguousarray(delta[self._kind_tangent[kid]])
                storages.append(kind.retract(state.storages[kid], d))
        objects = {}
        off = self.var_offset
        for v, x in state.objects.items():
            if R is not None and R.const_var[v]:
                objects[v] = x
                continue
            objects[v] = ops_for(x).retract(x, delta[off[v]:off[v] + self.var_dim[v]])
        if R is not None:
            storages = [s if s.flags.writeable else s.copy() for s in storages]
            R.restore(state, storages, objects)
        self.timing["retract"] += time.perf_counter() - t0
        return State(storages, objects)

    def values(self, state: State) -> Variables:
        """The state as a new ``Variables`` (keys the graph does not use are copied unchanged)."""
        extra = self._extra
        out = Variables()
        if (not extra._dict and len(extra._pending) == 1 and len(self.kinds) == 1
                and self.kinds[0].wrap is not None and not self.unused_keys
                and not state.objects):
            # the initial values are one bulk block of this one kind (a file's poses): the
            # result as one such block in its key order (objects made when read, see
            # Variables.at), as GTSAM's optimize returns C++ values wrapped when read
            blk = extra._pending[0]
            order = self._bulk_order
            if order is None or len(order) != blk.keys.shape[0]:
                order = self.var_row[self._vars_of(blk.keys)]
            rows = state.storages[0][order]  # a copy: owned
            rows.flags.writeable = False
            out._pending.append(_Rows(blk.keys, self.kinds[0], rows))
            return out
        groups = ((kind, self.var_keys[vs].tolist(), state.storages[kid][self.var_row[vs]])
                  for kid, (kind, vs) in enumerate(zip(self.kinds, self._kind_vars)))
        objects = {Key(int(self.var_keys[v])): x for v, x in state.objects.items()}
        return replaced_values(extra, groups, self.unused_keys, objects)

    def values_as_rows(self, state: State) -> Variables:
        """:meth:`values` with each kind's values left as storage rows (the bulk blocks of
        ``Variables.add_rows``): no Python object per variable until one is read, which is what a
        result shipped to another process needs. Same keys, order and bits as :meth:`values`;
        it is :meth:`values` when some initial keys are unused, some values take the slow path,
        or the kinds interleave in the initial order."""
        extra = self._extra
        V = self.var_keys.shape[0]
        if (len(extra) != V or self._slow_vars.shape[0]
                or any(kind.wrap is None for kind in self.kinds)):
            return self.values(state)
        order = np.concatenate(  # the initial values' keys in their order (a permutation here)
            [np.fromiter(extra._dict.keys(), dtype=np.int64, count=len(extra._dict))]
            + [blk.keys for blk in extra._pending])
        var = self._sorted[np.searchsorted(self.var_keys[self._sorted], order)]
        kind_of = self.var_kind[var]
        starts, lengths = _runs(kind_of, 0)
        if starts.shape[0] > _MAX_LAZY_BLOCKS:
            return self.values(state)
        out = Variables()
        for s, n in zip(starts.tolist(), lengths.tolist()):
            kid = int(kind_of[s])
            rows = state.storages[kid][self.var_row[var[s:s + n]]]  # fancy index: a copy
            rows.flags.writeable = False
            out._pending.append(_Rows(order[s:s + n], self.kinds[kid], rows))
        return out

    def locate_nonfinite(self, state: State) -> str:
        """Name the first factor whose residual or Jacobian is not finite."""
        for b in self.batches:
            for lo, hi in b.chunks(CHUNK):
                with self.kernel_mode():
                    res, jac = b.kernel.linearize(b.gather(state, lo, hi),
                                                  b.source.constants[lo:hi])
                for arr, what in ((res, "residual"), (jac, "Jacobian")):
                    if self.backend == "numpy":
                        bad = ~np.isfinite(arr.reshape(arr.shape[0], -1)).all(axis=1)
                        row = int(np.argmax(bad)) if bad.any() else -1
                    else:
                        row = asm.first_nonfinite_row(arr)
                    if row < 0:
                        continue
                    row += lo
                    keys = ", ".join(key_str(Key(int(k))) for k in b.source.keys[row])
                    hint = b.kernel.nonfinite_hint or "check its measurement and variables"
                    return (f"{b.kernel.name}({keys}) (factor {b.source._where(row)}) has a "
                            f"non-finite {what}: {hint}")
        view = _StateView(self, state)
        for s in self._slow:
            try:
                s.factor.checked_error(view)
                s.factor.checked_jacobians(view)
            except NonFiniteError as e:
                return str(e)
        return "a residual or Jacobian is not finite"

    # ----------------------------------------------------------------- per-factor weights (GNC)
    def squared_residuals(self, state: State) -> list[np.ndarray]:
        """``|R_i e_i|^2`` of every factor: one array per batch, then one for Python factors.

        Uses the factors' own noise models (any weights set by :meth:`set_weights` excluded).
        """
        out = []
        for b in self.batches:
            parts = []
            for lo, hi in b.chunks(CHUNK):
                with self.kernel_mode():
                    res = b.kernel.residual(b.gather(state, lo, hi), b.source.constants[lo:hi])
                R0 = b.sqrt_info0 if b.unit0 else b.sqrt_info0[lo:hi]
                norms = asm_np if self.backend == "numpy" else asm
                parts.append(norms.row_squared_norms(res, R0, b.unit0))
            out.append(np.concatenate(parts))
        view = _StateView(self, state)
        slow = [float(np.sum(s.factor.whitened_error(view) ** 2)) for s in self._slow]
        out.append(np.array(slow))
        return out

    def set_weights(self, weights: list[np.ndarray] | None) -> None:
        """Scale each factor's cost by ``w_i >= 0`` (as ``sqrt(w_i) R_i``); ``None`` resets."""
        for i, b in enumerate(self.batches):
            if weights is None:
                b.sqrt_info, b.unit = b.sqrt_info0, b.unit0
                continue
            sw = np.sqrt(np.asarray(weights[i], dtype=float))
            R0 = np.broadcast_to(b.sqrt_info0, (len(b.source),) + b.sqrt_info0.shape[1:])
            b.sqrt_info = np.ascontiguousarray(sw[:, None, None] * R0)
            b.unit = False
        for j, s in enumerate(self._slow):
            if weights is None:
                s.sqrt_info, s.unit = s.sqrt_info0, s.unit0
            else:
                s.sqrt_info = np.sqrt(float(weights[-1][j])) * s.sqrt_info0
                s.unit = False

    def gradient_norm(self) -> float:
        return float(np.abs(self.g).max(initial=0.0))

    def __repr__(self) -> str:
        kinds = ", ".join(f"{len(v)} {k.name}" for k, v in zip(self.kinds, self._kind_vars))
        if len(self._slow_vars):
            kinds += f", {len(self._slow_vars)} Python-manifold"
        lines = [f"Problem({self.num_variables} variables: {kinds}; tangent dim {self.size})"]
        for b in self.batches:
            lines.append(f"  batch {b.kernel.name}: {len(b.source)} factors")
        if self._slow:
            lines.append(f"  Python factors (slow path): {len(self._slow)}")
        if self.pattern is not None:
            lines.append(f"  H: {self.pattern.size}x{self.pattern.size}, "
                         f"{self.pattern.nnz} stored (lower) entries")
        return "\n".join(lines)
