"""``Variables``: the values of a factor graph's variables, by key."""

from __future__ import annotations

import html
from collections import Counter
from typing import Any, Iterator

import numpy as np

from .errors import (DimensionMismatchError, DuplicateKeyError, FgoptError, KeyNotFoundError,
                     NonFiniteError)
from .key import Key, as_key, key_str
from .manifolds.base import SCALAR_KIND, BatchKind, ops_for
from .manifolds.declared import DeclaredValue, declared_type
from .manifolds.lie import LieGroup


def _freeze(value: Any) -> Any:
    """Store a private, read-only copy of arrays so callers cannot alias our values."""
    if isinstance(value, np.ndarray):
        v = np.array(value, dtype=float)
        v.setflags(write=False)
        return v
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return float(value)
    return value


def _check_finite(k: Key, value: Any) -> None:
    ops = ops_for(value)
    try:
        data = ops.to_storage(value)
    except Exception:  # duck-typed manifolds have no storage; nothing to check
        return
    if not np.all(np.isfinite(data)):
        raise NonFiniteError(f"value of {key_str(k)} has a NaN or inf: {value!r}")


#: Bulk blocks of at most this many rows answer ``Variables.at`` from their value objects, all
#: made on the first read (a loop of reads over a file's 808 poses: 4.4 ms by searchsorted, ~0.4
#: ms so); larger ones (a BA problem's points) search their sorted keys and stay compact.
_INDEXED_ROWS = 100_000
_ABSENT = object()


class _Rows:
    """Values added in bulk by ``add_rows`` and not yet turned into one object per key."""

    __slots__ = ("keys", "kind", "rows", "_sorted", "_objects", "_row_of")

    def __init__(self, keys: np.ndarray, kind: Any, rows: np.ndarray):
        self.keys, self.kind, self.rows = keys, kind, rows
        self._sorted: tuple[np.ndarray, np.ndarray] | None = None
        self._objects: dict[int, Any] | None = None
        self._row_of: dict[int, int] | None = None

    def objects(self) -> dict[int, Any]:
        """key -> value object of every row, made on first use (``wrap_all``: no Python frame
        per row); the rows stay, for the compiled problem's bulk path."""
        if self._objects is None:
            self._objects = dict(zip(self.keys.tolist(), self.kind.wrap_all(self.rows)))
        return self._objects

    def row_index(self) -> dict[int, int] | None:
        """key -> row, made on first use, for blocks of at most ``_INDEXED_ROWS`` rows (None for
        larger ones): a few keys looked up from Python at ~0.1 us each instead of ~7 us for a
        call of :meth:`find`."""
        if self._row_of is None and self.keys.shape[0] <= _INDEXED_ROWS:
            self._row_of = dict(zip(self.keys.tolist(), range(self.keys.shape[0])))
        return self._row_of

    def find(self, keys: np.ndarray) -> np.ndarray:
        """Row of each of ``keys`` in this block, -1 where absent."""
        if self._sorted is None:
            order = np.argsort(self.keys, kind="stable")
            self._sorted = (self.keys[order], order)
        sk, order = self._sorted
        at = np.minimum(np.searchsorted(sk, keys), max(sk.shape[0] - 1, 0))
        hit = sk[at] == keys if sk.shape[0] else np.zeros(keys.shape[0], dtype=bool)
        return np.where(hit, order[at], -1)


