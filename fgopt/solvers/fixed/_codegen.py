"""Derivation and source of the "fixed" formulation (see :mod:`fgopt.solvers.fixed`).

One straight-line program for the whole problem (SymForce paper, Sec. VIII-C):

1. every factor type (and variable pattern) is derived ONCE with
   :func:`~fgopt.symbolic.linearize.linearization_program` over generic symbols (residual +
   tangent-space Jacobian, already CSE'd);
2. each factor instantiates that program by substitution: variable storage symbols ``x{v}_{k}``
   (shared by all factors of variable ``v``), constants ``c{i}``, square-root information
   entries ``w{i}`` (only its structurally non-zero entries). Statements are hash-consed while
   instantiating (global value numbering), so everything that depends only on shared inputs
   (e.g. a pose's inverse, its ``storage_D_tangent``) is computed once for all its factors;
3. whitened residual ``R e`` and Jacobian ``R J``, then the dense lower triangle of ``H = J^T J``,
   ``g = J^T r`` and ``cost = 0.5 |r|^2`` summed over factors, then one global CSE;
4. statements that depend only on constants / whitening (e.g. ``cos`` of a measured bearing) are
   hoisted into ``_precompute``: they run once per set of measurements, not once per iteration.

The emitted module holds ``_precompute(_c, _w, _aux)``, ``_linearize(_x, _aux, _H, _g) -> cost``
and a dense Levenberg-Marquardt loop ``_lm`` (Cholesky of the damped H, retraction through
:func:`fgopt.manifolds._kernels.lie_retract`), all ``numba.njit(cache=True)``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from ...symbolic.cse import Program, optimize, prune, total_ops

#: Bumped when the emitted source changes meaning (part of the cache key).
FIXED_CODEGEN_VERSION = "8"  # 7: envelope Cholesky (_envelope); 8: _lm's arenas


@dataclass(frozen=True)
class VarSpec:
    gid: int  # Lie group id of fgopt.manifolds._kernels, -1 vectors / scalars, -2 declared
    storage_dim: int
    tangent_dim: int
    storage_off: int
    tangent_off: int
    #: declared manifolds: their printed retract (``RETRACT_CODE`` of the generated module)
    retract_code: Any = field(default=None, compare=False)


@dataclass(frozen=True)
class FactorSpec:
    ftype: Any          # SymbolicFactorType
    pattern: tuple      # which arguments are variables
    var_idx: tuple      # graph variable index of each variable argument
    const_off: int      # first column in the flat constants vector
    num_consts: int
    residual_dim: int
    wmask: tuple        # row-major r*r booleans: structurally non-zero sqrt-information entries
    w_off: int          # first entry in the flat whitening vector


def _sym():
    from ...symbolic import _sym as s

    return s


def _type_program(ftype: Any, pattern: tuple) -> tuple:
    """(generic variable storage symbols per arg, generic constant symbols, program, number of
    clamped function calls)."""
    from ...symbolic.derive import residual_of
    from ...symbolic.functions import recording_clamps
    from ...symbolic.linearize import linearization_program
    from ...symbolic.ops import storage_of, symbolic_value

    args = [symbolic_value(tp, f"_a{i}") for i, (_, tp) in enumerate(ftype.params)]
    with recording_clamps() as clamps:
        res, _ = residual_of(ftype, args)
    var_args = [a for a, v in zip(args, pattern) if v]
    prog = linearization_program(res, var_args, method=ftype.method, engine=ftype.engine)
    var_syms = [tuple(storage_of(a)) for a, v in zip(args, pattern) if v]
    const_syms = [s for a, v in zip(args, pattern) if not v for s in storage_of(a)]
    return var_syms, const_syms, prog, len(clamps)


class _Builder:
    """Hash-consed statement list (global value numbering over instantiated programs)."""

    def __init__(self) -> None:
        self.sp = _sym().sp
        self.stmts: list = []
        self.seen: dict = {}
        self.count = 0

    def define(self, e: Any, prefix: str = "_v") -> Any:
        if e.is_Atom:
            return e
        hit = self.seen.get(e)
        if hit is not None:
            return hit
        s = self.sp.Symbol(f"{prefix}{self.count}", real=True)
        self.count += 1
        self.seen[e] = s
        self.stmts.append((s, e))
        return s


def build_program(variables: list, factors: list, log: dict | None = None) -> tuple:
    """The whole problem's program: outputs ``H`` (lower triangle, row-major), ``g``, ``cost``.

    Returns ``(program, const_symbols)``: ``const_symbols`` are the input symbols that do not
    change between iterations (constants and whitening).
    """
    sp = _sym().sp
    t0 = time.perf_counter()
    types: dict = {}
    for f in factors:
        k = (id(f.ftype), f.pattern)
        if k not in types:
            types[k] = _type_program(f.ftype, f.pattern)
    t1 = time.perf_counter()
    xsyms = [[sp.Symbol(f"x{v}_{k}", real=True) for k in range(var.storage_dim)]
             for v, var in enumerate(variables)]
    N = sum(v.tangent_dim for v in variables)
    b = _Builder()
    H: dict = {}
    g: list = [[] for _ in range(N)]
    cost_terms: list = []
    const_syms: set = set()
    for i, f in enumerate(factors):
        var_syms, csyms, prog, _ = types[(id(f.ftype), f.pattern)]
        m: dict = {}
        for gen, v in zip(var_syms, f.var_idx):
            m.update(zip(gen, xsyms[v]))
        cs = [sp.Symbol(f"c{f.const_off + k}", real=True) for k in range(f.num_consts)]
        m.update(zip(csyms, cs))
        const_syms.update(cs)
        for t, e in prog.stmts:
            m[t] = b.define(e.xreplace(m))
        res = [b.define(sp.sympify(e).xreplace(m)) for e in prog.outputs["res"]]
        r = len(res)
        D = sum(variables[v].tangent_dim for v in f.var_idx)
        jac = [sp.sympify(e).xreplace(m) for e in prog.outputs["jac"]]
        jac = [[b.define(jac[row * D + col]) for col in range(D)] for row in range(r)]
        # whitening with the structurally non-zero sqrt-information entries
        W = [[None] * r for _ in range(r)]
        k = 0
        for p in range(r):
            for q in range(r):
                if f.wmask[p * r + q]:
                    W[p][q] = sp.Symbol(f"w{f.w_off + k}", real=True)
                    const_syms.add(W[p][q])
                    k += 1
        rw = [b.define(sp.Add(*[W[p][q] * res[q] for q in range(r) if W[p][q] is not None]))
              for p in range(r)]
        jw = [[b.define(sp.Add(*[W[p][q] * jac[q][col] for q in range(r)
                                 if W[p][q] is not None]))
               for col in range(D)] for p in range(r)]
        gcol = []  # global tangent index of each local Jacobian column
        for v in f.var_idx:
            var = variables[v]
            gcol += [var.tangent_off + j for j in range(var.tangent_dim)]
        for ca in range(D):
            a = gcol[ca]
            g[a] += [jw[p][ca] * rw[p] for p in range(r)]
            for cb in range(D):
                bb = gcol[cb]
                if bb > a:
                    continue
                H.setdefault((a, bb), []).extend(jw[p][ca] * jw[p][cb] for p in range(r))
        cost_terms += [rw[p] * rw[p] for p in range(r)]
    t2 = time.perf_counter()
    hess = [sp.Add(*H.get((a, bb), [])) for a in range(N) for bb in range(a + 1)]
    outputs = {"H": hess, "g": [sp.Add(*t) for t in g],
               "cost": [sp.Rational(1, 2) * sp.Add(*cost_terms)]}
    prog = Program(b.stmts, outputs)
    prog = optimize(prog)
    t3 = time.perf_counter()
    if log is not None:
        log.update({"derive_types": t1 - t0, "instantiate": t2 - t1, "cse": t3 - t2,
                    "num_types": len(types)})
        # factor types with clamped functions: checked per factor after a solve
        log["clamp_ftypes"] = list({id(f.ftype): f.ftype for f in factors
                                    if types[(id(f.ftype), f.pattern)][3] > 0}.values())
    return prog, const_syms


def split_constant(prog: Program, const_syms: set) -> tuple:
    """Split into (constant statements, iteration statements, hoisted symbols)."""
    const = set(const_syms)
    eps = _sym().epsilon
    cstmts, vstmts = [], []
    for s, e in prog.stmts:
        if all(x in const or x == eps for x in e.free_symbols):
            cstmts.append((s, e))
            const.add(s)
        else:
            vstmts.append((s, e))
    used: set = set()
    for _, e in vstmts:
        used |= e.free_symbols
    for e in prog.all_outputs():
        used |= getattr(e, "free_symbols", set())
    hoisted = sorted((x for x in used if x in const), key=lambda x: x.name)
    cstmts = prune(cstmts, hoisted)
    return cstmts, vstmts, hoisted


def _index_of(sym: Any) -> int:
    return int(sym.name[1:])


_FIXED_PROLOGUE = '''
@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True)
def _precompute(_c, _w, _aux):
    """Iteration-independent terms (constants, whitening) -> _aux."""
    _pre(_c, _w, _aux)


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True)
def _retract(_x, _d, _out, _tmp, _aux):
{retract}


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True)
def _envelope(_aux, n):
    """H's envelope: each row's first structurally nonzero column (_FIRST, from the symbolic H)."""
    first = np.empty(n, dtype=np.int64)
    for i in range(n):
        first[i] = _FIRST[i]
    return first
'''

#: The dense LM of a generated module, around its ``_lin(x, aux, H, g) -> cost``,
#: ``_retract(x, delta, out, tmp, aux)`` and ``_envelope(aux, n)`` (per row of H the first
#: column that can be nonzero: the Cholesky skips what lies before it); ``{n}`` is the tangent
#: dimension's expression and ``{core_flags}`` ``_lm_core``'s extra numba options (see
#: :func:`lm_source`). Shared by the fixed formulation and :mod:`fgopt.solvers.small` (one
#: driver per set of kernels).
LM_TEMPLATE = '''
# reassociation lets LLVM vectorize the dot products (33 unknowns: 4.1 -> 2.9 us, 72: 34 -> 14
# us); the order of a sum's terms is all it changes, the same on every call
@numba.njit(cache=True, fastmath={"reassoc", "contract"}, error_model="numpy", nogil=True,
            _nrt=False)
def _cholesky_solve(A, b, L, y, first):
    """Solve A y = b for symmetric A by Cholesky (lower L); False if A is not positive definite.

    first[i]: the first column of row i's envelope (A[i, k] = 0 for every k < first[i], so
    first[i] <= i). L has A's envelope, so only entries inside it are computed and read: a
    chain-like pose graph's rows reach a few variables back (pose2example's 33 unknowns: a
    quarter of the dense work)."""
    n = A.shape[0]
    for j in range(n):
        fj = first[j]
        s = A[j, j]
        for k in range(fj, j):
            s -= L[j, k] * L[j, k]
        if not (s > 0.0) or not math.isfinite(s):
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            fi = first[i]
            if fi > j:
                continue  # outside the envelope: L[i, j] = 0, never read
            s = A[i, j]
            for k in range(max(fi, fj), j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    for i in range(n):
        s = b[i]
        for k in range(first[i], i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):  # L^T y = y by columns of L^T: row i of L, its envelope
        y[i] = y[i] / L[i, i]
        for k in range(first[i], i):
            y[k] -= L[i, k] * y[i]
    return True


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _absmax(g):
    m = 0.0
    for i in range(g.shape[0]):
        a = abs(g[i])
        if a > m:
            m = a
    return m


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _all_finite(a):
    for i in range(a.shape[0]):
        if not math.isfinite(a[i]):
            return False
    return True


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _all_finite_env(a, env):
    """Whether symmetric a's lower envelope (all it can hold) is finite."""
    ok = True
    for i in range(a.shape[0]):
        for j in range(env[i], i + 1):
            ok = ok and math.isfinite(a[i, j])
    return ok


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _copy(src, dst):
    for i in range(src.shape[0]):
        dst[i] = src[i]


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _copy_env(src, dst, env):
    """dst = src on symmetric src's envelope, both triangles (outside it both stay zero)."""
    for i in range(src.shape[0]):
        for j in range(env[i], i + 1):
            dst[i, j] = src[i, j]
            dst[j, i] = src[j, i]


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=False)
def _record(hist, row, cost, cand, rel, lam, step, grad, acc, pred):
    hist[row, 7] = pred
    hist[row, 0] = cost
    hist[row, 1] = cand
    hist[row, 2] = rel
    hist[row, 3] = lam
    hist[row, 4] = step
    hist[row, 5] = grad
    hist[row, 6] = acc


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True{core_flags})
def _lm_core(x0, aux, prm, hist, H, g, zw, ew):
    """Dense LM as fgopt.solvers.lm (same damping, gain ratio, lambda policy and stopping tests).

    The whole-problem linearization has ONE call site (the generated program is inlined once):
    each pass of the outer loop linearizes a point, then decides, then proposes the next step.
    prm: max_iterations, relative_tolerance, absolute_tolerance, gradient_tolerance,
    step_tolerance, initial_lambda, min_lambda, max_lambda, min_diagonal, max_diagonal,
    min_relative_decrease, identity damping (1/0), lambda by factor (1/0), lambda_factor.
    hist (max_iterations, 8): cost, candidate cost, relative decrease,
    lambda, |step|, |grad|, accepted, predicted decrease. H, g (out): the linearization at the
    returned x (H zero on entry: only its envelope is written). zw: 2 n^2 + n scratch for
    Hc, L and gc (zeros, unless _lin clears H and g on the envelope before it adds to them, as
    the small drivers' does: the Cholesky reads L only where it has written it), ew:
    2 len(x0) + n^2 + 3 n + 8 scratch (one arena each, not ten arrays); the final x is
    ew[:len(x0)].
    Returns (status, message, value, iterations, cost, initial cost); status 0 converged,
    1 max iterations, 2 failed, -1 non-finite at the initial values.
    """
    max_it = int(prm[0])
    rtol, atol, gtol, stol = prm[1], prm[2], prm[3], prm[4]
    lam, min_lam, max_lam = prm[5], prm[6], prm[7]
    min_diag, max_diag, min_dec = prm[8], prm[9], prm[10]
    identity, by_factor, lam_factor = prm[11] > 0.5, prm[12] > 0.5, prm[13]
    n = {n}
    env = _envelope(aux, n)  # per row of H its first column that can be nonzero
    nx = x0.shape[0]
    Hc = zw[:n * n].reshape((n, n))
    L = zw[n * n:2 * n * n].reshape((n, n))
    gc = zw[2 * n * n:2 * n * n + n]
    x = ew[:nx]
    xc = ew[nx:2 * nx]
    for i in range(nx):
        x[i] = x0[i]
        xc[i] = x0[i]
    Hd = ew[2 * nx:2 * nx + n * n].reshape((n, n))
    o = 2 * nx + n * n
    Dg = ew[o:o + n]
    rhs = ew[o + n:o + 2 * n]
    delta = ew[o + 2 * n:o + 3 * n]
    tmp = ew[o + 3 * n:o + 3 * n + 8]
    nu = 2.0
    cost = 0.0
    init = 0.0
    it = 0
    first = True
    step_norm = 0.0
    predicted = 0.0
    while True:
        new_cost = _lin(xc, aux, Hc, gc)
        if first:
            first = False
            if not (math.isfinite(new_cost) and _all_finite(gc) and _all_finite_env(Hc, env)):
                return -1, 0, 0.0, 0, new_cost, new_cost
            _copy_env(Hc, H, env)
            _copy(gc, g)
            cost = new_cost
            init = new_cost
            gn = _absmax(g)
            if gn <= gtol:
                return 0, 1, gn, 0, cost, init
        else:
            row = it - 1
            old = cost
            if not (math.isfinite(new_cost) and _all_finite(gc) and _all_finite_env(Hc, env)):
                new_cost = np.nan
            rho = (old - new_cost) / predicted if predicted > 0 else -np.inf
            accepted = math.isfinite(new_cost) and rho > min_dec
            rel = (old - new_cost) / old if old > 0 else 0.0
            if not math.isfinite(rel):
                rel = np.nan
            if accepted:
                _copy(xc, x)
                _copy_env(Hc, H, env)
                _copy(gc, g)
                cost = new_cost
                if by_factor:
                    lam = max(min_lam, lam / lam_factor)
                else:
                    lam = max(min_lam, lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3))
                nu = 2.0
                gn = _absmax(g)
                _record(hist, row, cost, new_cost, rel, lam, step_norm, gn, 1.0, predicted)
                dec = old - new_cost
                if dec < atol:
                    return 0, 2, dec, it, cost, init
                if old > 0 and dec / old < rtol:
                    return 0, 3, dec / old, it, cost, init
                if gn <= gtol:
                    return 0, 1, gn, it, cost, init
            else:
                _record(hist, row, cost, new_cost, rel, lam, step_norm, _absmax(g), 0.0, predicted)
                if by_factor:
                    lam = lam * lam_factor
                else:
                    lam = lam * nu
                    nu = nu * 2.0
                if lam > max_lam:
                    return 0 if step_norm < 1e-8 else 2, 6, step_norm, it, cost, init
            xn = 0.0
            for i in range(x.shape[0]):
                xn += x[i] * x[i]
            if step_norm <= stol * (math.sqrt(xn) + stol):
                return 0, 4, step_norm, it, cost, init
        # propose the next step (failed factorizations retry with more damping, no linearization)
        while True:
            it += 1
            if it > max_it:
                return 1, 7, 0.0, max_it, cost, init
            for i in range(n):
                Dg[i] = 1.0 if identity else min(max(H[i, i], min_diag), max_diag)
                for j in range(env[i], i + 1):  # the lower envelope: all the Cholesky reads
                    Hd[i, j] = H[i, j]
                Hd[i, i] += lam * Dg[i]
                rhs[i] = -g[i]
            ok = _cholesky_solve(Hd, rhs, L, delta, env)
            if ok:
                ok = _all_finite(delta)
            if ok:
                break
            _record(hist, it - 1, cost, np.nan, np.nan, lam, np.nan, _absmax(g), 0.0, np.inf)
            lam = lam * nu
            nu = nu * 2.0
            if lam > max_lam:
                return 2, 5, 0.0, it, cost, init
        sn = 0.0
        pred = 0.0
        gd = 0.0
        for i in range(n):
            sn += delta[i] * delta[i]
            pred += delta[i] * (lam * Dg[i] * delta[i])
            gd += g[i] * delta[i]
        step_norm = math.sqrt(sn)
        predicted = 0.5 * (pred - gd)
        _retract(x, delta, xc, tmp, aux)


