"""The "fixed" formulation (SymForce paper, Sec. VIII-C): one generated function per problem.

For a factor graph whose structure does not change (same factor types on the same variables,
only measurements and noise vary), :func:`compile_fixed` derives ONE flattened numba function
for the whole linearization -- whitened residuals, the dense ``H = J^T J``, ``g = J^T r`` and
the cost -- with subexpressions shared across factors, and a dense Levenberg-Marquardt loop
around it (no sparse structure, no batching, no Python per iteration)::

    from fgopt.solvers.fixed import compile_fixed, optimize_fixed

    result = optimize_fixed(graph, initial)             # compile (cached) + LM
    fp = compile_fixed(graph, initial)                  # or keep the compiled problem:
    fp.update(new_graph)                                #   new measurements, same structure
    result = fp.optimize(initial, max_iterations=20)

Supported factors: ``@fgopt.factor`` instances (:class:`~fgopt.symbolic.factor.SymbolicFactor`)
and the built-in ``BetweenFactor`` / ``PriorFactor`` on SO2/SE2/SO3/SE3/R^n (replaced by their
generated twins in :mod:`fgopt.factors.library.generated`, same residuals and constants), with
Gaussian noise models. Robust losses, Python factors and raw batches raise
:class:`~fgopt.errors.FgoptError` naming the first unsupported factor.

Inputs of the generated code are numeric: variable storages, every factor's constants and the
structurally non-zero entries of its square-root information, so one generated module serves
every problem of the same *structure*. The structure (factor types and their code, variable
patterns, variable kinds and order, sqrt-information sparsity) is hashed into the on-disk cache
key (:mod:`fgopt.symbolic.cache`, ``$FGOPT_CACHE_DIR``): a second process imports the module and
numba loads its machine code; SymPy is not imported.

The LM loop reproduces :class:`fgopt.solvers.lm.LevenbergMarquardt` step for step (``(H + lam D)
delta = -g`` with ``D = I`` or ``clip(diag H)``, lambda by a factor or Nielsen's rule, resolved
from ``LMParams.damping`` / ``lambda_policy`` the same way; the same stopping tests), with a
dense Cholesky instead of the sparse solvers. Per-iteration records carry no wall time (the
loop runs compiled): ``IterationRecord.time`` is NaN.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from typing import Any

import numpy as np

from ...errors import FgoptError, NonFiniteError
from ..params import LMParams
from ..diagnostics import fixed_clamp_hits, warn_clamps, warn_unused
from ..result import IterationRecord, Result, compiled_history
from ...variables import Variables
from ...symbolic import cache as _cache
from ._collect import Collected as _Collected
from ._collect import collect as _collect
from ._collect import fingerprint as _fingerprint

#: In-process memo: structure key -> generated module.
_MODULES: dict = {}
#: Counters (tests / benchmarks): modules ``derived`` (SymPy ran) or ``loaded`` from disk.
STATS = {"derived": 0, "loaded": 0, "memo": 0}


# ------------------------------------------------------------------------------------ module
#: What FixedProblem uses of a generated module (a cached entry without them is regenerated).
_REQUIRED = ("N", "S", "NUM_AUX", "META", "_precompute", "_lm")


def _module(col: _Collected, use_cache: bool, info: dict) -> Any:
    m = _MODULES.get(col.key)
    if m is not None:
        STATS["memo"] += 1
        info["source"] = "memo"
        return m
    name = f"fixed_{len(col.keys)}v_{col.num_factors}f"
    m = _cache.load(name, col.key, required=_REQUIRED) if use_cache else None
    if m is not None:
        STATS["loaded"] += 1
        info["source"] = "disk"
    else:
        from ._codegen import build_program, module_source

        t0 = time.perf_counter()
        prog, const_syms = build_program(col.variables, col.factors, info)
        types = sorted({run.ftype.name for run in col.runs})
        summary = (f"{len(col.variables)} variables, {col.num_factors} factors "
                   f"({', '.join(types)})")
        clamp_types = sorted(_fingerprint(ft) for ft in info.pop("clamp_ftypes", []))
        source, _ = module_source(col.variables, prog, const_syms,
                                  {"summary": summary, "clamp_types": clamp_types})
        info["derive_total"] = time.perf_counter() - t0
        key = col.key if use_cache else "nocache_" + hashlib.sha256(source.encode()).hexdigest()[:16]
        m = _cache.store(name, key, source)
        STATS["derived"] += 1
        info["source"] = "derived"
    _MODULES[col.key] = m
    return m


# ------------------------------------------------------------------------------------ problem
class FixedProblem:
    """A graph compiled into one generated linearization + dense LM (see the module docstring).

    Attributes: ``keys`` (variable order = tangent order), ``kinds``, ``size`` (tangent dim N),
    ``module`` (generated module), ``source``, ``ops`` (op counts), ``generation`` (timings: how
    the module was obtained, derivation / compile seconds).
    """

    def __init__(self, col: _Collected, values: Variables, module: Any, generation: dict):
        self._col = col
        self.keys = col.keys
        self._key_set = set(col.keys)
        self.kinds = col.kinds
        self.module = module
        self.size = int(module.N)
        self.storage_size = int(module.S)
        self.generation = generation
        self._values = values
        self._x0 = col.x0
        self._aux = np.zeros(module.NUM_AUX)
        self._set_inputs(col.consts, col.wvals)

    @property
    def structure_key(self) -> str:
        return self._col.key

    @property
    def source(self) -> str:
        return self.module.__fgopt_source__  # the text that was verified and run

    @property
    def ops(self) -> dict:
        m = self.module.META
        return {"linearize": m["ops_linearize"], "precompute": m["ops_precompute"],
                "statements": m["num_statements"],
                "instructions": m["instructions_linearize"]}

    def _set_inputs(self, consts: np.ndarray, wvals: np.ndarray) -> None:
        self._consts = np.ascontiguousarray(consts, dtype=float)
        self._wvals = np.ascontiguousarray(wvals, dtype=float)
        self.module._precompute(self._consts, self._wvals, self._aux)

    def update(self, graph: Any, values: Variables | None = None) -> FixedProblem:
        """Take new measurements / noise from ``graph`` (same structure); returns self."""
        col = _collect(graph, values if values is not None else self._values)
        if col.key != self._col.key:
            raise FgoptError("fixed formulation: the graph's structure differs from the "
                             "compiled one; call compile_fixed again")
        self._col = col
        if values is not None:
            self._values = values
            self._x0 = col.x0
        self._set_inputs(col.consts, col.wvals)
        return self

    # -- storage <-> Variables
    def flatten(self, values: Variables) -> np.ndarray:
        """Storage of every variable, concatenated in variable order."""
        x = np.empty(self.storage_size)
        off = self._col.storage_off.tolist()
        for v, (k, kind) in enumerate(zip(self.keys, self.kinds)):
            x[off[v]:off[v + 1]] = kind.to_storage(values.at(k))
        return x

    def values(self, x: np.ndarray) -> Variables:
        """A new ``Variables``: the initial values with every variable replaced from ``x``
        (keys no factor uses copied unchanged), in the initial values' key order."""
        from ...problem import replaced_values

        col = self._col
        groups = []
        for no in range(len(col.kind_specs)):
            vs = np.flatnonzero(col.kind_no == no)
            kind = self.kinds[int(vs[0])]
            cols = np.add.outer(col.storage_off[vs], np.arange(kind.storage_dim))
            groups.append((kind, [self.keys[v] for v in vs.tolist()], x[cols]))
        return replaced_values(self._values, groups)

    def linearize(self, values: Variables | np.ndarray | None = None) -> tuple:
        """``(cost, H (N, N), g (N,))`` at ``values`` (dense, tangent order = ``keys``)."""
        x = self._x0 if values is None else (
            np.ascontiguousarray(values, dtype=float) if isinstance(values, np.ndarray)
            else self.flatten(values))
        H = np.zeros((self.size, self.size))
        g = np.zeros(self.size)
        prm = np.array([0.0, 0, 0, -1.0, 0, 1e-5, 1e-12, 1e12, 1e-6, 1e32, 1e-3, 0, 0, 10.0])
        _, status, _, _, _, cost, _ = self.module._lm(x, self._aux, prm, np.empty((1, 8)), H, g)
        if status == -1:
            H[:], g[:] = np.nan, np.nan
        return float(cost), H, g

    # -- optimization
    def optimize(self, values: Variables | None = None, params: LMParams | None = None,
                 **options: Any) -> Result:
        """Dense LM from ``values`` (default: the compile-time values); ``options`` replace
        :class:`~fgopt.solvers.params.LMParams` fields (``max_iterations``, tolerances, damping).
        """
        t0 = time.perf_counter()
        p = _params(params, options)
        x0 = self._x0 if values is None else self.flatten(values)
        given = self._values if values is None else values
        unused = [k for k in given.keys() if k not in self._key_set] if len(given) > len(
            self.keys) else []
        warn_unused(unused)
        identity, by_factor = self._damping(p)
        rel_tol = p.relative_tolerance if p.relative_tolerance is not None else (
            1e-5 if identity else 1e-6)  # as LevenbergMarquardt resolves the defaults
        lam0 = p.initial_lambda if p.initial_lambda is not None else (1e-5 if identity else 1e-4)
        prm = np.array([p.max_iterations, rel_tol, p.absolute_tolerance,
                        p.gradient_tolerance, p.step_tolerance, lam0, p.min_lambda,
                        p.max_lambda, p.min_diagonal, p.max_diagonal, p.min_relative_decrease,
                        float(identity), float(by_factor), getattr(p, "lambda_factor", 10.0)])
        hist = np.empty((max(p.max_iterations, 1), 8))
        self.H = np.zeros((self.size, self.size))
        self.g = np.zeros(self.size)
        t1 = time.perf_counter()
        x, status, msg, val, its, cost, init = self.module._lm(x0, self._aux, prm, hist, self.H,
                                                               self.g)
        t2 = time.perf_counter()
        if status == -1:
            raise NonFiniteError("fixed formulation: " + self._locate_nonfinite(x0))
        records, st, message = compiled_history(hist, its, status,
                                                _message(int(msg), float(val), p), cost)
        costs = [float(init)] + records.accepted_costs()
        timing = {"setup": t1 - t0, "lm": t2 - t1, "total": time.perf_counter() - t0}
        clamps, num_clamped = fixed_clamp_hits(self, x)
        warn_clamps(clamps, num_clamped)
        if p.verbose:
            print(IterationRecord.HEADER)
            for r in records.records():
                print(r.row())
        return Result(None, status=st, message=message,
                      iterations=len(records), initial_cost=float(init), final_cost=float(cost),
                      cost_history=costs, iteration_records=records, timing=timing,
                      method="lm (fixed)", linear_solver="dense cholesky", problem=self,
                      state=x, unused_keys=tuple(unused), clamps=tuple(clamps),
                      num_clamped=num_clamped)

    def _locate_nonfinite(self, x: np.ndarray) -> str:
        """Name the first factor whose residual or Jacobian is not finite at storage ``x``."""
        values = self.values(x)
        hits, total = fixed_clamp_hits(self, x)
        clamped = (f"; at the initial values {total} clamped call(s) are outside their domain, "
                   f"e.g. {hits[0]}" if total > 0 else "")
        for f in self._col.sources:
            try:
                f.checked_error(values)
                f.checked_jacobians(values)
            except NonFiniteError as e:
                return str(e) + clamped
        return "the cost, gradient or H at the initial values is not finite" + clamped

    def _damping(self, p: LMParams) -> tuple:
        """(identity damping, lambda by factor) as LevenbergMarquardt resolves them."""
        from ..lm import auto_policy, problem_class_for

        return auto_policy(problem_class_for(self.kinds, False, self._pattern), p)

    def _pattern(self):
        """The block pattern of H (natural order; only its variable kinds and couplings matter
        for the damping choice)."""
        from ...structure import build_pattern

        pi, pj = [], []
        for run in self._col.runs:
            vs = run.var_idx
            for a in range(vs.shape[1]):
                for b in range(a + 1, vs.shape[1]):
                    pi.extend(vs[:, a].tolist())
                    pj.extend(vs[:, b].tolist())
        dims = np.array([k.dim for k in self.kinds], dtype=np.int64)
        pattern, _ = build_pattern(dims, np.arange(len(self.keys)),
                                   np.array(pi, dtype=np.int64), np.array(pj, dtype=np.int64))
        ids = {id(k): i for i, k in enumerate(dict.fromkeys(self.kinds))}
        pattern.var_kind = np.array([ids[id(k)] for k in self.kinds], dtype=np.int64)
        return pattern

    def __repr__(self) -> str:
        o = self.ops
        return (f"FixedProblem({len(self.keys)} variables, {self._col.num_factors} factors, "
                f"tangent dim {self.size}; linearize {o['linearize']} ops, "
                f"precompute {o['precompute']} ops)")


