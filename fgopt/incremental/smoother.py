"""``IncrementalSmoother``: iSAM2-style online smoothing on a Bayes tree of dense cliques.

Each :meth:`IncrementalSmoother.update` does what iSAM2's does (Kaess et al., IJRR 2012):

1. add the new variables (linearization point = the given value, ``delta = 0``) and factors;
2. every ``relinearize_skip`` updates, *fluid relinearization*: variables whose ``delta``
   exceeds the threshold move their linearization point (``theta <- theta (+) delta``) and
   every factor touching them is relinearized;
3. mark the variables of new, removed and relinearized factors; remove the cliques holding
   them and all their ancestors (the *top*); re-order the top's variables (minimum degree,
   the new factors' variables last) and re-eliminate it from the factors inside it plus the
   cached marginals of the orphaned subtrees (:mod:`._eliminate`);
4. back-substitute the new top, and the orphans where their separators moved (wildfire).

The estimate is ``theta (+) delta``. An update is atomic: bad input is refused before
anything changes, and a failure during elimination (a variable left unconstrained) rolls the
smoother back to its state before the call.
"""

from __future__ import annotations

import time
from typing import Any, Iterable

import numpy as np

from ..errors import (DuplicateKeyError, FgoptError, KeyNotFoundError, ManifoldError,
                      NotPositiveDefiniteError)
from ..factors.base import Factor
from ..graph import FactorGraph
from ..key import Key, as_key, key_str
from ..manifolds.base import ops_for
from ..solvers.linear._block_kernels import blas_workspace
from ..variables import Variables
from . import _eliminate, _ordering, _solve, _top
from ._factors import FactorStore
from ._state import (M_CL_HWM, M_CN_GARBAGE, M_CN_TOP, M_CV_GARBAGE, M_CV_TOP, M_HP_GARBAGE,
                     M_HP_TOP, M_NCLIQUES, M_STAMP, TreeState)
from ._values import VariableStore
from .params import IncrementalParams, UpdateResult

_EMPTY = np.zeros(0, np.int64)