@numba.njit(cache=True, fastmath=False, error_model="numpy", nogil=True, _nrt=True)
def _lm(x0, aux, prm, hist, H, g):
    """_lm_core with its scratch: (x, status, message, value, iterations, cost, initial cost)."""
    n = {n}
    nx = x0.shape[0]
    ew = np.empty(2 * nx + n * n + 3 * n + 8)
    status, msg, val, its, cost, init = _lm_core(x0, aux, prm, hist, H, g,
                                                 np.zeros(2 * n * n + n), ew)
    return ew[:nx], status, msg, val, its, cost, init
'''


def lm_source(n: str, counted: bool = True) -> str:
    """:data:`LM_TEMPLATE` with ``n`` the tangent dimension's expression; ``counted=False``
    compiles ``_lm_core`` without numba's reference counting (``_nrt=False``: no atomic
    increment and decrement of every array it passes or slices, ~7 ns each here, hundreds per
    solve). Only for modules whose ``_envelope`` is inlined and whose ``_lin`` and
    ``_retract`` return no new array: a core without counting would never release one."""
    # (explicit both ways: numba compiles a function without its own _nrt with its caller's)
    return LM_TEMPLATE.replace("{n}", n).replace("{core_flags}",
                                                 ", _nrt=True" if counted else ", _nrt=False")


def _retract_source(variables: list) -> str:
    """x (+) d per variable; Lie groups through lie_retract on C-contiguous scratch rows (the
    signature batch_retract already compiled and cached, so nothing is recompiled)."""
    lines = ["    _xs = np.empty(8)", "    _ds = np.empty(8)", "    _os = np.empty(8)"]
    for v in variables:
        so, to, s, d = v.storage_off, v.tangent_off, v.storage_dim, v.tangent_dim
        if v.retract_code is not None:  # declared manifold: its generated retract, inlined
            code = v.retract_code
            lines += [f"    {x} = _x[{so + k}]" for k, x in enumerate(code["x"])]
            lines += [f"    {x} = _d[{to + k}]" for k, x in enumerate(code["d"])]
            lines += [f"    {t} = {e}" for t, e in code["stmts"]]
            lines += [f"    _out[{so + k}] = {e}" for k, e in enumerate(code["out"])]
            continue
        if v.gid < 0:
            for k in range(s):
                lines.append(f"    _out[{so + k}] = _x[{so + k}] + _d[{to + k}]")
            continue
        lines += [f"    for _k in range({s}):", f"        _xs[_k] = _x[{so} + _k]",
                  f"    for _k in range({d}):", f"        _ds[_k] = _d[{to} + _k]",
                  f"    lie_retract(np.int64({v.gid}), _xs, _ds, _os, _tmp)",
                  f"    for _k in range({s}):", f"        _out[{so} + _k] = _os[_k]"]
    return "\n".join(lines)


def _table_source(name: str, code: tuple) -> str:
    """The instruction table as a Python literal, a few instructions per line."""
    lines = [f"{name} = ("]
    per = 8
    for i in range(0, len(code), per):
        lines.append("    " + " ".join(f"{ins!r}," for ins in code[i:i + per]))
    lines.append(")")
    return "\n".join(lines)


def module_source(variables: list, prog: Program, const_syms: set, header: dict) -> tuple:
    """Emit the module; returns ``(source, meta)``."""
    from ._llvm import count_instructions, to_instructions
    from ...symbolic._sym import EPSILON_VALUE
    from ...symbolic.printer import to_source

    cstmts, vstmts, hoisted = split_constant(prog, const_syms)
    N = sum(v.tangent_dim for v in variables)
    S = sum(v.storage_dim for v in variables)
    ops_lin = total_ops(Program(vstmts, prog.outputs))
    ops_pre = total_ops(Program(cstmts, {}))
    sp = _sym().sp

    # _precompute: raw constants / whitening -> constant statements -> hoisted values in _aux
    pre_in = {}
    used: set = set()
    for _, e in cstmts:
        used |= e.free_symbols
    used |= set(hoisted)
    for s in used:
        if s.name[:1] in ("c", "w") and s.name[1:].isdigit():
            pre_in[s] = (0 if s.name[0] == "c" else 1, _index_of(s))
    pre_code = to_instructions(cstmts, [(2, k, s) for k, s in enumerate(hoisted)], pre_in)
    # _linearize: x storage + _aux -> H (both triangles), g, cost
    lin_in = {sp.Symbol(f"x{v}_{k}", real=True): (0, var.storage_off + k)
              for v, var in enumerate(variables) for k in range(var.storage_dim)}
    lin_in.update({s: (1, k) for k, s in enumerate(hoisted)})
    stores, k = [], 0
    first = list(range(N))  # H's envelope: per row, its first structurally nonzero column
    for a in range(N):
        for b in range(a + 1):
            e = prog.outputs["H"][k]
            k += 1
            if e != 0:
                first[a] = min(first[a], b)
            stores.append((2, a * N + b, e))
            if a != b:
                stores.append((2, b * N + a, e))
    stores += [(3, a, prog.outputs["g"][a]) for a in range(N)]
    lin_code = to_instructions(vstmts, stores, lin_in, prog.outputs["cost"][0])
    counts = count_instructions(lin_code)

    # readable plain-Python twin of the linearization (documentation, tests)
    py = ["def linearize_py(_x, _aux, _H, _g):",
          '    """Plain-Python twin of the generated linearization (slow; for reading/tests)."""']
    py += [f"    {s.name} = {'_x' if a == 0 else '_aux'}[{i}]" for s, (a, i) in lin_in.items()]
    py += [f"    {s.name} = {to_source(e)}" for s, e in vstmts]
    for arr, idx, e in stores:
        target = "_H" if arr == 2 else "_g"
        tidx = f"{idx // N}, {idx % N}" if arr == 2 else f"{idx}"
        py.append(f"    {target}[{tidx}] = {to_source(e) if e != 0 else '0.0'}")
    py.append(f"    return {to_source(prog.outputs['cost'][0])}")

    meta = {"N": N, "S": S, "num_hoisted": len(hoisted), "ops_linearize": ops_lin,
            "ops_precompute": ops_pre, "num_statements": len(vstmts),
            "instructions_linearize": counts, "instructions_precompute":
            count_instructions(pre_code), **header}
    head = [
        "# " + "-" * 98,
        "# Autogenerated by fgopt.solvers.fixed (template: fgopt/solvers/fixed/_codegen.py).",
        f"# Fixed-structure linearization: {header.get('summary', '')}",
        f"# total ops (sympy.count_ops after CSE): linearize {ops_lin}, precompute {ops_pre}",
        "# The linearization is the instruction table _LIN_CODE, emitted as LLVM IR by",
        "# fgopt.solvers.fixed._llvm; linearize_py at the end is its readable Python twin.",
        "# Do NOT modify by hand.",
        "# " + "-" * 98,
        "# ruff: noqa",
        "# fmt: off",
        '"""Generated fixed-formulation problem (dense H, g and cost of the whole graph)."""',
        "",
        "import math",
        "",
        "import numba",
        "import numpy as np",
        "",
        "from fgopt.manifolds._kernels import lie_retract",
        "from fgopt.solvers.fixed._llvm import make_intrinsic",
        "",
        f"EPSILON = {EPSILON_VALUE!r}",
        f"N = {N}",
        f"S = {S}",
        f"NUM_AUX = {len(hoisted)}",
        f"_FIRST = np.array({first!r}, dtype=np.int64)",
        f"META = {meta!r}",
        "",
        _table_source("_PRE_CODE", pre_code),
        "",
        _table_source("_LIN_CODE", lin_code),
        "",
        '_pre = make_intrinsic(_PRE_CODE, 3, "fixed_precompute")',
        '_lin = make_intrinsic(_LIN_CODE, 4, "fixed_linearize")',
        "",
    ]
    src = ("\n".join(head) + "\n"
           + _FIXED_PROLOGUE.replace("{retract}", _retract_source(variables)) + "\n"
           + lm_source("N") + "\n\n" + "\n".join(py) + "\n")
    return src, meta