class Variables:
    """A map from keys to manifold values (Lie groups, floats, 1-D arrays, custom manifolds).

    >>> fgopt.Variables().add(key('x', 1), fgopt.SE2.from_xytheta(0, 0, 0)).at(key('x', 1))
    SE2(x=0.000, y=0.000, theta=0.000)

    Vector values added in bulk (:meth:`add_rows`, what the file readers use) stay in their
    ``(n, d)`` array until per-key objects are needed: a million BA points then cost 24 bytes
    each instead of ~250, and the compiled problem takes their storage rows without a Python
    step per variable.
    """

    __slots__ = ("_dict", "_pending")

    def __init__(self, values: dict | None = None):
        self._dict: dict[Key, Any] = {}
        self._pending: list[_Rows] = []  # after every entry of _dict, in insertion order
        if values is not None:
            for k, v in values.items():
                self.add(k, v)

    @classmethod
    def _of_rows(cls, block: "_Rows") -> "Variables":  # (a solver's result: no __init__)
        out = object.__new__(cls)
        out._dict, out._pending = {}, [block]
        return out

    @property
    def _values(self) -> dict[Key, Any]:
        """The map key -> value (bulk rows are turned into per-key values first)."""
        if self._pending:
            self._materialize()
        return self._dict

    def _materialize(self) -> None:
        for blk in self._pending:
            objs = blk._objects
            self._dict.update(zip(map(Key, blk.keys.tolist()),
                                  blk.kind.wrap_all(blk.rows) if objs is None else objs.values()))
        self._pending = []

    def __getstate__(self) -> dict:
        # One float64 array per kind instead of one pickled object per value (a worker's result
        # of 3500 poses: ~1 ms instead of ~30); see _pack.
        return _pack(self)

    def __setstate__(self, state: dict) -> None:
        if "values" in state:  # per-value form (keys past int64)
            self._dict, self._pending = state["values"], []
            return
        _unpack(self, state)

    # -- building
    def add(self, k: int, value: Any) -> "Variables":
        """Add a new variable; adding an existing key is an error (use ``update``)."""
        k = as_key(k)
        if k in self._values:
            raise DuplicateKeyError(f"variable {key_str(k)} is already present; use update()")
        ops_for(value)  # raises ManifoldError with advice for non-manifold values
        _check_finite(k, value)
        self._dict[k] = _freeze(value)
        return self

    def add_rows(self, keys, kind, rows: np.ndarray) -> "Variables":
        """Bulk-add ``n`` values of one batch kind from storage rows ``(n, storage_dim)``.

        The vectorized path for file readers: finiteness and duplicates are checked once for all
        rows; rows must already lie on the manifold (unit quaternions, unit (cos, sin)).
        """
        rows = np.array(rows, dtype=float).reshape(-1, kind.storage_dim)
        rows.flags.writeable = False
        key_arr = np.asarray(list(keys) if not isinstance(keys, np.ndarray) else keys)
        if key_arr.size and (key_arr.dtype.kind not in "iu" or key_arr.min() < 0):
            raise FgoptError(f"add_rows: keys must be non-negative ints, got {key_arr[:3]}...")
        key_arr = key_arr.astype(np.int64).reshape(-1)
        if key_arr.shape[0] != rows.shape[0]:
            raise DimensionMismatchError(
                f"add_rows: {key_arr.shape[0]} keys for {rows.shape[0]} rows")
        bad = ~np.all(np.isfinite(rows), axis=1)
        if np.any(bad):
            i = int(np.nonzero(bad)[0][0])
            raise NonFiniteError(f"value of {key_str(Key(int(key_arr[i])))} has a NaN or inf: "
                                 f"{rows[i]}")
        srt = np.sort(key_arr)
        dup = srt[1:][srt[1:] == srt[:-1]]
        clash = self._present(key_arr)
        if dup.shape[0] or clash.any():
            k = int(key_arr[np.argmax(clash)]) if clash.any() else int(dup[0])
            raise DuplicateKeyError(f"variable {key_str(Key(k))} is already present; use update()")
        if kind.wrap is not None:  # vector kinds: the row is the value (kept as an array)
            self._pending.append(_Rows(key_arr, kind, rows))
            return self
        values = self._values
        for k, row in zip(map(Key, key_arr.tolist()), rows):
            values[k] = kind.from_storage(row)
        return self

    def _present(self, keys: np.ndarray) -> np.ndarray:
        """Which of ``keys`` (int64 array) already have a value."""
        out = np.zeros(keys.shape[0], dtype=bool)
        if self._dict:
            have = np.fromiter(self._dict.keys(), dtype=np.int64, count=len(self._dict))
            out |= np.isin(keys, have)
        for blk in self._pending:
            out |= blk.find(keys) >= 0
        return out

    def _find_rows(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each of ``keys``: the index of the bulk block holding it (-1: not in one) and its
        row there. Does not turn bulk rows into objects."""
        block = np.full(keys.shape[0], -1, dtype=np.int64)
        row = np.full(keys.shape[0], -1, dtype=np.int64)
        for b, blk in enumerate(self._pending):
            r = blk.find(keys)
            hit = r >= 0
            block[hit], row[hit] = b, r[hit]
        return block, row

    def update(self, k: int, value: Any) -> "Variables":
        """Replace the value of an existing variable (same manifold and dimension)."""
        k = as_key(k)
        old = self.at(k)
        ops_old, ops_new = ops_for(old), ops_for(value)
        if type(old) is not type(value) and not (
                isinstance(old, float) and isinstance(value, (float, int, np.floating))):
            raise DimensionMismatchError(
                f"update of {key_str(k)}: new value is a {type(value).__name__}, "
                f"the variable is a {type(old).__name__}")
        if ops_old.dim(old) != ops_new.dim(value):
            raise DimensionMismatchError(
                f"update of {key_str(k)}: dimension {ops_new.dim(value)} != {ops_old.dim(old)}")
        _check_finite(k, value)
        self._values[k] = _freeze(value)
        return self

    def insert_or_assign(self, k: int, value: Any) -> "Variables":
        return self.update(k, value) if as_key(k) in self else self.add(k, value)

    # -- reading
    def at(self, k: int) -> Any:
        """The value of key ``k``; a missing key raises ``KeyNotFoundError``."""
        try:
            x = self._dict.get(k, _ABSENT)
        except TypeError:
            raise KeyNotFoundError(f"{k!r} is not a key") from None
        if x is not _ABSENT:
            return x
        for blk in self._pending:  # blocks read before: their objects, by key (not bools)
            if blk._objects is not None:
                x = blk._objects.get(k, _ABSENT)
                if x is not _ABSENT and type(k) is not bool:
                    return x
        if (self._pending and isinstance(k, (int, np.integer)) and not isinstance(k, bool)
                and 0 <= k < 2 ** 63):
            k = int(k)
            for blk in self._pending:
                if blk.keys.shape[0] <= _INDEXED_ROWS:
                    x = (blk._objects or blk.objects()).get(k, _ABSENT)
                    if x is not _ABSENT:
                        return x
                    continue
                r = int(blk.find(np.array([k], dtype=np.int64))[0])
                if r >= 0:
                    return blk.kind.wrap(blk.rows[r])
        raise KeyNotFoundError(f"no variable {key_str(as_key(k))} in Variables ({len(self)} "
                               "keys): add it with Variables.add(key, value)")

    __getitem__ = at

    def keys(self) -> list[Key]:
        return list(self._values.keys())

    def keys_of_kinds(self, kinds) -> np.ndarray:
        """Keys (int64) whose values have a batch kind in ``kinds``; bulk rows are judged by
        their block's kind, without turning them into per-key values (``keys()`` would)."""
        out = [blk.keys for blk in self._pending if blk.kind in kinds]
        per_key = [int(k) for k, x in self._dict.items() if ops_for(x).batch_kind(x) in kinds]
        return np.concatenate(out + [np.array(per_key, dtype=np.int64)])

    def values(self) -> list[Any]:
        return list(self._values.values())

    def items(self):
        return self._values.items()

    def copy(self) -> "Variables":
        out = Variables()
        out._dict = dict(self._dict)  # values are immutable or frozen copies
        out._pending = list(self._pending)  # bulk rows are read-only: shared
        return out

    def dim(self) -> int:
        """Total tangent dimension."""
        return sum(ops_for(v).dim(v) for v in self._values.values())

    def retract(self, deltas: dict) -> "Variables":
        """A new Variables with ``x (+) delta`` for each ``key -> delta`` in ``deltas``."""
        out = self.copy()
        for k, d in deltas.items():
            x = self.at(k)
            out._values[as_key(k)] = _freeze(ops_for(x).retract(x, np.asarray(d, dtype=float)))
        return out

    def __contains__(self, k: object) -> bool:
        if k in self._dict:
            return True
        if not self._pending or not isinstance(k, (int, np.integer)) or isinstance(k, bool):
            return False
        q = np.array([int(k)], dtype=np.int64) if 0 <= int(k) < 2 ** 63 else None
        return q is not None and any(blk.find(q)[0] >= 0 for blk in self._pending)

    def __len__(self) -> int:
        return len(self._dict) + sum(blk.keys.shape[0] for blk in self._pending)

    def __iter__(self) -> Iterator[Key]:
        return iter(self._values)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Variables) or self.keys() != other.keys():
            return NotImplemented if not isinstance(other, Variables) else False
        for k, v in self._values.items():
            w = other._values[k]
            ops = ops_for(v)
            if np.abs(ops.local(v, w)).max(initial=0.0) > 1e-12:
                return False
        return True

    def type_counts(self) -> Counter:
        """Values per type name; bulk rows by their block's kind (no per-key objects made)."""
        counts = Counter(_type_name(v) for v in self._dict.values())
        for b in (b for b in self._pending if b.keys.shape[0]):
            counts[_type_name(b.kind.wrap_all(b.rows[:1])[0])] += b.keys.shape[0]
        return counts

    def __repr__(self) -> str:
        counts = ", ".join(f"{n} {t}" for t, n in self.type_counts().most_common())
        head = f"Variables({len(self)} keys: {counts})" if len(self) else "Variables(empty)"
        lines = [head]
        items = list(self._values.items())
        show = items if len(items) <= 8 else items[:4] + [None] + items[-3:]
        for item in show:
            if item is None:
                lines.append(f"  ... {len(items) - 7} more")
                continue
            k, v = item
            lines.append(f"  {key_str(k)}: {_short(v)}")
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        rows = []
        items = list(self._values.items())
        for k, v in items[:20]:
            rows.append(f"<tr><td><code>{key_str(k)}</code></td><td>{_type_name(v)}</td>"
                        f"<td><code>{html.escape(_short(v), quote=False)}</code></td></tr>")
        more = f"<tr><td colspan=3>... {len(items) - 20} more</td></tr>" if len(items) > 20 else ""
        counts = ", ".join(f"{n} {t}" for t, n in self.type_counts().most_common())
        return (f"<b>Variables</b> ({len(self)} keys: {counts})<table>"
                "<tr><th>key</th><th>type</th><th>value</th></tr>"
                + "".join(rows) + more + "</table>")


