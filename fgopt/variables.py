"""``Variables``: the values of a factor graph's variables, by key."""

from __future__ import annotations

from collections import Counter
from typing import Any, Iterator

import numpy as np

from .errors import (DimensionMismatchError, DuplicateKeyError, FgoptError, KeyNotFoundError,
                     NonFiniteError)
from .key import Key, as_key, key_str
from .manifolds.base import ops_for


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


class Variables:
    """A map from keys to manifold values (Lie groups, floats, 1-D arrays, custom manifolds).

    >>> v = Variables(); v.add(key('x', 1), SE2.from_xytheta(0, 0, 0)); v.at(key('x', 1))
    """

    __slots__ = ("_values",)

    def __init__(self, values: dict | None = None):
        self._values: dict[Key, Any] = {}
        if values is not None:
            for k, v in values.items():
                self.add(k, v)

    # -- building
    def add(self, k: int, value: Any) -> "Variables":
        """Add a new variable; adding an existing key is an error (use ``update``)."""
        k = as_key(k)
        if k in self._values:
            raise DuplicateKeyError(f"variable {key_str(k)} is already present; use update()")
        ops_for(value)  # raises ManifoldError with advice for non-manifold values
        _check_finite(k, value)
        self._values[k] = _freeze(value)
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
        keys = list(map(Key, key_arr.tolist()))
        if len(keys) != rows.shape[0]:
            raise DimensionMismatchError(f"add_rows: {len(keys)} keys for {rows.shape[0]} rows")
        bad = ~np.all(np.isfinite(rows), axis=1)
        if np.any(bad):
            i = int(np.nonzero(bad)[0][0])
            raise NonFiniteError(f"value of {key_str(keys[i])} has a NaN or inf: {rows[i]}")
        clash = [k for k in keys if k in self._values]
        if clash or len(set(keys)) != len(keys):
            k = clash[0] if clash else next(k for k in keys if keys.count(k) > 1)
            raise DuplicateKeyError(f"variable {key_str(k)} is already present; use update()")
        make = kind.wrap if kind.wrap is not None else kind.from_storage
        values = self._values
        for k, row in zip(keys, rows):
            values[k] = make(row)
        return self

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
        k = as_key(k)
        if k in self._values:
            return self.update(k, value)
        return self.add(k, value)

    # -- reading
    def at(self, k: int) -> Any:
        """The value of key ``k``; a missing key raises ``KeyNotFoundError``."""
        try:
            return self._values[k]
        except KeyError:
            raise KeyNotFoundError(
                f"no variable {key_str(as_key(k))} in Variables ({len(self)} keys): "
                "add it with Variables.add(key, value)") from None
        except TypeError:
            raise KeyNotFoundError(f"{k!r} is not a key") from None

    __getitem__ = at

    def keys(self) -> list[Key]:
        return list(self._values.keys())

    def values(self) -> list[Any]:
        return list(self._values.values())

    def items(self):
        return self._values.items()

    def copy(self) -> "Variables":
        out = Variables()
        out._values = dict(self._values)  # values are immutable or frozen copies
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
        return k in self._values

    def __len__(self) -> int:
        return len(self._values)

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
        return Counter(_type_name(v) for v in self._values.values())

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
                        f"<td><code>{_html_escape(_short(v))}</code></td></tr>")
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


def _html_escape(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
