"""Variables of the incremental smoother: keys -> slots, linearization points, estimates.

Each variable has a slot (reused after removal). Values of a batch kind (SE2, SE3, R^n ...)
keep their linearization point ``theta`` in one ``(capacity, storage_dim)`` array per kind,
indexed by slot, so factor kernels gather them without Python per variable; duck-typed
manifolds keep Python objects. The tangent update ``delta`` and the relinearization
thresholds live in the tree state (``TreeState.delta`` / ``thr``), so the estimate is
``theta (+) delta``, retracted per kind in one batched call.

Changes made during an update are logged so a failed update can be rolled back exactly.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import FgoptError, KeyNotFoundError
from ..key import _CHAR_SHIFT, Key, key_char, key_str
from ..manifolds._kernels import retract_rows
from ..manifolds.base import BatchKind, ops_for
from ..variables import Variables, _Rows
from ._state import TreeState


_ROW0 = np.zeros(1, np.int64)


def _take_rows(a: np.ndarray, rows: np.ndarray, d: int) -> np.ndarray:
    """``a[rows, :d]`` as a C-contiguous array (``take``: a third of fancy indexing's cost)."""
    out = a.take(rows, 0)
    return out if d == a.shape[1] else np.ascontiguousarray(out[:, :d])


def _dispatcher(kernel: Any) -> Any:
    """The numba dispatcher of a :class:`fgopt._jit.LazyKernel` once built (calling it directly
    saves the proxy's ~0.7 us per call; the smoother's kernels always run on numba), else
    ``kernel`` itself (first call, or not a lazy kernel)."""
    d = getattr(kernel, "_dispatcher", None)
    return kernel if d is None else d


class VariableStore:
    def __init__(self, tree: TreeState, thresholds: Any):
        self.tree = tree
        self.slot_of: dict[Key, int] = {}
        self.key_of = np.zeros(16, np.int64)
        self.kind_of = np.full(16, -2, np.int64)       # kind id, -1 Python manifold, -2 free
        self.kinds: list[BatchKind] = []
        self._retract: list = []                        # per kind: its batched retract
        self._retract_rows: list = []   # per kind: retract_rows of its Lie group, else None
        self._kind_id: dict[int, int] = {}
        self.theta: list[np.ndarray] = []
        self.est: list[np.ndarray] = []     # per kind: theta (+) delta by slot (see _refresh)
        self.objects: dict[int, Any] = {}
        self.free: list[int] = []
        self.hwm = 0
        self._thresholds = thresholds
        self._thr_rows: dict = {}
        self._vi_new: dict[int, np.ndarray] = {}        # tangent dim -> a new slot's VI column
        self._live: np.ndarray | None = None
        self._log: list | None = None

    # ------------------------------------------------------------------ transactions
    def begin(self) -> None:
        self._log = []

    def rollback(self) -> None:
        for entry in reversed(self._log):
            what = entry[0]
            if what == "add":
                _, k, slot, hwm, reused = entry
                del self.slot_of[k]
                self.kind_of[slot] = -2
                self.tree.var_live[slot] = 0
                self.objects.pop(slot, None)
                if reused:
                    self.free.append(slot)
                else:
                    self.hwm = hwm
            elif what == "delta":
                _, slots, rows = entry
                self.tree.delta[slots] = rows
            elif what == "theta":
                _, kid, slots, rows = entry
                self.theta[kid][slots] = rows
            elif what == "object":
                _, slot, value = entry
                self.objects[slot] = value
        self._log = None
        self._live = None

    def end(self) -> None:
        self._log = None

    # ------------------------------------------------------------------ adding / removing
    def __len__(self) -> int:
        return len(self.slot_of)

    def __contains__(self, k: object) -> bool:
        return k in self.slot_of

    def add(self, k: Key, value: Any, kind: Any = False) -> int:
        """A new variable; ``kind``: its batch kind if known (``None``: a Python manifold)."""
        if kind is False:
            kind = ops_for(value).batch_kind(value)
        free = self.free
        reused = bool(free)
        if reused:
            slot = free.pop()
        else:
            slot = self.hwm
            self.hwm = slot + 1
        if slot >= self.key_of.shape[0]:
            n = max(2 * self.key_of.shape[0], slot + 1)
            self.key_of = np.resize(self.key_of, n)
            kinds = np.full(n, -2, np.int64)
            kinds[:self.kind_of.shape[0]] = self.kind_of
            self.kind_of = kinds
        if self._log is not None:
            self._log.append(("add", k, slot, slot, reused))  # hwm before: the slot if new
        if kind is None:
            kid = -1
            dim = int(ops_for(value).dim(value))
            self.objects[slot] = value
        else:
            kid = self._kind_id.get(id(kind))
            if kid is None:
                kid = self._kind_id[id(kind)] = len(self.kinds)
                self.kinds.append(kind)
                # fancy-indexed rows are C-contiguous float64: the compiled loop needs no checks
                self._retract.append(getattr(kind.retract, "compiled", kind.retract))
                gid = getattr(kind.retract, "gid", None)
                self._retract_rows.append(None if gid is None else retract_rows(gid))
                self.theta.append(np.zeros((max(16, self.key_of.shape[0]), kind.storage_dim)))
                self.est.append(np.zeros_like(self.theta[-1]))
            th = self.theta[kid]
            if slot >= th.shape[0]:
                grown = np.zeros((max(2 * th.shape[0], slot + 1), kind.storage_dim))
                grown[:th.shape[0]] = th
                self.theta[kid] = th = grown
            th[slot] = kind.to_storage(value)
            dim = kind.dim
        self.slot_of[k] = slot
        self.key_of[slot] = k
        self.kind_of[slot] = kid
        tree = self.tree
        if slot >= tree.VI.shape[1] or dim > tree.maxd:
            tree.ensure_vars(slot + 1, dim)
        col = self._vi_new.get(dim)
        if col is None:
            # VI rows: dim, clique, mark, loc, pos, fhead, changed, live, repl, stale, xrepl, out
            col = self._vi_new[dim] = np.array((dim, -1, 0, 0, 0, -1, 0, 1, 0, 1, 0, 0),
                                               np.int64)
        tree.VI[:, slot] = col   # (delta, xdelta, xprop: zero in free slots, see remove)
        ck = (k >> _CHAR_SHIFT, id(kind), dim, tree.maxd)  # the key's character, kind, sizes
        row = self._thr_rows.get(ck)
        if row is None:
            row = self._thr_rows[ck] = self._threshold_row(k, kind, dim, tree.maxd)
        tree.thr[slot] = row
        self._live = None
        return slot

    def remove(self, slots: np.ndarray) -> None:
        """Forget variables (after commit: they are in no clique and no factor)."""
        tree = self.tree
        for v in slots.tolist():
            k = Key(int(self.key_of[v]))
            del self.slot_of[k]
            self.kind_of[v] = -2
            self.objects.pop(v, None)
            tree.var_clique[v] = -1
            tree.var_fhead[v] = -1
            tree.var_live[v] = 0
            tree.delta[v] = 0.0  # as a new slot's (add does not write them)
            tree.xdelta[v] = 0.0
            tree.xprop[v] = 0.0
            self.free.append(v)
        self._live = None

    def _threshold_row(self, k: Key, kind: BatchKind | None, dim: int, width: int) -> np.ndarray:
        thr = self._thresholds
        row = np.full(width, np.inf)
        if isinstance(thr, dict):
            value = thr.get(key_char(k)) if key_char(k) in thr else None
            if value is None and kind is not None:
                value = thr.get(kind.name)
            if value is None:
                value = thr.get("default", np.inf)
        else:
            value = thr
        value = np.broadcast_to(np.asarray(value, dtype=float), (dim,)) if np.ndim(value) == 0 \
            else np.asarray(value, dtype=float)
        if value.shape != (dim,):
            raise FgoptError(f"relinearize_threshold for {key_str(k)} has {value.shape[0]} "
                             f"entries, the variable has tangent dim {dim}")
        row[:dim] = value
        return row

    # ------------------------------------------------------------------ reading
    def slot(self, k: Any) -> int:
        try:
            return self.slot_of[k]
        except (KeyError, TypeError):
            raise KeyNotFoundError(f"{key_str(k) if isinstance(k, int) else k!r} is not a "
                                   "variable of the smoother") from None

    def live_slots(self) -> np.ndarray:
        if self._live is None:
            self._live = np.flatnonzero(self.tree.VI[7, :self.hwm])
        return self._live

    def theta_value(self, slot: int) -> Any:
        kid = int(self.kind_of[slot])
        if kid < 0:
            return self.objects[slot]
        return self.kinds[kid].from_storage(self.theta[kid][slot])

    def estimate_value(self, slot: int) -> Any:
        kid = int(self.kind_of[slot])
        tree = self.tree
        if kid < 0:
            x = self.objects[slot]
            return ops_for(x).retract(x, tree.delta[slot, :int(tree.VI[0, slot])].copy())
        kind = self.kinds[kid]
        rows = self._retract_rows[kid]
        if rows is not None:  # (rows of one-row views: the kernel the cache uses)
            out = np.empty((1, kind.storage_dim))
            _dispatcher(rows)(self.theta[kid][slot:slot + 1], tree.delta[slot:slot + 1], _ROW0,
                              out)
            row = out[0]
        else:
            row = _dispatcher(self._retract[kid])(
                self.theta[kid][slot:slot + 1],
                np.ascontiguousarray(tree.delta[slot:slot + 1, :kind.dim]))[0]
        # retract's output is a fresh row on the manifold: wrap it without re-normalizing
        return kind.wrap(row) if kind.wrap is not None else kind.from_storage(row)

    def _refresh(self, stale: np.ndarray) -> None:
        """Bring the cached ``theta (+) xdelta`` of each batch kind up to date by retracting
        ``stale`` (the variables whose ``xdelta`` or ``theta`` changed since the last call,
        from :func:`._solve.solve_estimate`)."""
        one = len(self.kinds) == 1 and not self.objects
        kinds = None if one else self.kind_of[stale]
        for kid, kind in enumerate(self.kinds):
            th = self.theta[kid]
            est = self.est[kid]
            if est.shape[0] != th.shape[0]:
                grown = np.zeros_like(th)
                grown[:est.shape[0]] = est
                self.est[kid] = est = grown
            rows = stale if one else stale[kinds == kid]
            n = rows.shape[0]
            if n == 0:
                continue
            in_place = self._retract_rows[kid]
            if in_place is not None:  # gather, retract, scatter: one call
                _dispatcher(in_place)(th, self.tree.xdelta, rows, est)
                continue
            new = _dispatcher(self._retract[kid])(th.take(rows, 0),
                                                  _take_rows(self.tree.xdelta, rows, kind.dim))
            if n <= 4:  # (most reads: a row's basic indexing costs less than a scatter)
                for i, v in enumerate(rows.tolist()):
                    est[v] = new[i]
            else:
                est[rows] = new

    def estimate_storages(self, stale: np.ndarray) -> tuple[list[np.ndarray], dict[int, Any]]:
        """``theta (+) xdelta`` of every live variable: one array per kind (indexed by slot;
        the smoother's cache, to read only), and the Python-manifold values."""
        self._refresh(stale)
        objects = {}
        for v, x in self.objects.items():
            objects[v] = ops_for(x).retract(x, self.tree.xdelta[v, :self.tree.var_dim[v]].copy())
        return self.est, objects

    def estimate(self, stale: np.ndarray) -> Variables:
        """``theta (+) xdelta`` of every live variable, as a Variables the caller may keep.

        Values of kinds with ``wrap`` (Lie groups, vectors) go in as one bulk block of fresh,
        read-only storage rows per kind (``Variables.add_rows``'s form), copied from the cache
        :meth:`_refresh` keeps: no Python per variable until the caller reads values, no
        retraction of variables whose ``delta`` did not move, and later updates cannot change
        them. Order: kinds in order of first use, slots ascending within a kind, duck-typed
        values last.
        """
        self._refresh(stale)
        one = len(self.kinds) == 1 and not self.objects
        if one and not self.free and self.hwm:   # every slot below hwm is live: one copy
            kind = self.kinds[0]
            if kind.wrap is not None:
                est = self.est[0][:self.hwm].copy()
                est.setflags(write=False)
                return Variables._of_rows(_Rows(self.key_of[:self.hwm].copy(), kind, est))
        out = Variables()
        live = self.live_slots()
        kinds = None if one else self.kind_of[live]
        for kid, kind in enumerate(self.kinds):
            rows = live if one else live[kinds == kid]
            n = rows.shape[0]
            if n == 0:
                continue
            if rows[n - 1] - rows[0] == n - 1:  # consecutive slots (no removals): plain copies
                est = self.est[kid][rows[0]:rows[0] + n].copy()
                keys = self.key_of[rows[0]:rows[0] + n].copy()
            else:
                est = self.est[kid][rows]
                keys = self.key_of[rows]
            if kind.wrap is not None:
                est.setflags(write=False)
                out._pending.append(_Rows(keys, kind, est))
                continue
            values = out._values  # (turns earlier blocks into values: keeps the order)
            for k, row in zip(keys.tolist(), est):
                values[Key(k)] = kind.from_storage(row)
        if self.objects:
            values = out._values
            for v in live[kinds < 0].tolist():
                x = self.objects[v]
                values[Key(int(self.key_of[v]))] = ops_for(x).retract(
                    x, self.tree.xdelta[v, :self.tree.var_dim[v]].copy())
        return out

    # ------------------------------------------------------------------ relinearization
    def relinearize(self, slots: np.ndarray) -> None:
        """``theta <- theta (+) delta``, ``delta <- 0`` for ``slots`` (logged)."""
        tree = self.tree
        kinds = self.kind_of[slots]
        for kid, kind in enumerate(self.kinds):
            rows = slots[kinds == kid]
            if rows.shape[0] == 0:
                continue
            old = self.theta[kid][rows]
            if self._log is not None:
                self._log.append(("theta", kid, rows, old))
            in_place = self._retract_rows[kid]
            if in_place is not None:
                _dispatcher(in_place)(self.theta[kid], tree.delta, rows, self.theta[kid])
            else:
                self.theta[kid][rows] = kind.retract(old, np.ascontiguousarray(
                    tree.delta[rows, :kind.dim]))
        tree.var_stale[slots] = 1   # theta moved: the estimate retracts them again
        for v in slots[kinds < 0].tolist():
            x = self.objects[v]
            if self._log is not None:
                self._log.append(("object", v, x))
            self.objects[v] = ops_for(x).retract(x, tree.delta[v, :tree.var_dim[v]].copy())
        if self._log is not None:
            self._log.append(("delta", slots, tree.delta[slots].copy()))
        tree.delta[slots] = 0.0

    def describe(self, slot: int) -> str:
        return key_str(int(self.key_of[slot]))