def _params(params: LMParams | None, options: dict) -> LMParams:
    p = params or LMParams()
    if not options:
        return p
    fields = {f.name for f in dataclasses.fields(p)}
    unknown = set(options) - fields
    if unknown:
        raise FgoptError(f"unknown option(s) {sorted(unknown)}; valid: {sorted(fields)}")
    return dataclasses.replace(p, **options) if options else p


def _message(code: int, v: float, p: LMParams) -> str:
    return {
        1: lambda: f"gradient norm {v:.3g} <= {p.gradient_tolerance:g}",
        2: lambda: f"absolute cost decrease {v:.3g} < {p.absolute_tolerance:g}",
        3: lambda: f"relative cost decrease {v:.3g} below the relative tolerance",
        4: lambda: f"step norm {v:.3g} below step_tolerance",
        5: lambda: ("damping exceeded max_lambda: the linear system stays singular (is a "
                    "variable unconstrained?)"),
        6: lambda: "no step decreases the cost (damping exceeded max_lambda)",
        7: lambda: f"reached max_iterations={p.max_iterations}",
    }.get(code, lambda: "")()


# ------------------------------------------------------------------------------------ API
def compile_fixed(graph: Any, values: Variables, cache: bool = True) -> FixedProblem:
    """Compile ``graph`` (at ``values``) into a :class:`FixedProblem` (see the module docstring).

    The generated module is reused from this process, else from the on-disk cache, else derived
    (SymPy) and compiled (numba); ``problem.generation`` tells which and how long it took.
    """
    if not isinstance(values, Variables):
        raise FgoptError(f"values must be fgopt.Variables, got {type(values).__name__}")
    t0 = time.perf_counter()
    col = _collect(graph, values)
    info: dict = {}
    module = _module(col, cache, info)
    t1 = time.perf_counter()
    fp = FixedProblem(col, values, module, info)
    if not getattr(module, "_fgopt_warm", False):  # first call compiles / loads machine code
        fp.linearize()
        module._fgopt_warm = True
    info["total"] = time.perf_counter() - t0
    info["collect+module"] = t1 - t0
    return fp


def optimize_fixed(graph: Any, initial: Variables, params: LMParams | None = None,
                   cache: bool = True, **lm_options: Any) -> Result:
    """``compile_fixed(graph, initial).optimize(**lm_options)``: LM on the fixed formulation.

    Same :class:`~fgopt.solvers.result.Result` as ``fgopt.optimize(graph, initial, "lm")``.
    """
    return compile_fixed(graph, initial, cache=cache).optimize(params=params, **lm_options)
