"""What the fixed formulation reads from a graph: variables, factor types, inputs, structure key.

Consecutive factors of one symbolic type and variable pattern form a *run*: ``(n, k)`` variable
indices, ``(n, c)`` constants and ``(n, r * r)`` structurally non-zero square-root-information
masks. A graph's batches (file readers' ``graph.add_batch``) become runs as arrays, without a
factor object per row: on an 11-pose file this collection is what a warm solve spends most of
its time in otherwise (~0.5 ms of ~0.74 by materializing rows, vs ~0.05 ms now). The structure
key hashes the runs, so the same factors added one by one or as a batch share a module.

:class:`~fgopt.solvers.fixed._codegen.FactorSpec` (one per factor, for the derivation) and the
factor objects (for error messages) are made only when asked for.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from itertools import accumulate
from typing import Any

import numpy as np

from ...errors import FgoptError
from ...key import Key, key_str
from ...symbolic import cache as _cache
from ._codegen import FIXED_CODEGEN_VERSION, FactorSpec, VarSpec

_GIDS = {"SO2": 0, "SE2": 1, "SO3": 2, "SE3": 3, "Sim3": 4}
_FINGERPRINTS: dict = {}
#: (id(kernel), factor class) -> (kernel, info): resolving a kernel's symbolic type takes ~80 us
_KERNEL_INFO: dict = {}


def resolve(f: Any) -> tuple:
    """(SymbolicFactorType, variable pattern) of a factor, or raise FgoptError."""
    from ...factors.library.prior_between import BetweenFactor, PriorFactor
    from ...factors.decorator import KERNEL_ORIGINS, SymbolicFactor

    if isinstance(f, SymbolicFactor) and not isinstance(f, (BetweenFactor, PriorFactor)):
        ft = f.factor_type
        for pattern, k in ft._kernels.items():
            if k is f.kernel:
                return ft, pattern
        raise FgoptError(f"fixed formulation: {f.describe()}: kernel not found on its type")
    origin = KERNEL_ORIGINS.get(id(f.kernel)) if f.kernel is not None else None
    if origin is not None and not isinstance(f, (BetweenFactor, PriorFactor)):
        return origin[1], origin[2]  # e.g. a BAL reader row: the generated bal_reprojection
    if isinstance(f, (BetweenFactor, PriorFactor)) and f.kernel is not None:
        # built-ins: the hand-written kernel or the generated twin, same residual and constants
        from ...factors.library import generated as gen
        from ...factors.library import lie_kernels

        kind = f.kernel.arg_kinds[0]
        between = isinstance(f, BetweenFactor)
        try:
            types = gen._types_for(kind, "between" if between else "prior")
        except Exception:  # noqa: BLE001 - no symbolic twin (e.g. Sim3)
            types = None
        if types is not None:
            ft = types[0] if between else types[1]
            pattern = (True, True, False) if between else (True, False)
            hand = lie_kernels.between_kernel if between else lie_kernels.prior_kernel
            try:
                is_hand = f.kernel is hand(kind)
            except Exception:  # noqa: BLE001
                is_hand = False
            if is_hand or any(k is f.kernel for k in ft._kernels.values()):
                return ft, pattern
    raise FgoptError(
        f"fixed formulation: {f.describe()} is not supported: every factor must be an "
        "@fgopt.factor (symbolic) factor or a built-in BetweenFactor/PriorFactor")


def fingerprint(ft: Any) -> str:
    fp = _FINGERPRINTS.get(id(ft))
    if fp is None or fp[0] is not ft:
        from ...symbolic.ops import type_key

        h = hashlib.sha256(ft.fingerprint.encode())
        h.update(repr((ft.name, tuple((n,) + type_key(tp) for n, tp in ft.params),
                       ft.method, ft.engine)).encode())
        fp = _FINGERPRINTS[id(ft)] = (ft, h.hexdigest())
    return fp[1]


@dataclass
class Run:
    """Consecutive factors of one type and pattern (see the module docstring)."""

    ftype: Any
    pattern: tuple
    residual_dim: int
    var_idx: np.ndarray   # (n, k) graph variable index of each variable argument
    num_consts: int
    wmask: np.ndarray     # (n, r * r) bool, row-major
    sources: list         # per part: a list of factors, or (batch, first row, last row + 1)


@dataclass
class Collected:
    keys: list
    kinds: list
    runs: list
    x0: np.ndarray  # storage of every variable at the values read, in variable order
    storage_off: np.ndarray  # (V + 1,) variable v's storage is x0[storage_off[v]:storage_off[v+1]]
    tangent_off: np.ndarray  # (V + 1,)
    kind_no: np.ndarray  # (V,) index into kind_specs
    kind_specs: list  # per distinct kind: (gid, storage dim, tangent dim, retract code)
    consts: np.ndarray
    wvals: np.ndarray
    key: str

    @property
    def variables(self) -> list:
        """One :class:`VarSpec` per variable (for the derivation and diagnostics)."""
        out = []
        for v, kn in enumerate(self.kind_no.tolist()):
            gid, sd, td, code = self.kind_specs[kn]
            out.append(VarSpec(gid, sd, td, int(self.storage_off[v]), int(self.tangent_off[v]),
                               code))
        return out

    @property
    def num_factors(self) -> int:
        return sum(r.var_idx.shape[0] for r in self.runs)

    @property
    def factors(self) -> list:
        """One :class:`FactorSpec` per factor, in graph order (offsets into consts / wvals)."""
        out, coff, woff = [], 0, 0
        for run in self.runs:
            counts = run.wmask.sum(axis=1).tolist()
            for idx, mask, nw in zip(run.var_idx.tolist(), run.wmask.tolist(), counts):
                out.append(FactorSpec(run.ftype, run.pattern, tuple(idx), coff, run.num_consts,
                                      run.residual_dim, tuple(mask), woff))
                coff += run.num_consts
                woff += nw
        return out

    @property
    def sources(self) -> list:
        """The factor objects, in ``factors`` order (batch rows materialized)."""
        out: list = []
        for run in self.runs:
            for part in run.sources:
                if isinstance(part, list):
                    out.extend(part)
                else:
                    b, lo, hi = part
                    out.extend(b.factor(i) for i in range(lo, hi))
        return out


class _Collector:
    def __init__(self, values: Any):
        self.values = values
        self.var_of: dict = {}
        self.keys: list = []
        self.kinds: list = []
        self.runs: list = []  # (ftype, pattern, r, c, [idx], [mask], [source]) per run
        self.consts: list = []
        self.wvals: list = []
        self.where: list = []  # per variable: its value, or (bulk block, row)
        self.kind_by_type: dict = {}
        self.kind_by_block: dict = {}
        self.per_noise: dict = {}   # id(loss) -> (mask (1, r*r), nonzero values, loss)

    def kernel_info(self, kernel: Any, first: Any, cls: type) -> tuple:
        hit = _KERNEL_INFO.get((id(kernel), cls))
        if hit is not None and hit[0] is kernel:
            return hit[1]
        from ...factors.decorator import batch_kind_of

        ft, pattern = resolve(first())
        var_kinds = [batch_kind_of(tp) for (_, tp), v in zip(ft.params, pattern) if v]
        info = (ft, pattern, var_kinds, kernel.residual_dim)
        _KERNEL_INFO[(id(kernel), cls)] = (kernel, info)
        return info

    def variable(self, k: int, describe: Any) -> int:
        """The index of variable ``k`` (numbered in order of first use)."""
        v = self.var_of.get(k)
        if v is not None:
            return v
        values = self.values
        x = values._dict.get(k)
        if x is not None:
            kind, where = self.kind_of(x), x
        else:  # a bulk block's row (file readers' Variables.add_rows)
            where = None
            if values._pending and 0 <= k < 2 ** 63:
                block, row = values._find_rows(np.array([k], dtype=np.int64))
                where = (int(block[0]), int(row[0])) if block[0] >= 0 else None
            if where is None:
                raise FgoptError(f"fixed formulation: {describe()} uses {key_str(k)}, "
                                 "which is not in the initial values")
            kind = self.block_kind(where[0])
        if kind is None:
            raise FgoptError(f"fixed formulation: {key_str(k)} is a "
                             f"{type(values.at(k)).__name__} (no batch kind)")
        return self.new_variable(k, kind, where)

    def new_variable(self, k: int, kind: Any, where: Any) -> int:
        """Number variable ``k``; ``where``: its value, or ``(block, row)`` of a bulk block."""
        v = self.var_of[k] = len(self.keys)
        self.keys.append(Key(k))
        self.kinds.append(kind)
        self.where.append(where)
        return v

    def add_variables(self, new: list, describe: Any) -> None:
        """Number the keys ``new`` (not seen before, in order of first use): at once when all
        are rows of small bulk blocks (a file's values), else key by key."""
        pending = self.values._pending
        indexes = [blk.row_index() for blk in pending]
        located, kinds = [], []
        if all(index is not None for index in indexes):
            for k in new:
                for b, index in enumerate(indexes):
                    r = index.get(k)
                    if r is not None:
                        located.append((b, r))
                        kinds.append(self.block_kind(b))
                        break
                else:
                    break
        if len(located) < len(new) or any(kind is None for kind in kinds):
            for k in new:
                self.variable(k, lambda k=k: describe(k))
            return
        n0 = len(self.keys)
        self.var_of.update(zip(new, range(n0, n0 + len(new))))
        self.keys.extend(map(Key, new))
        self.kinds.extend(kinds)
        self.where.extend(located)

    def kind_of(self, x: Any) -> Any:
        from ...manifolds.base import ops_for

        t = type(x) if type(x) is not np.ndarray else (np.ndarray, x.shape)
        kind = self.kind_by_type.get(t, self)
        if kind is self:
            kind = self.kind_by_type[t] = ops_for(x).batch_kind(x)
        return kind

    def block_kind(self, b: int) -> Any:
        """The batch kind of a bulk block's values (the kind the per-key path would find)."""
        kind = self.kind_by_block.get(b, self)
        if kind is self:
            blk = self.values._pending[b]
            kind = self.kind_by_block[b] = self.kind_of(blk.kind.wrap(blk.rows[0]))
        return kind

    def check_kinds(self, idx: np.ndarray, var_kinds: list, key_at: Any, describe: Any) -> None:
        """Raise naming the first row whose ``j``-th variable is not of ``var_kinds[j]``
        (``key_at(row, j)``: that variable's key, for the message)."""
        kinds = self.kinds
        for j, want in enumerate(var_kinds):
            column = idx[:, j].tolist()
            for v in set(column):
                if kinds[v] is not want:
                    row = column.index(v)
                    raise FgoptError(
                        f"fixed formulation: {describe(row)}: {key_str(key_at(row, j))} is a "
                        f"{kinds[v].name}, the factor expects {want.name}")

    def append(self, info: tuple, idx: np.ndarray, consts: np.ndarray, mask: np.ndarray,
               wvals: np.ndarray, source: Any) -> None:
        ft, pattern, _, r = info
        last = self.runs[-1] if self.runs else None
        if last is None or last[0] is not ft or last[1] != pattern:
            last = (ft, pattern, r, consts.shape[1], [], [], [])
            self.runs.append(last)
        last[4].append(idx)
        last[5].append(mask)
        last[6].append(source)
        self.consts.append(consts.reshape(-1))
        self.wvals.append(wvals)

    def factors(self, fs: list) -> None:
        """Individually added factors, a run of consecutive ones of one kernel at a time."""
        kernels = [f.kernel for f in fs]
        classes = list(map(type, fs))
        starts = [0] + [i for i in range(1, len(fs)) if kernels[i] is not kernels[i - 1]
                        or classes[i] is not classes[i - 1]] + [len(fs)]
        for i, j in zip(starts[:-1], starts[1:]):
            if i < j:
                self.factor_run(fs[i:j])

    def noise_of(self, f: Any, r: int) -> tuple:
        """(mask (1, r*r), non-zero entries of R) of a factor's noise model, or raise for a
        robust loss; one entry per noise model object (factors usually share a few)."""
        loss = f.loss
        w = self.per_noise.get(id(loss))
        if w is None:
            from ...noise.models import LOSS_NONE, loss_code_and_param

            if loss_code_and_param(loss)[0] != LOSS_NONE:
                raise FgoptError(f"fixed formulation: {f.describe()} has a robust loss; only "
                                 "Gaussian noise models are supported")
            R = np.asarray(f.noise.sqrt_information, dtype=float)
            if R.shape != (r, r):
                R = R * np.eye(r) if R.size == 1 else R.reshape(r, r)
            mask = R != 0.0
            w = self.per_noise[id(loss)] = (mask.reshape(1, -1), R[mask], loss)
        return w

    def factor_run(self, fs: list) -> None:
        f0 = fs[0]
        info = self.kernel_info(f0.kernel, lambda: f0, type(f0))
        var_of = self.var_of
        key_lists = [f.keys for f in fs]
        flat = [k for keys in key_lists for k in keys]
        for k in dict.fromkeys(flat):
            if k not in var_of:
                self.variable(k, fs[flat.index(k) // len(f0.keys)].describe)
        m = len(fs)
        idx = np.array([var_of[k] for k in flat], dtype=np.int64).reshape(m, -1)
        self.check_kinds(idx, info[2], lambda row, j: fs[row].keys[j],
                         lambda row: fs[row].describe())
        losses = [f.loss for f in fs]
        first: dict = {}  # id(loss) -> the first factor with it
        for loss, f in zip(losses, fs):
            first.setdefault(id(loss), f)
        ws = {i: self.noise_of(f, info[3]) for i, f in first.items()}
        if len(ws) == 1:
            w = next(iter(ws.values()))
            mask = np.broadcast_to(w[0], (m, w[0].shape[1]))
            wv = np.tile(w[1], m)
        else:
            noises = [ws[id(loss)] for loss in losses]
            mask = np.concatenate([w[0] for w in noises])
            wv = np.concatenate([w[1] for w in noises])
        consts = np.concatenate([f.constants for f in fs]).reshape(m, -1)
        self.append(info, idx, consts, mask, wv, list(fs))

    def batch(self, b: Any) -> None:
        n = len(b)
        if n == 0:
            return
        info = self.kernel_info(b.kernel, lambda: b.factor(0), type(b))

        def describe(row: int) -> str:
            return f"{b.factor(row).describe()} (factor {b._where(row)})"

        if b.loss_code != 0:
            raise FgoptError(f"fixed formulation: {describe(0)} has a robust loss; only "
                             "Gaussian noise models are supported")
        keys = b.keys
        # variables numbered in order of first use, as one factor at a time would number them
        flat = keys.reshape(-1).tolist()
        var_of = self.var_of
        new = [k for k in dict.fromkeys(flat) if k not in var_of]
        if new:
            self.add_variables(new, lambda k: describe(flat.index(k) // keys.shape[1]))
        idx = np.array([var_of[k] for k in flat], dtype=np.int64).reshape(keys.shape)
        self.check_kinds(idx, info[2], lambda row, j: int(keys[row, j]), describe)
        r = info[3]
        R = b.sqrt_information
        if R is None:
            mask = np.broadcast_to(np.eye(r, dtype=bool).reshape(1, -1), (n, r * r))
            wv = np.ones(n * r)
        else:
            flatR = R.reshape(n, r * r)
            mask = flatR != 0.0
            wv = flatR[mask]
        self.append(info, idx, b.constants, mask, wv, (b, 0, n))

    def finish(self) -> Collected:
        if not self.runs:
            raise FgoptError("fixed formulation: the factor graph is empty")
        runs = [Run(ft, pattern, r, np.concatenate(idx), c, np.concatenate(mask), src)
                for ft, pattern, r, c, idx, mask, src in self.runs]
        h = hashlib.sha256()
        for run in runs:
            h.update(repr((fingerprint(run.ftype), run.pattern, run.num_consts,
                           run.residual_dim, run.var_idx.shape)).encode())
            h.update(np.ascontiguousarray(run.var_idx).tobytes())
            h.update(np.packbits(run.wmask).tobytes())
        # the distinct kinds once (a problem has one to three), then per variable as arrays
        distinct: dict = {}  # id(kind) -> (number, kind, gid, retract code)
        for kind in self.kinds:
            if id(kind) not in distinct:
                distinct[id(kind)] = (len(distinct), kind) + _group_of(kind)
        numbers = [distinct[id(k)][0] for k in self.kinds]
        kind_no = np.array(numbers, dtype=np.int64)
        table = list(distinct.values())
        h.update(repr([(k.name, k.dim, k.storage_dim, k.key) for _, k, _, _ in table]).encode())
        h.update(kind_no.tobytes())
        soff = [0, *accumulate(table[n][1].storage_dim for n in numbers)]
        toff = [0, *accumulate(table[n][1].dim for n in numbers)]
        x0 = np.empty(soff[-1])
        per_block: dict = {}  # bulk block -> ([variable], [row]): gathered as arrays
        for v, where in enumerate(self.where):
            if type(where) is tuple:
                vs_rows = per_block.setdefault(where[0], ([], []))
                vs_rows[0].append(v)
                vs_rows[1].append(where[1])
            else:
                x0[soff[v]:soff[v + 1]] = self.kinds[v].to_storage(where)
        pending = self.values._pending
        for blk, (vs, rows) in per_block.items():
            block = pending[blk]
            if len(vs) == len(numbers):  # every variable from this block (a file's poses)
                x0 = block.rows[rows].reshape(-1)
                continue
            d = block.rows.shape[1]
            x0[np.add.outer(np.array(soff)[vs], np.arange(d))] = block.rows[rows]
        specs = [(gid, k.storage_dim, k.dim, code) for _, k, gid, code in table]
        h.update(_cache.package_fingerprint().encode())
        h.update(FIXED_CODEGEN_VERSION.encode())
        return Collected(self.keys, self.kinds, runs, x0, np.array(soff), np.array(toff),
                         kind_no, specs,
                         np.concatenate(self.consts), np.concatenate(self.wvals),
                         h.hexdigest()[:20])


def _group_of(kind: Any) -> tuple:
    """(gid, retract code) of a variable kind for the generated code, or raise FgoptError."""
    from ...manifolds.base import is_vector_kind
    from ...manifolds.declared import declared_type

    declared = declared_type(kind)
    if declared is not None:
        return -2, declared._spec.retract_code
    gid = _GIDS.get(kind.name, -1)
    if gid < 0 and not is_vector_kind(kind):
        raise FgoptError(f"fixed formulation: variables of kind {kind.name} are not supported")
    return gid, None


def collect(graph: Any, values: Any) -> Collected:
    """Read ``graph`` at ``values`` for the fixed formulation (raises FgoptError naming the
    first factor it cannot take)."""
    c = _Collector(values)
    c.factors(graph.factors)
    for b in graph.batches:
        c.batch(b)
    return c.finish()
