"""Factors of the incremental smoother: growing batches, linearization into the tree's pool.

Kernel factors (built-in, ``@fgopt.factor``) join a batch per (kernel, robust loss): rows of
variable slots, constants and square-root information in arrays that grow and reuse the rows
of removed factors, so a new factor never recompiles anything. Linearizing a set of factors
gathers their variables' linearization points, runs each batch's kernel once on the rows
concerned, and writes every factor's local system (``H = w J^T J`` row-major, ``g = w J^T r``
with the whitened ``J, r`` and robust weight ``w``, :func:`fgopt._assembly._local_system`) at
the end of the tree's ``hpool``. Python factors take the slow path, one call each.

Each factor has a *handle* (the index ``update`` returns, used to remove it) and a slot.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._jit import njit
from .. import _assembly as asm
from ..errors import FgoptError, KeyNotFoundError, ManifoldError, NonFiniteError
from ..factors.base import Factor
from ..key import Key, key_str
from ..noise import RobustLoss
from . import _pool
from ._pool import alloc
from ._state import M_HP_HEAD, M_HP_TOP, TreeState
from ._values import VariableStore, _dispatcher


def loss_parts(loss: Any) -> tuple[np.ndarray, int, float, float]:
    """``(sqrt_information, code, k, shape)`` of a noise model or robust loss."""
    if isinstance(loss, RobustLoss):
        return np.asarray(loss.base.sqrt_information), int(loss.code), float(loss.k), \
            float(loss.shape)
    return np.asarray(loss.sqrt_information), 0, 0.0, 0.0


def compiled_linearize(kernel: Any) -> Any:
    """``kernel.linearize`` on numba whatever the batch size (not the NumPy twin generated
    modules run up to ``NUMPY_MAX_BATCH`` instances: ~150 us against ~3 us for the one to few
    factors of an update): its ``trusted_linearize`` where it has one (the smoother's gathered
    rows and constants are C-contiguous float64), else ``linearize``."""
    return kernel.trusted_linearize or kernel.linearize


@dataclass(eq=False)
class _Batch:
    kernel: Any
    code: int
    k: float
    shape: float
    kids: tuple[int, ...] = ()
    var_slots: np.ndarray = field(default=None)   # (cap, nargs)
    consts: np.ndarray = field(default=None)      # (cap, c)
    R: np.ndarray = field(default=None)           # (cap, r, r)
    fac: np.ndarray = field(default=None)         # (cap,) factor slot, -1 free
    free: list = field(default_factory=list)
    hwm: int = 0
    linearize: Any = None                         # compiled_linearize(kernel)
    D: int = 0                                    # tangent dims of the arguments, summed
    raw: Any = None                               # linearize's numba kernel, if it has one

    def grow(self, n: int) -> None:
        cap = self.fac.shape[0]
        if n <= cap:
            return
        cap = max(n, 2 * cap)
        for name in ("var_slots", "consts", "R"):
            old = getattr(self, name)
            new = np.zeros((cap,) + old.shape[1:], old.dtype)
            new[:old.shape[0]] = old
            setattr(self, name, new)
        fac = np.full(cap, -1, np.int64)
        fac[:self.fac.shape[0]] = self.fac
        self.fac = fac


class _ThetaView:
    """``values.at(k)`` at the linearization point, for Python factors."""

    def __init__(self, store: VariableStore):
        self._s = store

    def at(self, k: Any) -> Any:
        return self._s.theta_value(self._s.slot(k))

    __getitem__ = at

    def __contains__(self, k: object) -> bool:
        return k in self._s.slot_of


@njit(cache=True)
def _local_systems(res, jac, R, code, k, shape, hpool, meta, fac_hoff, slots):
    """Write the local system of each instance ``i`` (see the module docstring) in a new block
    of ``hpool`` whose offset goes to ``fac_hoff[slots[i]]``; returns ``(all finite, hpool)``
    (the pool may have grown). Allocation and writing in one call: an update linearizes one
    to a few factors, where each numba call counts."""
    n, m = res.shape
    D = jac.shape[2]
    r = np.empty(m)
    Jw = np.empty((m, D))
    Hl = np.empty((D, D))
    gl = np.empty(D)
    ok = True
    for i in range(n):
        h, hpool = alloc(hpool, meta, M_HP_TOP, M_HP_HEAD, D * D + D)
        fac_hoff[slots[i]] = h
        asm._local_system(res[i], jac[i], R[i], False, code, k, shape, r, Jw, Hl, gl)
        for a in range(D):
            for b in range(D):
                x = Hl[a, b]
                hpool[h + a * D + b] = x
                if not np.isfinite(x):
                    ok = False
        for a in range(D):
            hpool[h + D * D + a] = gl[a]
            if not np.isfinite(gl[a]):
                ok = False
    return ok, hpool


#: :meth:`FactorStore.linearize`'s "nothing deferred" (empty, of the types it defers)
NO_LINEARIZATION = (np.zeros((0, 1)), np.zeros((0, 1, 1)), np.zeros((0, 1, 1)), 0, 0.0, 0.0,
                    np.zeros(0, np.int64))


class FactorStore:
    def __init__(self, tree: TreeState, variables: VariableStore):
        self.tree = tree
        self.vars = variables
        self.batches: list[_Batch] = []
        self._batch_of: dict[tuple, int] = {}
        self.python: dict[int, Factor] = {}            # slot -> Python factor
        # Python lists (read and written from Python only, one entry at a time)
        self.fac_batch: list[int] = [-2] * 16     # slot -> batch (-1 Python, -2 free)
        self.fac_row: list[int] = [0] * 16
        self.handle_of_slot: list[int] = [-1] * 16
        self.slot_of_handle: dict[int, int] = {}
        self.next_handle = 0
        self.free: list[int] = []
        self.hwm = 0
        self._log: list | None = None
        self._release: tuple | None = None
        self._loss_cache: dict = {}
        self._deferred: tuple | None = None

    # ------------------------------------------------------------------ transactions
    def begin(self) -> None:
        self._log = []

    def rollback(self) -> None:
        for entry in reversed(self._log):
            if entry[0] == "add":
                _, slot, handle, hwm, reused, b, row = entry
                del self.slot_of_handle[handle]
                self.handle_of_slot[slot] = -1
                self.fac_batch[slot] = -2
                self.python.pop(slot, None)
                if b >= 0:
                    batch = self.batches[b]
                    batch.fac[row] = -1
                    batch.free.append(row)
                if reused:
                    self.free.append(slot)
                else:
                    self.hwm = hwm
                self.next_handle = handle
            elif entry[0] == "hoff":
                self._release = None
                _, slots, hoff = entry
                self.tree.fac_hoff[slots] = hoff
        self._log = None

    def end(self) -> None:
        self._log = None
        self._release = None

    def release(self) -> None:
        """Free the blocks of the previous linearizations (after a successful update)."""
        if self._release is not None:
            off, size = self._release
            _pool.free_many(self.tree.hpool, self.tree.meta, M_HP_HEAD, off, size)
            self._release = None

    # ------------------------------------------------------------------ adding / removing
    def __len__(self) -> int:
        return len(self.slot_of_handle)

    def _new_slot(self) -> tuple[int, int, bool]:
        hwm = self.hwm
        if self.free:
            return self.free.pop(), hwm, True
        self.hwm += 1
        slot = hwm
        n = len(self.fac_batch)
        if slot >= n:
            grow = max(n, slot + 1 - n)
            self.fac_batch += [-2] * grow
            self.fac_row += [0] * grow
            self.handle_of_slot += [-1] * grow
        return slot, hwm, False

    def _batch_for(self, kernel: Any, code: int, k: float, shape: float) -> int:
        key = (id(kernel), code, k, shape)
        b = self._batch_of.get(key)
        if b is None:
            kids = []
            for kind in kernel.arg_kinds:
                kid = self.vars._kind_id.get(id(kind))
                kids.append(-1 if kid is None else kid)
            r = kernel.residual_dim
            D = sum(kind.dim for kind in kernel.arg_kinds)
            lin = compiled_linearize(kernel)
            batch = _Batch(kernel, code, k, shape, tuple(kids),
                           np.zeros((16, len(kernel.arg_kinds)), np.int64),
                           np.zeros((16, kernel.num_constants)), np.zeros((16, r, r)),
                           np.full(16, -1, np.int64), linearize=lin, D=D,
                           raw=getattr(lin, "raw", None))
            b = self._batch_of[key] = len(self.batches)
            self.batches.append(batch)
        return b

    def _batch_of_loss(self, kernel: Any, loss: Any) -> tuple[int, np.ndarray]:
        """``(batch, sqrt_information)`` of a kernel factor, cached per (kernel, loss object):
        online factors mostly share a few noise models. The cache holds both objects, so their
        ids cannot be reused while they key an entry."""
        hit = self._loss_cache.get((id(kernel), id(loss)))
        if hit is not None:
            return hit[0], hit[1]
        R, code, k, shape = loss_parts(loss)
        b = self._batch_for(kernel, code, k, shape)
        if len(self._loss_cache) >= 256:
            self._loss_cache.clear()
        self._loss_cache[(id(kernel), id(loss))] = (b, R, kernel, loss)
        return b, R

    def add(self, f: Factor, var_slots: list[int]) -> tuple[int, int]:
        """Store ``f`` over variable slots ``var_slots``; returns ``(slot, handle)``."""
        slot, hwm, reused = self._new_slot()
        handle = self.next_handle
        self.next_handle = handle + 1
        tree = self.tree
        nv = len(var_slots)
        if slot >= tree.FI.shape[1] or nv > tree.kmax:
            tree.ensure_factors(slot + 1, nv)
        fv = tree.fac_vars
        for j, v in enumerate(var_slots):   # (a list into a slice: twice the cost)
            fv[slot, j] = v
        b, row = -1, -1
        kernel = f.kernel
        if kernel is not None:
            hit = self._loss_cache.get((id(kernel), id(f.loss)))
            if hit is not None:
                b, R = hit[0], hit[1]
            else:
                b, R = self._batch_of_loss(kernel, f.loss)
            batch = self.batches[b]
            if batch.free:
                row = batch.free.pop()
            else:
                row = batch.hwm
                batch.hwm += 1
                if row >= batch.fac.shape[0]:
                    batch.grow(batch.hwm)
            bv = batch.var_slots
            for j, v in enumerate(var_slots):
                bv[row, j] = v
            batch.consts[row] = f.constants
            batch.R[row] = R
            batch.fac[row] = slot
            self.fac_row[slot] = row
            FI = tree.FI  # nv, D (hoff comes with the local system, mark and alive are right)
            FI[0, slot], FI[2, slot] = nv, batch.D
        else:
            self.python[slot] = f
            dims = tree.VI[0]
            D = sum([int(dims[v]) for v in var_slots])
            tree.FI[:, slot] = (nv, 0, D, 0, 0)
        self.fac_batch[slot] = b
        self.handle_of_slot[slot] = handle
        self.slot_of_handle[handle] = slot
        if self._log is not None:
            self._log.append(("add", slot, handle, hwm, reused, b, row))
        return slot, handle

    def add_all(self, factors: list[Factor], slot_of: dict) -> tuple[np.ndarray, list, list]:
        """:meth:`add` each of ``factors`` (slots, handles, variable slots concatenated), checked
        on the way (``update`` rolls back on error): keys known, kernel arguments of their kind."""
        new, handles, observed, add = np.empty(len(factors), np.int64), [], [], self.add
        kind_of, fac_batch, batches = self.vars.kind_of, self.fac_batch, self.batches
        for i, f in enumerate(factors):
            try:
                vsl = [slot_of[k] for k in f.keys]
            except KeyError as e:
                raise KeyNotFoundError(f"update: {f.describe()} uses {key_str(e.args[0])}, which "
                                       "is neither a variable of the smoother nor in "
                                       "new_values") from None
            s, h = add(f, vsl)
            b = fac_batch[s]
            if b >= 0:
                kids = batches[b].kids
                for j, v in enumerate(vsl):
                    kid = kind_of.item(v)  # (a Python int: compares faster)
                    if kid != kids[j] or kid < 0:
                        self._check_kinds(batches[b], f, vsl)
                        break
            new[i] = s
            handles.append(h)
            observed += vsl
        return new, handles, observed

    def _check_kinds(self, batch: _Batch, f: Factor, var_slots: list[int]) -> None:
        """Raise ``ManifoldError`` if an argument of ``f`` is not of its kernel's kind; else set
        ``batch.kids`` (kinds new since the batch was made: :meth:`linearize` reads them)."""
        vars_, kinds = self.vars, f.kernel.arg_kinds
        for j, v in enumerate(var_slots):
            kind = vars_.kinds[vars_.kind_of.item(v)] if vars_.kind_of.item(v) >= 0 else None
            if kind is not kinds[j]:
                raise ManifoldError(
                    f"update: {f.describe()} expects {kinds[j].name} for argument {j}, but "
                    f"{key_str(f.keys[j])} is a {getattr(kind, 'name', 'Python-manifold value')}")
        batch.kids = tuple(vars_._kind_id.get(id(kind), -1) for kind in kinds)

    def drop(self, slots: np.ndarray) -> None:
        """Forget factors (after commit removed them from the tree)."""
        for s in slots.tolist():
            handle = self.handle_of_slot[s]
            del self.slot_of_handle[handle]
            self.handle_of_slot[s] = -1
            b = self.fac_batch[s]
            if b >= 0:
                batch = self.batches[b]
                row = self.fac_row[s]
                batch.fac[row] = -1
                batch.free.append(row)
            else:
                self.python.pop(s, None)
            self.fac_batch[s] = -2
            self.free.append(s)

    def factor(self, slot: int) -> Factor:
        """The factor in ``slot`` as a factor object (kernel rows materialized)."""
        from ..factors.base import KernelFactor
        from .. import noise

        b = int(self.fac_batch[slot])
        if b < 0:
            return self.python[slot]
        batch = self.batches[b]
        row = int(self.fac_row[slot])
        keys = [Key(int(self.vars.key_of[v])) for v in batch.var_slots[row]]
        base = noise.Gaussian(batch.R[row])
        loss = base if batch.code == 0 else _robust(batch, base)
        return KernelFactor(batch.kernel, keys, batch.consts[row], loss)

    def describe(self, slot: int) -> str:
        b = int(self.fac_batch[slot])
        keys = ", ".join(self.vars.describe(int(v))
                         for v in self.tree.fac_vars[slot, :self.tree.fac_nv[slot]])
        name = self.batches[b].kernel.name if b >= 0 else type(self.python[slot]).__name__
        return f"{name}({keys})"

    # ------------------------------------------------------------------ linearization
    def linearize(self, slots: np.ndarray, fresh: int, defer: bool = False) -> tuple:
        """(Re)linearize ``slots`` at the current theta into new hpool blocks (logged). The
        first ``fresh`` are new factors; the old blocks of the others are kept until
        :meth:`release` (after the update succeeded).

        ``defer``: the local systems of the last kernel batch are not written; returns
        ``(res, jac, R, code, k, shape, slots)`` for :func:`_local_systems` (the smoother's
        ``tree_update`` writes them: one numba call less per update; a non-finite one is then
        reported by :meth:`raise_nonfinite`), else :data:`NO_LINEARIZATION`."""
        if slots.shape[0] == 0:
            return NO_LINEARIZATION
        tree = self.tree
        if slots.shape[0] > fresh:  # relinearized: their old blocks are freed after success
            old = slots[fresh:]
            hoff = tree.FI[1].take(old)
            D = tree.FI[2].take(old)
            self._release = (hoff, D * D + D)
            if self._log is not None:
                self._log.append(("hoff", old, hoff))
        theta = self.vars.theta
        fac_batch, fac_row = self.fac_batch, self.fac_row
        sl = slots.tolist()
        if len(sl) == 1:  # the common online case: row slices, no fancy indexing
            s = sl[0]
            b = fac_batch[s]
            if b < 0:
                self._linearize_python(s)
                return NO_LINEARIZATION
            batch = self.batches[b]
            r = fac_row[s]
            args = tuple([theta[kid][v:v + 1]
                          for v, kid in zip(batch.var_slots[r].tolist(), batch.kids)])
            return self._run(batch, slots, args, batch.consts[r:r + 1], batch.R[r:r + 1], defer)
        fb = [fac_batch[s] for s in sl]
        if fb.count(fb[0]) == len(fb):     # one batch
            groups = [(fb[0], slots, sl)]
        else:
            fba = np.array(fb, np.int64)
            groups = [(b, slots[fba == b]) for b in sorted(set(fb))]
            groups = [(b, sel, sel.tolist()) for b, sel in groups]
        out = NO_LINEARIZATION
        for i, (b, sel, sell) in enumerate(groups):
            if b < 0:  # (sorted first: the last group is a kernel batch if any is)
                for s in sell:
                    self._linearize_python(s)
                continue
            batch = self.batches[b]
            rows = [fac_row[s] for s in sell]
            n, r0 = len(rows), rows[0]
            if rows == list(range(r0, r0 + n)):  # e.g. new factors: slices (views)
                vs = batch.var_slots[r0:r0 + n]
                consts, R = batch.consts[r0:r0 + n], batch.R[r0:r0 + n]
            else:  # (``take``: a third of fancy indexing's cost on a few rows)
                rows = np.array(rows, np.int64)
                vs = batch.var_slots.take(rows, 0)
                consts, R = batch.consts.take(rows, 0), batch.R.take(rows, 0)
            args = tuple([theta[kid].take(vs[:, j], 0)
                          for j, kid in enumerate(batch.kids)])
            out = self._run(batch, sel, args, consts, R, defer and i == len(groups) - 1)
        return out

    def _run(self, batch: _Batch, sel: np.ndarray, args: tuple, consts: np.ndarray,
             R: np.ndarray, defer: bool = False) -> tuple:
        """Linearize factors ``sel`` of ``batch`` (their gathered arguments, constants and
        square-root informations) into new hpool blocks (``defer``: see :meth:`linearize`)."""
        tree = self.tree
        raw = batch.raw
        if raw is not None:   # the compiled kernel itself (no wrapper per call)
            n = consts.shape[0]
            r, D = batch.linearize.dims
            res = np.empty((n, r))
            jac = np.empty((n, r, D))
            _dispatcher(raw)(*args, consts, res, jac)
        else:
            res, jac = batch.linearize(args, consts)
        if defer:
            self._deferred = (batch, res, jac, sel)
            return res, jac, R, batch.code, batch.k, batch.shape, sel
        ok, tree.hpool = _dispatcher(_local_systems)(res, jac, R, batch.code, batch.k,
                                                     batch.shape, tree.hpool, tree.meta,
                                                     tree.FI[1], sel)
        if not ok:
            self._deferred = (batch, res, jac, sel)
            self.raise_nonfinite()
        return NO_LINEARIZATION

    def raise_nonfinite(self) -> None:
        """Name the factor whose deferred local system was not finite (see :meth:`linearize`)."""
        batch, res, jac, sel = self._deferred
        bad = sel[~np.all(np.isfinite(res), axis=1) |
                  ~np.all(np.isfinite(jac.reshape(jac.shape[0], -1)), axis=1)]
        where = self.describe(int(bad[0])) if bad.shape[0] else batch.kernel.name
        raise NonFiniteError(f"{where} has a non-finite residual or Jacobian at the "
                             "linearization point: check its measurement and variables")

    def _linearize_python(self, slot: int) -> None:
        f = self.python[slot]
        view = _ThetaView(self.vars)
        e = f.checked_error(view)
        J = np.concatenate(f.checked_jacobians(view), axis=1)
        R, code, k, shape = loss_parts(f.loss)
        tree = self.tree
        ok, tree.hpool = _local_systems(e[None], J[None], np.ascontiguousarray(R)[None], code, k,
                                        shape, tree.hpool, tree.meta, tree.FI[1],
                                        np.array([slot], np.int64))
        if not ok:
            raise NonFiniteError(f"{f.describe()}: non-finite local system at the "
                                 "linearization point")

    # ------------------------------------------------------------------ cost
    def cost(self, storages: list[np.ndarray], objects: dict[int, Any]) -> float:
        """``sum rho_i`` at the values ``storages`` (per kind, by slot) / ``objects``."""
        total = 0.0
        for batch in self.batches:
            rows = np.nonzero(batch.fac[:batch.hwm] >= 0)[0]
            if rows.shape[0] == 0:
                continue
            vs = batch.var_slots[rows]
            args = tuple(storages[kid][vs[:, j]] for j, kid in enumerate(batch.kids))
            res = batch.kernel.residual(args, batch.consts[rows])
            total += asm.batch_cost(res, batch.R[rows], False, batch.code, batch.k, batch.shape,
                                    0.0)
        if self.python:
            view = _EstimateView(self.vars, storages, objects)
            for f in self.python.values():
                total += f.cost(view)
        return float(total)


class _EstimateView(_ThetaView):
    def __init__(self, store: VariableStore, storages: list[np.ndarray], objects: dict):
        self._s, self._st, self._obj = store, storages, objects

    def at(self, k: Any) -> Any:
        v = self._s.slot(k)
        kid = int(self._s.kind_of[v])
        if kid < 0:
            return self._obj[v]
        return self._s.kinds[kid].from_storage(self._st[kid][v])

    __getitem__ = at


def _robust(batch: _Batch, base: Any) -> Any:
    from .. import noise

    cls = {1: noise.Huber, 2: noise.Cauchy, 3: noise.Tukey, 4: noise.GemanMcClure}
    if batch.code == 5:
        return noise.Barron(batch.k, batch.shape, base)
    if batch.code not in cls:
        raise FgoptError(f"unknown robust loss code {batch.code}")
    return cls[batch.code](batch.k, base)