def _type_name(v: Any) -> str:
    if isinstance(v, np.ndarray):
        return f"R{v.shape[0]}"
    if isinstance(v, float):
        return "float"
    return type(v).__name__


def _short(v: Any) -> str:
    if isinstance(v, np.ndarray):
        return np.array2string(v, precision=4, suppress_small=True, max_line_width=100)
    if isinstance(v, float):
        return f"{v:.6g}"
    return repr(v)


# ----------------------------------------------------------------------------- pickling
#
# A pickled Variables is its keys (int64), each value's kind index, one contiguous float64
# storage array per kind and, for values without a storage layout (duck-typed, subclasses, NumPy
# scalars), the values themselves. Values of kinds with ``wrap`` load as bulk rows (``_Rows``):
# no Python object per value until one is read. Rows are the values' storage bit for bit (no
# normalization on either side).

#: Above this many runs of one kind (values of interleaved kinds), loading builds per-key values
#: at once: every bulk block costs a search in ``at``.
_MAX_LAZY_BLOCKS = 16


def _runs(a: np.ndarray, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Start indices and lengths of the runs of ``a`` where each entry is the previous + step."""
    if a.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    cut = np.flatnonzero(np.diff(a) != step) + 1
    starts = np.concatenate([[0], cut])
    return starts, np.diff(np.concatenate([starts, [a.shape[0]]]))


def _encode(a: np.ndarray, step: int) -> Any:
    """``a`` as ``(first values, run lengths, step)`` when that is smaller (consecutive keys,
    long runs of one kind), else as itself."""
    starts, lengths = _runs(a, step)
    if 2 * starts.shape[0] < a.shape[0]:
        return a[starts], lengths, step
    return a


def _decode(enc: Any) -> np.ndarray:
    if isinstance(enc, np.ndarray):
        return enc.astype(np.int64, copy=False)
    firsts, lengths, step = enc
    offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    n = int(lengths.sum())
    return (np.repeat(firsts.astype(np.int64), lengths)
            + step * (np.arange(n, dtype=np.int64) - np.repeat(offsets, lengths)))


def _storage_rows(values: list, kind: BatchKind) -> np.ndarray:
    """The ``(n, storage_dim)`` storage of ``values`` (all of one packable type)."""
    first = values[0]
    if isinstance(first, np.ndarray):
        return np.stack(values)
    if isinstance(first, float):
        return np.array(values, dtype=np.float64).reshape(-1, 1)
    if isinstance(first, (LieGroup, DeclaredValue)):
        return np.stack([x._data for x in values])
    return np.stack([kind.to_storage(x) for x in values])


def _packable_kind(x: Any) -> BatchKind | None:
    """The kind whose storage row rebuilds ``x`` exactly (same type, same bits), or ``None``."""
    t = type(x)
    if t is float:
        return SCALAR_KIND
    kind = ops_for(x).batch_kind(x)  # every stored value has traits (add checks)
    if kind is None or kind.wrap is None:
        return None
    if t is np.ndarray:
        return kind if x.ndim == 1 and x.dtype == np.float64 else None
    row = np.array(_storage_rows([x], kind)[0], dtype=np.float64)
    row.flags.writeable = False
    back = kind.wrap(row)
    same = type(back) is t and np.array_equal(kind.to_storage(back), row)
    return kind if same else None


def _kind_token(kind: BatchKind) -> Any:
    """How a kind travels: declared ones as their declaration (the receiver derives or loads it),
    the others by name (BatchKind.__reduce__)."""
    cls = declared_type(kind)
    return kind if cls is None else ("declared", cls._spec.twin)


def _kind_of_token(token: Any) -> BatchKind:
    return token if isinstance(token, BatchKind) else token[1].Value.batch_kind()


def _pack(v: Variables) -> dict:
    d = v._dict
    try:
        dkeys = np.fromiter(d.keys(), dtype=np.int64, count=len(d))
    except OverflowError:  # keys past int64 (fgopt's own keys never are): one by one
        return {"values": v._values}
    kinds: list[BatchKind] = []
    index: dict[int, int] = {}          # id(kind) -> kind index
    of_type: dict[Any, int] = {}        # value type (arrays: and shape) -> kind index, -1: none
    members: list[list] = []            # per kind index: the dict's values of that kind
    objects: list = []                  # values pickled one by one
    tags = []

    def number(kind: BatchKind | None) -> int:
        if kind is None:
            return -1
        if id(kind) not in index:
            index[id(kind)] = len(kinds)
            kinds.append(kind)
            members.append([])
        return index[id(kind)]

    for x in d.values():
        t = type(x)
        tk = (t, x.shape, x.dtype.str) if t is np.ndarray else t
        k = of_type.get(tk)
        if k is None:
            k = of_type[tk] = number(_packable_kind(x))
        tags.append(k)
        (members[k] if k >= 0 else objects).append(x)
    rows: list[list[np.ndarray]] = [[_storage_rows(m, kinds[k])] if m else []
                                    for k, m in enumerate(members)]
    tag_parts = [np.array(tags, dtype=np.int64)]
    for blk in v._pending:
        k = number(blk.kind)
        if k == len(rows):
            rows.append([])
        rows[k].append(blk.rows)
        tag_parts.append(np.full(blk.keys.shape[0], k, dtype=np.int64))
    tag = np.concatenate(tag_parts)
    tag[tag < 0] = len(kinds)  # per-value objects: the last index
    keys = np.concatenate([dkeys] + [blk.keys for blk in v._pending])
    small = tag.astype(np.min_scalar_type(len(kinds)))
    return {"keys": _encode(keys, 1), "kinds": _encode(small, 0),
            "kind_tokens": [_kind_token(k) for k in kinds],
            "rows": [np.concatenate(r) if len(r) > 1 else r[0] for r in rows],
            "objects": objects}


def _unpack(v: Variables, state: dict) -> None:
    keys = _decode(state["keys"])
    tag = _decode(state["kinds"])
    kinds = [_kind_of_token(t) for t in state["kind_tokens"]]
    rows = state["rows"]
    for r in rows:
        r.flags.writeable = False  # owned by this unpickling; values wrap views of it
    lazy = np.array([k.wrap is not None for k in kinds] + [False])
    # the longest tail of bulk-row kinds goes to _pending (after the dict, as iteration order
    # requires), one block per run of one kind
    eager = np.flatnonzero(~lazy[tag])
    split = int(eager[-1]) + 1 if eager.shape[0] else 0
    starts, lengths = _runs(tag[split:], 0)
    if starts.shape[0] > _MAX_LAZY_BLOCKS:
        split, starts, lengths = tag.shape[0], starts[:0], lengths[:0]
    head = tag[:split]
    used = [int(np.count_nonzero(head == k)) for k in range(len(kinds))]
    made = []
    for k, kind in enumerate(kinds):
        part = rows[k][:used[k]]
        made.append(iter(part[:, 0].tolist() if kind.wrap is None else kind.wrap_all(part)))
    made.append(iter(state["objects"]))
    v._dict = dict(zip(map(Key, keys[:split].tolist()), (next(made[t]) for t in head.tolist())))
    v._pending = []
    cursor = used
    for s, n in zip((starts + split).tolist(), lengths.tolist()):
        k = int(tag[s])
        v._pending.append(_Rows(keys[s:s + n], kinds[k], rows[k][cursor[k]:cursor[k] + n]))
        cursor[k] += n