class IncrementalSmoother:
    """Online nonlinear least squares: add factors and variables over time, read estimates.

    >>> isam = IncrementalSmoother(IncrementalParams(relinearize_skip=1))
    >>> r = isam.update([PriorFactor(x0, SE2(), noise)], Variables({x0: SE2()}))
    >>> isam.estimate(x0), isam.marginal(x0), isam.cost()
    """

    def __init__(self, params: IncrementalParams | None = None):
        self.params = params if params is not None else IncrementalParams()
        self._tree = TreeState()
        self._vars = VariableStore(self._tree, self.params.relinearize_threshold)
        self._facs = FactorStore(self._tree, self._vars)
        self._count = 0
        self._iw, self._fw = blas_workspace()
        self._nnz = 0
        self._nnz_per_var_ref = 0.0
        self._force_batch = False

    # ================================================================== public API
    def update(self, new_factors: "FactorGraph | Iterable[Factor]" = (),
               new_values: "Variables | dict | None" = None,
               remove: Iterable[int] = ()) -> UpdateResult:
        """Add ``new_factors`` and ``new_values`` (values of keys new to the smoother), remove
        the factors with handles ``remove``, and update the estimate (see the module docstring).

        Raises :class:`~fgopt.FgoptError` (naming the key or factor) and leaves the smoother
        unchanged when a factor uses an unknown key, ``new_values`` repeats a known key, a
        handle in ``remove`` is not a factor of the smoother, or a variable would be left
        unconstrained.
        """
        t0 = time.perf_counter()
        factors = self._check_factors(new_factors)
        values = self._check_values(new_values, factors)
        removed = self._check_remove(remove)
        self._count += 1
        relin = (self.params.enable_relinearization
                 and self._count % int(self.params.relinearize_skip) == 0)
        try:
            result = self._step(factors, values, removed, relin, t0)
        except BaseException:
            self._count -= 1
            raise
        for _ in range(int(self.params.extra_steps)):
            if not self.params.enable_relinearization:
                break
            extra = self._step([], [], _EMPTY, True, time.perf_counter())
            if extra.variables_relinearized == 0:
                break
            result.variables_relinearized += extra.variables_relinearized
            result.variables_reeliminated += extra.variables_reeliminated
            result.factors_relinearized += extra.factors_relinearized
            result.cliques_reeliminated += extra.cliques_reeliminated
            result.cliques_solved += extra.cliques_solved
            result.cliques = extra.cliques
            result.relinearized_keys = np.union1d(result.relinearized_keys,
                                                  extra.relinearized_keys)
        result.timing["total"] = time.perf_counter() - t0
        return result

    def estimate(self, key: Any = None) -> Any:
        """All current estimates as :class:`~fgopt.Variables` (``theta (+) delta``), or the
        value of one ``key``."""
        if key is None:
            return self._vars.estimate()
        return self._vars.estimate_value(self._vars.slot(as_key(key)))

    def linearization_point(self) -> Variables:
        """The values ``theta`` the factors are currently linearized at."""
        out = Variables()
        for k, v in self._vars.slot_of.items():
            out._values[k] = self._vars.theta_value(v)
        return out

    def marginal(self, key: Any) -> np.ndarray:
        """Marginal covariance of ``key`` (its tangent space at the linearization point), from
        the Bayes tree: a walk from the root to the clique holding the variable."""
        v = self._vars.slot(as_key(key))
        t = self._tree
        c = int(t.var_clique[v])
        path = []
        while c > 0:
            path.append(c)
            c = int(t.cl_parent[c])
        path = np.array(path[::-1], np.int64)
        joint = _solve.clique_covariance(path, t.var_dim, t.cvpool, t.cnpool, t.cl_voff,
                                         t.cl_nf, t.cl_ns, t.cl_fdim, t.cl_sdim, t.cl_poff,
                                         t.var_pos)
        p, d = int(t.var_pos[v]), int(t.var_dim[v])
        block = joint[p:p + d, p:p + d]
        return 0.5 * (block + block.T)

    def cost(self) -> float:
        """Total cost ``sum rho_i`` (``0.5 |r|^2`` without robust losses) at the estimate."""
        storages, objects = self._vars.estimate_storages()
        return self._facs.cost(storages, objects)

    def factors(self) -> FactorGraph:
        """The factors currently in the smoother, as a new graph (slow: materializes them)."""
        g = FactorGraph()
        for s in sorted(self._facs.slot_of_handle.values()):
            g.add(self._facs.factor(s))
        return g

    def factor(self, index: int) -> Factor:
        """The factor with handle ``index``."""
        return self._facs.factor(self._check_remove([index])[0])

    def keys(self) -> list[Key]:
        return list(self._vars.slot_of)

    def __len__(self) -> int:
        return len(self._vars)

    def __contains__(self, k: object) -> bool:
        return k in self._vars

    def __repr__(self) -> str:
        return (f"IncrementalSmoother({len(self._vars)} variables, {len(self._facs)} factors, "
                f"{int(self._tree.meta[M_NCLIQUES])} cliques, {self._count} updates)")

    # ================================================================== validation
    def _check_factors(self, new_factors: Any) -> list[Factor]:
        if isinstance(new_factors, FactorGraph):
            factors = list(new_factors)
        elif isinstance(new_factors, Factor):
            factors = [new_factors]
        else:
            factors = list(new_factors)
        for f in factors:
            if not isinstance(f, Factor):
                raise FgoptError(f"update: new_factors must hold Factors, got "
                                 f"{type(f).__name__}")
        return factors

    def _check_values(self, new_values: Any, factors: list[Factor]) -> list[tuple[Key, Any]]:
        if new_values is None:
            items = []
        elif isinstance(new_values, Variables):
            items = list(new_values.items())
        elif isinstance(new_values, dict):
            items = [(as_key(k), v) for k, v in new_values.items()]
        else:
            raise FgoptError(f"update: new_values must be Variables or a dict, got "
                             f"{type(new_values).__name__}")
        known = self._vars.slot_of
        new_kind = {}
        for k, v in items:
            if k in known:
                raise DuplicateKeyError(f"update: {key_str(k)} is already a variable of the "
                                        "smoother; new_values may only hold new keys")
            new_kind[k] = ops_for(v).batch_kind(v)
        touched = set()
        vars_ = self._vars
        for f in factors:
            kinds = f.kernel.arg_kinds if f.kernel is not None else None
            for j, k in enumerate(f.keys):
                slot = known.get(k)
                if slot is None and k not in new_kind:
                    raise KeyNotFoundError(
                        f"update: {f.describe()} uses {key_str(k)}, which is neither a "
                        "variable of the smoother nor in new_values")
                touched.add(k)
                if kinds is not None:
                    if slot is not None:
                        kid = int(vars_.kind_of[slot])
                        kind = vars_.kinds[kid] if kid >= 0 else None
                    else:
                        kind = new_kind[k]
                    if kind is not kinds[j]:
                        raise ManifoldError(
                            f"update: {f.describe()} expects {kinds[j].name} for argument {j}, "
                            f"but {key_str(k)} is a "
                            f"{getattr(kind, 'name', 'Python-manifold value')}")
        for k, _ in items:
            if k not in touched:
                raise NotPositiveDefiniteError(
                    f"update: new variable {key_str(k)} has no factor, so the system would be "
                    "indefinite: add a factor on it in the same update")
        return items

    def _check_remove(self, remove: Iterable[int]) -> np.ndarray:
        slots = []
        seen = set()
        for h in remove:
            if isinstance(h, bool) or not isinstance(h, (int, np.integer)):
                raise FgoptError(f"remove: factor indices are ints (from UpdateResult."
                                 f"new_factor_indices), got {h!r}")
            h = int(h)
            s = self._facs.slot_of_handle.get(h)
            if s is None:
                raise FgoptError(f"remove: factor index {h} is not in the smoother (never "
                                 "added, or already removed)")
            if h in seen:
                raise FgoptError(f"remove: factor index {h} is listed twice")
            seen.add(h)
            slots.append(s)
        return np.array(slots, np.int64)

    # ================================================================== one step
    def _step(self, factors: list[Factor], values: list, removed: np.ndarray, relin: bool,
              t0: float, groups0: np.ndarray | None = None,
              marginalize: np.ndarray | None = None) -> UpdateResult:
        tree, vars_, facs = self._tree, self._vars, self._facs
        p = self.params
        res = UpdateResult()
        timing = res.timing
        meta0 = tree.meta.copy()
        vars_.begin()
        facs.begin()
        try:
            new_slots = np.array([vars_.add(k, x) for k, x in values], np.int64)
            slot_of = vars_.slot_of
            new_facs, handles, obs = [], [], []
            for f in factors:
                vsl = [slot_of[k] for k in f.keys]
                s, h = facs.add(f, vsl)
                new_facs.append(s)
                handles.append(h)
                obs.extend(vsl)
            new_facs = np.array(new_facs, np.int64)
            observed = np.unique(np.array(obs, np.int64))
            res.new_factor_indices = handles
            t1 = time.perf_counter()
            timing["check"] = t1 - t0
            # fluid relinearization
            J = _EMPTY
            if relin:
                J = _solve.relinearize_candidates(vars_.live_slots(), tree.var_dim, tree.delta,
                                                  tree.thr)
            relin_facs = _EMPTY
            relin_vars = _EMPTY
            if J.shape[0]:
                vars_.relinearize(J)
                relin_facs, relin_vars = _top.adjacent(tree.vs, tree.fs, tree.meta, J, removed)
            to_lin = np.concatenate((new_facs, relin_facs)) if relin_facs.shape[0] else new_facs
            facs.linearize(to_lin)
            t2 = time.perf_counter()
            timing["linearize"] = t2 - t1
            # the top
            rem_vars = _top.factor_vars(tree.fs, removed)
            unused = self._unused(rem_vars, removed, observed)
            marked = np.concatenate((new_slots, observed, rem_vars, J, relin_vars))
            if marginalize is not None:
                marked = np.concatenate((marked, marginalize))
            if unused.shape[0]:
                marked = np.setdiff1d(marked, unused)
            live = vars_.live_slots()
            frac = 0.0 if self._force_batch else p.batch_threshold
            T, R, O, FL, batch, stamp = _top.remove_top(
                tree.vs, tree.fs, tree.cs, tree.cvpool, tree.meta, marked, new_facs, removed,
                frac, live if unused.shape[0] == 0 else np.setdiff1d(live, unused))
            if unused.shape[0]:
                T = T[~np.isin(T, unused)]
            t = T.shape[0]
            if groups0 is not None:
                group = groups0(T)
            else:
                group = np.ones(t, np.int64)
                if observed.shape[0] < t:
                    group[np.isin(T, observed)] = 2
            tree.ensure_cliques(int(tree.meta[M_CL_HWM]) + t + 1)
            ap, ai = _top.top_graph(tree.vs, tree.fs, tree.cs, tree.cvpool, T, FL, O)
            order = _ordering.elimination_order(t, ap, ai, group) if t else _EMPTY
            t3 = time.perf_counter()
            timing["order"] = t3 - t2
            if t:
                status, newcl, oparent, T_clique, tree.cvpool, tree.cnpool = \
                    _eliminate.eliminate(tree.vs, tree.fs, tree.cs, tree.meta, tree.cvpool,
                                         tree.cnpool, tree.hpool, T, order, group, ap, ai, FL, O,
                                         p.pivot_tolerance, self._iw, self._fw)
                if status >= 0:
                    raise NotPositiveDefiniteError(
                        f"update: {vars_.describe(int(status))} is not constrained by its "
                        "factors (the system is indefinite); the update was not applied")
            else:
                newcl = oparent = T_clique = _EMPTY
            t4 = time.perf_counter()
            timing["eliminate"] = t4 - t3
            tree.ensure_adjacency(int(tree.fac_nv[new_facs].sum()) if new_facs.shape[0] else 0)
        except BaseException:
            stamp_now = tree.meta[M_STAMP]
            tree.meta[:] = meta0
            tree.meta[M_STAMP] = stamp_now
            facs.rollback()
            vars_.rollback()
            raise
        # ---------------------------------------------------------------- commit
        self._nnz += _top.panel_entries(tree.cs, newcl) - _top.panel_entries(tree.cs, R)
        _top.commit(tree.vs, tree.fs, tree.cs, tree.meta, R, newcl, O, oparent, T, T_clique,
                    removed, new_facs)
        if removed.shape[0]:
            facs.drop(removed)
        if unused.shape[0]:
            res.removed_keys = [Key(int(vars_.key_of[v])) for v in unused]
            vars_.remove(unused)
        vars_.end()
        facs.end()
        tree.meta[M_STAMP] += 1
        res.cliques_solved = _solve.backsolve(tree.vs, tree.cs, tree.cvpool, tree.cnpool, newcl,
                                              O, p.wildfire_threshold, tree.meta[M_STAMP])
        timing["solve"] = time.perf_counter() - t4
        n = len(vars_)
        if batch or self._force_batch:
            self._nnz_per_var_ref = self._nnz / max(n, 1)
            self._force_batch = False
        elif n > 64 and self._nnz > p.fill_refresh * self._nnz_per_var_ref * n:
            self._force_batch = True
        self._maybe_compact()
        res.variables_relinearized = int(J.shape[0])
        res.relinearized_keys = vars_.key_of[J] if J.shape[0] else _EMPTY
        res.variables_reeliminated = t
        res.factors_relinearized = int(to_lin.shape[0])
        res.cliques_reeliminated = int(newcl.shape[0])
        res.cliques = int(tree.meta[M_NCLIQUES])
        res.batch = bool(batch)
        return res

    def _unused(self, rem_vars: np.ndarray, removed: np.ndarray,
                observed: np.ndarray) -> np.ndarray:
        """Variables that removing ``removed`` leaves without factors (they are dropped)."""
        if rem_vars.shape[0] == 0:
            return _EMPTY
        counts = _top.remaining_factors(self._tree.vs, self._tree.fs, self._tree.meta, rem_vars,
                                        removed)
        out = rem_vars[(counts == 0) & ~np.isin(rem_vars, observed)]
        return np.unique(out)

    def _maybe_compact(self) -> None:
        """Copy live data to the front of the pools when garbage exceeds the live data."""
        t = self._tree
        m = t.meta
        if (m[M_HP_GARBAGE] > 4096 and 2 * m[M_HP_GARBAGE] > m[M_HP_TOP]) or \
                (m[M_CN_GARBAGE] > 4096 and 2 * m[M_CN_GARBAGE] > m[M_CN_TOP]) or \
                (m[M_CV_GARBAGE] > 4096 and 2 * m[M_CV_GARBAGE] > m[M_CV_TOP]):
            t.hpool, t.cnpool, t.cvpool = _top.compact(t.vs, t.fs, t.cs, t.meta, t.hpool,
                                                       t.cnpool, t.cvpool)

