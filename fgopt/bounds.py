"""What the optimizer may move: constant variables, constant coordinates and bounds.

``optimize(graph, initial, constant=..., bounds=...)`` compiles into a :class:`Restrictions`:

* a **constant variable** leaves the tangent space: H and g are built over the other variables
  only (:meth:`fgopt.problem.Problem._build_structure`), so every linear solver, the Schur
  complement included, factors a smaller system. Its factors still count in the cost.
* a **constant coordinate** (``constant={key: [i, j]}``, Ceres' ``SubsetManifold``) of a vector,
  scalar or calibration variable keeps its row and column in H, decoupled: its off-diagonal
  entries and its gradient entry are zeroed after each linearization, so its step is zero.
* a **bound** ``bounds={key: (lower, upper)}`` (``-inf`` / ``inf`` per coordinate) on such a
  variable is kept by a projected LM with an active set: a coordinate at a bound whose gradient
  pushes outward is held like a constant coordinate for that step, the others are solved for,
  the step is projected onto the box, and the gain ratio uses the model decrease of the
  projected step (Bertsekas' projected Newton, with LM's accept / reject around it).

Values held constant are restored from the previous iterate after every retraction: they stay
bit for bit. Coordinates are tangent coordinates; for vectors and calibrations they are the
leading storage coordinates (``Cal3_S2``: ``fx, fy, s, u0, v0``; ``Cal3Bundler``: ``f, k1, k2``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import FgoptError
from .key import Key, as_key, key_str
from .manifolds.base import is_vector_kind


def additive(kind: Any) -> bool:
    """Whether ``kind``'s retraction adds the step to its leading ``dim`` storage coordinates
    (vectors, scalars, calibrations): the kinds coordinates can be held or bounded on."""
    if kind is None:
        return False
    if is_vector_kind(kind):
        return True
    from .cameras import _calib_kernels as CK

    return kind.retract is CK.vector_retract or kind.retract is CK.bundler_retract


def _constant_items(constant: Any) -> list[tuple[Key, Any]]:
    """``[(key, None | indices)]`` of a ``constant`` argument (keys, or a dict key -> indices,
    ``None`` / ``True`` / ``"all"`` meaning the whole variable)."""
    if constant is None:
        return []
    if isinstance(constant, dict):
        out = []
        for k, v in constant.items():
            whole = v is None or v is True or (isinstance(v, str) and v == "all")
            out.append((as_key(k), None if whole else v))
        return out
    if isinstance(constant, (int, np.integer)):
        return [(as_key(constant), None)]
    try:
        return [(as_key(k), None) for k in constant]
    except TypeError:
        raise FgoptError("constant must be a list of keys or a dict key -> coordinate "
                         f"indices, got {type(constant).__name__}") from None


def _indices(k: Key, v: Any, dim: int) -> np.ndarray:
    try:
        idx = np.asarray(v)
        if idx.dtype == bool:
            raise TypeError
        idx = idx.astype(np.int64, casting="safe").reshape(-1)
    except (TypeError, ValueError):
        raise FgoptError(f"constant coordinates of {key_str(k)} must be integer indices, got "
                         f"{v!r}") from None
    bad = idx[(idx < 0) | (idx >= dim)]
    if bad.shape[0]:
        raise FgoptError(f"constant coordinate {int(bad[0])} of {key_str(k)} is out of range: "
                         f"the variable has {dim} coordinates (0..{dim - 1})")
    return np.unique(idx)


def _bound(k: Key, side: str, v: Any, dim: int) -> np.ndarray:
    try:
        a = np.array(v, dtype=float)
    except (TypeError, ValueError):
        raise FgoptError(f"{side} bound of {key_str(k)} is not numeric: {v!r}") from None
    if a.ndim == 0:
        a = np.full(dim, float(a))
    if a.shape != (dim,):
        raise FgoptError(f"{side} bound of {key_str(k)} has shape {a.shape}: the variable has "
                         f"{dim} coordinates (give {dim} numbers or one)")
    if np.isnan(a).any():
        raise FgoptError(f"{side} bound of {key_str(k)} is NaN at coordinate "
                         f"{int(np.flatnonzero(np.isnan(a))[0])}")
    return a


class Restrictions:
    """The constant variables, constant coordinates and bounds of a compiled problem.

    Made from the problem's variables (``var_keys`` ... ``kinds``) and the user's ``constant`` /
    ``bounds``; raises :class:`~fgopt.FgoptError` naming the key for a key that is not a
    variable, a coordinate out of range, bounds of the wrong length, ``lower > upper``, bounds
    or coordinates on a variable that is not a vector, or an initial value outside its bounds
    (as Ceres and SciPy, which reject an infeasible start).
    """

    def __init__(self, problem: Any, constant: Any, bounds: Any):
        V = problem.var_keys.shape[0]
        self.const_var = np.zeros(V, dtype=bool)
        self.coords: list[tuple[int, np.ndarray]] = []  # (variable, coordinates held)
        self.bounds: list[tuple[int, np.ndarray, np.ndarray]] = []  # (variable, lower, upper)
        var_of = problem._var_of_key
        extra = problem._extra
        for k, v in _constant_items(constant):
            var = self._variable(problem, k, "constant", var_of, extra)
            if var is None:
                continue  # a value no factor uses: returned unchanged anyway
            if v is None:
                self.const_var[var] = True
                continue
            kind = self._additive_kind(problem, var, k, "constant coordinates")
            idx = _indices(k, v, kind.dim)
            if idx.shape[0] == kind.dim:
                self.const_var[var] = True
            elif idx.shape[0]:
                self.coords.append((var, idx))
        if bounds is not None:
            if not isinstance(bounds, dict):
                raise FgoptError("bounds must be a dict key -> (lower, upper), got "
                                 f"{type(bounds).__name__}")
            for k, lu in bounds.items():
                k = as_key(k)
                var = self._variable(problem, k, "bounds", var_of, extra)
                try:
                    lo, up = lu
                except (TypeError, ValueError):
                    raise FgoptError(f"bounds of {key_str(k)} must be a pair (lower, upper), "
                                     f"got {lu!r}") from None
                if var is None:
                    continue
                kind = self._additive_kind(problem, var, k, "bounds")
                lo, up = _bound(k, "lower", lo, kind.dim), _bound(k, "upper", up, kind.dim)
                bad = np.flatnonzero(lo > up)
                if bad.shape[0]:
                    i = int(bad[0])
                    raise FgoptError(f"bounds of {key_str(k)}: lower {lo[i]:g} > upper {up[i]:g} "
                                     f"at coordinate {i}")
                x = problem._initial_storages[problem.var_kind[var]][problem.var_row[var]]
                x = x[:kind.dim]
                out = np.flatnonzero((x < lo) | (x > up))
                if out.shape[0]:
                    i = int(out[0])
                    raise FgoptError(
                        f"the initial value of {key_str(k)} is outside its bounds at coordinate "
                        f"{i}: {x[i]:g} not in [{lo[i]:g}, {up[i]:g}] (start from a feasible "
                        "value, e.g. np.clip(x, lower, upper))")
                if np.isinf(lo).all() and np.isinf(up).all():
                    continue
                self.bounds.append((var, lo, up))
        # held coordinates and bounds of a constant variable: nothing to do
        self.coords = [(v, c) for v, c in self.coords if not self.const_var[v]]
        self.bounds = [(v, lo, up) for v, lo, up in self.bounds if not self.const_var[v]]

    @staticmethod
    def _variable(problem: Any, k: Key, what: str, var_of: dict, extra: Any) -> int | None:
        var = var_of.get(k)
        if var is not None:
            return var
        if k in extra:
            return None
        raise FgoptError(f"{what}: {key_str(k)} is not a variable (it is not in the initial "
                         "values)")

    @staticmethod
    def _additive_kind(problem: Any, var: int, k: Key, what: str) -> Any:
        kid = int(problem.var_kind[var])
        kind = problem.kinds[kid] if kid >= 0 else None
        if not additive(kind):
            name = kind.name if kind is not None else type(problem._extra.at(k)).__name__
            raise FgoptError(f"{what} on {key_str(k)}: it is a {name}, not a vector-valued "
                             "variable (vectors, scalars and calibrations take coordinate "
                             "bounds and constant coordinates; hold a whole variable with "
                             f"constant=[{key_str(k)}])")
        return kind

    def __bool__(self) -> bool:
        return bool(self.const_var.any() or self.coords or self.bounds)

    @property
    def has_bounds(self) -> bool:
        return bool(self.bounds)

    def free_variables(self) -> np.ndarray | None:
        """The variables left in the tangent space (None: all of them)."""
        if not self.const_var.any():
            return None
        return np.flatnonzero(~self.const_var)

    # ------------------------------------------------------------------ after the structure
    def attach(self, problem: Any) -> None:
        """Tangent indices and storage positions of the held and bounded coordinates, once the
        problem's tangent layout (``problem.var_offset``) is known."""
        off, N = problem.var_offset, problem.pattern.size
        self.N = N
        kinds = problem.var_kind
        # whole constant variables: their storage rows per kind (restored after a retraction)
        self.const_rows = []
        for kid in range(len(problem.kinds)):
            vs = problem._kind_vars[kid]
            self.const_rows.append(problem.var_row[vs[self.const_var[vs]]])
        self.const_objects = [int(v) for v in problem._slow_vars if self.const_var[v]]

        def where(items):
            var = np.concatenate([np.full(c.shape[0], v, np.int64) for v, c in items])
            coord = np.concatenate([c for _, c in items])
            return off[var] + coord, kinds[var], problem.var_row[var], coord

        self.held = where(self.coords) if self.coords else None
        if self.held is not None:
            self._held_mask = self._entry_mask(problem.pattern, self.held[0])
        if self.bounds:
            items = [(v, np.arange(lo.shape[0])) for v, lo, _ in self.bounds]
            self.bt, self.bkind, self.brow, self.bcoord = where(items)
            self.lower = np.concatenate([lo for _, lo, _ in self.bounds])
            self.upper = np.concatenate([up for _, _, up in self.bounds])
            keep = ~(np.isinf(self.lower) & np.isinf(self.upper))
            self.bt, self.bkind, self.brow, self.bcoord, self.lower, self.upper = (
                a[keep] for a in (self.bt, self.bkind, self.brow, self.bcoord, self.lower,
                                  self.upper))
        #: the bounded coordinates held at the last linearization (tangent indices)
        self.active = np.zeros(0, np.int64)

    @staticmethod
    def _entry_mask(pattern: Any, t: np.ndarray) -> np.ndarray:
        """Data positions of H's off-diagonal entries in rows or columns ``t``."""
        N = pattern.size
        on = np.zeros(N, dtype=bool)
        on[t] = True
        rows = pattern.row_indices()
        cols = np.repeat(np.arange(N), np.diff(pattern.indptr))
        return np.flatnonzero((on[rows] | on[cols]) & (rows != cols))

    def _bound_values(self, state: Any) -> np.ndarray:
        x = np.empty(self.bt.shape[0])
        for kid in np.unique(self.bkind).tolist():
            m = self.bkind == kid
            x[m] = state.storages[kid][self.brow[m], self.bcoord[m]]
        return x

    def clamp(self, problem: Any, state: Any, H: np.ndarray, g: np.ndarray) -> None:
        """Hold the constant coordinates and the active bounds of ``state`` in the
        linearization ``(H, g)``: their off-diagonal entries and gradient set to zero (a zero
        or negative diagonal to one), so their step is exactly zero."""
        held = self.held[0] if self.held is not None else None
        mask = self._held_mask if self.held is not None else None
        if self.bounds:
            x = self._bound_values(state)
            gb = g[self.bt]
            # at a bound with the descent direction -g pointing out of the box
            act = ((x <= self.lower) & (gb > 0)) | ((x >= self.upper) & (gb < 0))
            self.active = self.bt[act]
            if self.active.shape[0]:
                held = self.active if held is None else np.concatenate([held, self.active])
                mask = self._entry_mask(problem.pattern, held)
        if held is None or held.shape[0] == 0:
            return
        H[mask] = 0.0
        dp = problem.pattern.diag_pos[held]
        d = H[dp]
        H[dp] = np.where(d > 0.0, d, 1.0)
        g[held] = 0.0

    def at_bounds(self, problem: Any, state: Any) -> list[tuple[Key, int, str]]:
        """``(key, coordinate, "lower" | "upper")`` of every bounded coordinate of ``state``
        sitting on its bound."""
        if not self.bounds:
            return []
        x = self._bound_values(state)
        var = problem.var_keys
        out = []
        off_var = {int(problem.var_offset[v]): v for v, _, _ in self.bounds}
        for side, hit in (("lower", x <= self.lower), ("upper", x >= self.upper)):
            for t, c in zip(self.bt[hit].tolist(), self.bcoord[hit].tolist()):
                out.append((Key(int(var[off_var[t - c]])), int(c), side))
        return out

    def project_step(self, problem: Any, state: Any, delta: np.ndarray,
                     predicted: float) -> tuple[np.ndarray, float]:
        """``delta`` projected so ``x + delta`` stays in the box, and the model decrease
        ``-(g.d + 0.5 d.H.d)`` of the projected step (``predicted`` when nothing moved)."""
        x = self._bound_values(state)
        t = x + delta[self.bt]
        clipped = np.clip(t, self.lower, self.upper)
        if np.array_equal(clipped, t):
            return delta, predicted
        d = delta.copy()
        d[self.bt] = clipped - x
        g, H = problem.g, problem.H_data
        Hd = problem.pattern.matvec(H, d)
        return d, -float(g @ d + 0.5 * (d @ Hd))

    def restore(self, old: Any, storages: list[np.ndarray], objects: dict) -> None:
        """After a retraction: constant values and coordinates copied back from ``old`` (bit
        for bit), bounded coordinates clipped into their box."""
        for kid, rows in enumerate(self.const_rows):
            if rows.shape[0]:
                storages[kid][rows] = old.storages[kid][rows]
        for v in self.const_objects:
            objects[v] = old.objects[v]
        if self.held is not None:
            _, hk, hr, hc = self.held
            for kid in np.unique(hk).tolist():
                m = hk == kid
                storages[kid][hr[m], hc[m]] = old.storages[kid][hr[m], hc[m]]
        if self.bounds:
            for kid in np.unique(self.bkind).tolist():
                m = self.bkind == kid
                S = storages[kid]
                S[self.brow[m], self.bcoord[m]] = np.clip(S[self.brow[m], self.bcoord[m]],
                                                          self.lower[m], self.upper[m])
