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
4. back-substitute, deferred as in iSAM2 to the next read of the estimate (or the next
   relinearization check): the re-eliminated cliques, and the orphans whose separators moved
   by more than the wildfire threshold (:func:`._solve.solve_pending`).

The estimate is ``theta (+) delta``. An update is atomic: bad input is refused before
anything changes, and a failure during elimination (a variable left unconstrained) rolls the
smoother back to its state before the call. ``marginalize`` cuts variables out into Gaussian
priors on their Markov blanket (the fixed-lag smoother's step).

Design, measured against the alternative the issue allowed (an incremental supernodal
Cholesky on a fixed global order, new variables appended): iSAM2's reordering of the top is
what keeps loop closures cheap (a chronological order of a pose graph fills in badly), so the
engine is a Bayes tree, kept as flat arrays and numba kernels: multifrontal dense cliques
(fundamental supernodes of the top's elimination tree, reusing the block Cholesky's symbolic
steps and BLAS bindings), each caching the Schur complement it passes to its parent.
"""

from __future__ import annotations

import time
from typing import Any, Iterable

import numpy as np

from ..errors import (DuplicateKeyError, FgoptError, KeyNotFoundError,
                      NotPositiveDefiniteError)
from ..factors.base import Factor
from ..graph import FactorGraph
from ..key import Key, as_key, key_str
from ..manifolds.base import ops_for
from ..solvers.linear._block_kernels import blas_workspace
from ..variables import Variables
from . import _constants, _marginal, _ordering, _pool, _solve, _top, _update
from ._factors import FactorStore
from ._state import M_CL_HWM, M_HP_HEAD, M_HP_TOP, M_NCLIQUES, M_STAMP, VI_OUT, TreeState
from ._values import VariableStore, _dispatcher
from .linear_container import LinearContainerFactor
from .params import IncrementalParams, UpdateResult

_EMPTY = np.zeros(0, np.int64)
#: ``estimate()`` re-solves a subtree when a separator variable moved by more than this (tangent
#: units) since the subtree was last solved, or by more than ``wildfire_threshold`` if smaller.
ESTIMATE_TOLERANCE = 1e-9
#: Clock of ``UpdateResult.timing`` (wall time; benchmarks may swap in a CPU clock).
_clock = time.perf_counter


class IncrementalSmoother:
    """Online nonlinear least squares: add factors and variables over time, read estimates.

    >>> from fgopt import SE2, BetweenFactor, PriorFactor
    >>> from fgopt.incremental import IncrementalParams, IncrementalSmoother
    >>> from fgopt.noise import Isotropic
    >>> noise, step = Isotropic.sigma(3, 0.1), SE2.from_xytheta(1.0, 0.0, 0.0)
    >>> isam = IncrementalSmoother(IncrementalParams(relinearize_skip=1))
    >>> r = isam.update([PriorFactor(key('x', 0), SE2(), noise)], {key('x', 0): SE2()})
    >>> r = isam.update([BetweenFactor(key('x', 0), key('x', 1), step, noise)],
    ...                 {key('x', 1): SE2.from_xytheta(0.9, 0.1, 0.0)})   # a rough guess
    >>> isam.estimate(key('x', 1)).equals(step, 1e-9), isam.cost() < 1e-20
    (True, True)
    >>> np.round(np.diag(isam.marginal(key('x', 1))), 6)   # [x, y, theta] variances
    array([0.02    , 0.020125, 0.028125])
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
        self._dirty = False
        self._constants: dict = {}  # key -> value held constant (update(constant=...))
        #: Cliques back-substituted by the last (deferred) solve, and by the last estimate().
        self.last_solve_cliques = 0
        self.last_estimate_cliques = 0

    def _solve(self) -> None:
        """Bring ``delta`` up to date (iSAM2 defers back-substitution to the next read)."""
        if self._dirty:
            t = self._tree
            vs, _, cs = t.tuples()
            self.last_solve_cliques = _dispatcher(_solve.solve_pending)(
                vs, cs, t.cvpool, t.cnpool, float(self.params.wildfire_threshold), t.meta)
            self._dirty = False

    def _solve_estimate(self) -> np.ndarray:
        """Bring the estimate's ``xdelta`` up to date (:func:`._solve.solve_estimate`), and
        ``delta`` (:meth:`_solve`) in the same call; returns the variables to retract again."""
        t = self._tree
        wildfire = float(self.params.wildfire_threshold)
        vs, _, cs = t.tuples()
        self.last_estimate_cliques, n, solved = _dispatcher(_solve.solve_estimate)(
            vs, cs, t.cvpool, t.cnpool, t.xdelta, t.xprop, min(wildfire, ESTIMATE_TOLERANCE),
            t.meta, self._dirty, wildfire)
        if solved >= 0:
            self.last_solve_cliques = solved
            self._dirty = False
        return t.VI[VI_OUT, :n]

    # ================================================================== public API
    def update(self, new_factors: "FactorGraph | Iterable[Factor]" = (),
               new_values: "Variables | dict | None" = None,
               remove: Iterable[int] = (), constant: Iterable[Any] = ()) -> UpdateResult:
        """Add ``new_factors`` and ``new_values`` (values of keys new to the smoother), remove
        the factors with handles ``remove``, and update the estimate (see the module docstring).

        ``constant``: keys of ``new_values`` held fixed from now on (e.g. a map one localizes
        against): they never enter the smoother's system, so they cost nothing in the solve,
        and keep their values bit for bit (``estimate`` returns them); factors over them, in
        this update and later ones, become factors over their other keys (kernel factors only;
        :mod:`._constants`). A key already in the smoother cannot become constant.

        Raises :class:`~fgopt.FgoptError` (naming the key or factor) and leaves the smoother
        unchanged when a factor uses an unknown key, ``new_values`` repeats a known key, a
        constant key is not in ``new_values``, a handle in ``remove`` is not a factor of the
        smoother, or a variable would be left unconstrained by its factors. A variable that
        ``remove`` leaves with no factor at all is dropped from the smoother (as GTSAM's ISAM2
        drops unused keys; ``UpdateResult.removed_keys`` lists it).

        Example::

            isam.update(factors, values, constant=[key("l", j) for j in range(num_landmarks)])
        """
        t0 = _clock()
        factors = self._check_factors(new_factors)
        consts = {} if type(constant) is tuple and not constant else \
            self._check_constant(constant, new_values)
        if consts or self._constants:
            every = {**self._constants, **consts}
            factors = [_constants.substitute(f, every) for f in factors]
            new_values = {k: v for k, v in self._values_items(new_values) if k not in consts}
        values = self._check_values(new_values)
        removed = self._check_remove(remove)
        p = self.params
        self._count += 1
        relin = p.enable_relinearization and self._count % int(p.relinearize_skip) == 0
        try:
            result = self._step(factors, values, removed, relin, t0)
        except BaseException:
            self._count -= 1
            raise
        if consts:
            self._constants.update(consts)
        for _ in range(int(p.extra_steps) if p.enable_relinearization else 0):
            extra = self._step([], [], _EMPTY, True, _clock())
            if extra.variables_relinearized == 0:
                break
            result.variables_relinearized += extra.variables_relinearized
            result.variables_reeliminated += extra.variables_reeliminated
            result.factors_relinearized += extra.factors_relinearized
            result.cliques_reeliminated += extra.cliques_reeliminated
            result.cliques = extra.cliques
            result.relinearized_keys = np.union1d(result.relinearized_keys,
                                                  extra.relinearized_keys)
        result.timing["total"] = _clock() - t0
        return result

    def estimate(self, key: Any = None) -> Any:
        """All current estimates as :class:`~fgopt.Variables`, or the value of one ``key``.

        The estimate is ``theta (+) delta``, as iSAM2's ``calculateEstimate``: ``delta`` is
        back-substituted on read, only where it can have changed (wildfire: the re-eliminated
        cliques, and the subtrees below a separator variable that moved by more than
        ``wildfire_threshold``; 0 gives the exact Gauss-Newton step of the current
        linearization), and only variables whose ``delta`` moved are retracted again. The
        Variables holds one read-only array per kind (value objects are made when read) and is
        the caller's: later updates do not change it.
        """
        if key is None:
            out = self._vars.estimate(self._solve_estimate())
            for k, x in self._constants.items():
                out.add(k, x)
            return out
        k = as_key(key)
        if self._constants and k in self._constants:
            return self._constants[k]
        if self._dirty:
            self._solve()
        return self._vars.estimate_value(self._vars.slot(k))

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
        """Total cost ``sum rho_i`` (``0.5 |r|^2`` without robust losses) at ``estimate()``."""
        storages, objects = self._vars.estimate_storages(self._solve_estimate())
        return self._facs.cost(storages, objects)

    def marginalize(self, keys: Iterable[Any]) -> list[int]:
        """Marginalize ``keys`` out (iSAM2's ``marginalizeLeaves``); returns the handles of the
        :class:`~fgopt.incremental.LinearContainerFactor` s put on their Markov blanket.

        The variables must fill whole subtrees of the Bayes tree; when they do not, the cliques
        around them are first re-eliminated with them ordered first. Each removed subtree's
        cached marginal becomes a factor (no re-elimination: its parent's front already holds
        exactly those numbers), and every factor touching ``keys`` is removed with them.
        """
        vars_, tree, facs = self._vars, self._tree, self._facs
        M = np.unique(np.array([vars_.slot(as_key(k)) for k in keys], np.int64))
        if M.shape[0] == 0:
            return []
        ok, sub = _marginal.subtrees(tree.vs, tree.cs, tree.cvpool, tree.meta, M)
        if not ok:
            self._step([], [], _EMPTY, False, _clock(), first=M, extra_marked=sub)
        self._solve()
        gone, _ = _top.adjacent(tree.vs, tree.fs, tree.meta, M, _EMPTY)
        sep_ptr, sep, mat_ptr, C, vec_ptr, c = _marginal.cut(tree.vs, tree.cs, tree.cvpool,
                                                             tree.cnpool, tree.meta, M)
        new, handles = [], []
        for i in range(sep_ptr.shape[0] - 1):
            slots = sep[sep_ptr[i]:sep_ptr[i + 1]]
            if slots.shape[0] == 0:
                continue
            sd = vec_ptr[i + 1] - vec_ptr[i]
            H = C[mat_ptr[i]:mat_ptr[i + 1]].reshape(sd, sd)
            g = -c[vec_ptr[i]:vec_ptr[i + 1]]
            f = LinearContainerFactor([Key(int(vars_.key_of[s])) for s in slots],
                                      [vars_.theta_value(int(s)) for s in slots], H, g)
            slot, h = facs.add(f, slots.tolist())
            off, tree.hpool = _pool.alloc_many(tree.hpool, tree.meta, M_HP_TOP, M_HP_HEAD,
                                               np.array([sd * sd + sd], np.int64))
            tree.hpool[off[0]:off[0] + sd * sd] = f.information.reshape(-1)
            tree.hpool[off[0] + sd * sd:off[0] + sd * sd + sd] = f.gradient
            tree.fac_hoff[slot] = off[0]
            new.append(slot)
            handles.append(h)
        new = np.array(new, np.int64)
        tree.ensure_adjacency(int(tree.fac_nv[new].sum()) if new.shape[0] else 0)
        _top.commit(tree.vs, tree.fs, tree.cs, tree.meta, tree.cvpool, tree.cnpool, tree.hpool,
                    _EMPTY, _EMPTY, _EMPTY, _EMPTY, _EMPTY, _EMPTY, gone, new)
        facs.drop(gone)
        vars_.remove(M)
        self._nnz = int(tree.nnz_factor())
        return handles

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
            factors = list(new_factors) + list(new_factors.constraints)
        elif isinstance(new_factors, Factor):
            factors = [new_factors]
        else:
            factors = list(new_factors)
        for f in factors:
            if not isinstance(f, Factor):
                raise FgoptError(f"update: new_factors must hold Factors, got "
                                 f"{type(f).__name__}")
            if getattr(f, "is_constraint", False):
                raise FgoptError(f"update: {f.describe()} is a constraint; the incremental "
                                 "smoother does not enforce constraints (fgopt.optimize does)")
        return factors

    @staticmethod
    def _values_items(new_values: Any) -> list[tuple[Key, Any]]:
        if new_values is None:
            return []
        if isinstance(new_values, Variables):
            return list(new_values.items())
        if isinstance(new_values, dict):
            return [(as_key(k), v) for k, v in new_values.items()]
        raise FgoptError(f"update: new_values must be Variables or a dict, got "
                         f"{type(new_values).__name__}")

    def _check_constant(self, constant: Iterable[Any], new_values: Any) -> dict:
        """``{key: value}`` of the keys made constant by this update (checked)."""
        keys = [as_key(k) for k in constant]
        if not keys:
            return {}
        given = dict(self._values_items(new_values))
        out = {}
        for k in keys:
            if k in self._vars.slot_of or k in self._constants:
                raise FgoptError(f"update: {key_str(k)} is already in the smoother; only keys "
                                 "new in this update (in new_values) can be held constant")
            if k not in given:
                raise KeyNotFoundError(f"update: constant key {key_str(k)} is not a variable: "
                                       "give its value in new_values")
            out[k] = given[k]
        return out

    def _check_values(self, new_values: Any) -> list[tuple[Key, Any, Any]]:
        """``(key, value, batch kind)`` of each new value (checked against the factors as they
        are added, :meth:`._factors.FactorStore.add_all`)."""
        known, out = self._vars.slot_of, []
        for k, v in self._values_items(new_values):
            if k in known or k in self._constants:
                raise DuplicateKeyError(f"update: {key_str(k)} is already a variable of the "
                                        "smoother; new_values may only hold new keys")
            out.append((k, v, ops_for(v).batch_kind(v)))
        return out

    def _check_remove(self, remove: Iterable[int]) -> np.ndarray:
        if isinstance(remove, (tuple, list)) and not remove:
            return _EMPTY
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
              t0: float, first: np.ndarray = _EMPTY,
              extra_marked: np.ndarray = _EMPTY) -> UpdateResult:
        """One iSAM2 update (module docstring); atomic. ``first``: variables to eliminate
        before all others (group 0), ``extra_marked``: variables to re-eliminate anyway."""
        tree, vars_, facs = self._tree, self._vars, self._facs
        p = self.params
        timing = {}
        meta0 = tree.meta.copy()
        vars_.begin()
        facs.begin()
        try:
            add = vars_.add
            new_slots = [add(k, x, kind) for k, x, kind in values]
            new_facs, handles, obs = facs.add_all(factors, vars_.slot_of)
            seen = set(obs) if new_slots else ()
            for v in new_slots:
                if v not in seen:
                    raise NotPositiveDefiniteError(
                        f"update: new variable {vars_.describe(v)} has no factor, so the "
                        "system would be indefinite: add a factor on it in the same update")
            observed = np.array(obs, np.int64)  # (repeats: tree_update sorts them out)
            t1 = _clock()
            timing["check"] = t1 - t0
            # fluid relinearization
            J = _EMPTY
            if relin:
                self._solve()
                J = _solve.relinearize_candidates(tree.var_live, tree.var_dim, tree.delta,
                                                  tree.thr)
            to_lin = new_facs
            marked = _EMPTY   # (besides the observed variables)
            if J.shape[0]:
                vars_.relinearize(J)
                relin_facs, relin_vars = _top.adjacent(tree.vs, tree.fs, tree.meta, J, removed)
                to_lin = np.concatenate((new_facs, relin_facs))
                marked = np.concatenate((J, relin_vars))
            lin = facs.linearize(to_lin, new_facs.shape[0], defer=True)
            t2 = _clock()
            timing["linearize"] = t2 - t1
            unused = _EMPTY
            if removed.shape[0]:
                rem_vars = _top.factor_vars(tree.fs, removed)
                unused = self._unused(rem_vars, removed, observed)
                marked = np.concatenate((marked, rem_vars))
            if extra_marked.shape[0]:
                marked = np.concatenate((marked, extra_marked))
            n_live = len(vars_.slot_of) - unused.shape[0]
            meta = tree.meta
            if tree.CI.shape[1] < int(meta[M_CL_HWM]) + n_live + 2:
                tree.ensure_cliques(int(meta[M_CL_HWM]) + n_live + 2)
            tree.ensure_adjacency(len(obs))  # one entry per (new factor, variable)
            vs, fs, cs = tree.tuples()
            frac = 0.0 if self._force_batch else p.batch_threshold
            out = _dispatcher(_update.tree_update)(
                vs, fs, cs, meta, tree.cvpool, tree.cnpool, tree.hpool, marked, unused,
                new_facs, removed, observed, first, n_live, frac, p.pivot_tolerance, self._iw,
                self._fw, _ordering.BITSET_LIMIT, lin)
            status, info, top = out[0], out[1:1 + _update.N_INFO], out[1 + _update.N_INFO]
            cv, cn, hp = out[2 + _update.N_INFO:]   # None: the pool did not grow
            tree.cvpool = tree.cvpool if cv is None else cv
            tree.cnpool = tree.cnpool if cn is None else cn
            tree.hpool = tree.hpool if hp is None else hp
            if status == _update.NONFINITE:
                facs.raise_nonfinite()
            if status == _update.NEED_ORDER:
                t3 = _clock()
                T, R, O, FL, ap, ai, group = _update.unpack_top(top)
                order = _ordering.amd_groups(T.shape[0], ap, ai, group)
                timing["order"] = _clock() - t3
                info = top[:_update.N_INFO]
                status, _, tree.cvpool, tree.cnpool = _update.tree_finish(
                    vs, fs, cs, meta, tree.cvpool, tree.cnpool, tree.hpool, T, R, O, FL, ap, ai,
                    group, order, new_facs, removed, p.pivot_tolerance, self._iw, self._fw,
                    info)
                info = info.tolist()
            if status == _update.FAILED:
                raise NotPositiveDefiniteError(
                    f"update: {vars_.describe(int(info[_update.I_FAIL]))} is not constrained "
                    "by its factors (the system is indefinite); the update was not applied")
        except BaseException:
            stamp_now = tree.meta[M_STAMP]
            tree.meta[:] = meta0
            tree.meta[M_STAMP] = stamp_now
            facs.rollback()
            vars_.rollback()
            raise
        # committed: forget removed factors and variables
        removed_keys = []
        if removed.shape[0]:
            facs.drop(removed)
        if unused.shape[0]:
            removed_keys = [Key(int(vars_.key_of[v])) for v in unused]
            vars_.remove(unused)
        facs.release()
        vars_.end()
        facs.end()
        self._dirty = True
        timing["tree"] = _clock() - t2
        t, nnz, new_cliques, _, batch, _ = info
        self._nnz += nnz
        n = len(vars_.slot_of)
        if batch:
            self._nnz_per_var_ref = self._nnz / max(n, 1)
            self._force_batch = False
        elif n > 64 and self._nnz > p.fill_refresh * self._nnz_per_var_ref * n:
            self._force_batch = True
        return UpdateResult._of({
            "new_factor_indices": handles, "variables_relinearized": int(J.shape[0]),
            "variables_reeliminated": t, "factors_relinearized": int(to_lin.shape[0]),
            "cliques_reeliminated": new_cliques, "cliques": int(tree.meta[M_NCLIQUES]),
            "batch": bool(batch), "removed_keys": removed_keys, "marginalized_keys": [],
            "relinearized_keys": vars_.key_of[J] if J.shape[0] else _EMPTY, "timing": timing})

    def _unused(self, rem_vars: np.ndarray, removed: np.ndarray,
                observed: np.ndarray) -> np.ndarray:
        """Variables that removing ``removed`` leaves without factors (they are dropped)."""
        if rem_vars.shape[0] == 0:
            return _EMPTY
        counts = _top.remaining_factors(self._tree.vs, self._tree.fs, self._tree.meta, rem_vars,
                                        removed)
        out = rem_vars[(counts == 0) & ~np.isin(rem_vars, observed)]
        return np.unique(out)
