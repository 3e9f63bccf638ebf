"""Residual + tangent-space Jacobian programs for code generation.

:func:`linearization_program` turns a function value and its arguments into a
:class:`~fgopt.symbolic.cse.Program` with outputs ``res`` (r entries) and ``jac`` (r x D,
row-major), optionally also ``hess`` (``J^T J``, D x D) and ``rhs`` (``J^T r``, D) as in the
SymForce paper's ``with_linearization`` (Sec. III-C).

Three differentiation engines compute the same tangent-space Jacobians (method
``"retraction"`` or ``"chain"``, see :mod:`fgopt.symbolic.jacobians`):

* ``"tree"``: SymPy differentiates the whole flattened expression (what SymForce does), then
  CSE. Best code for small functions; SymPy's tree traversals make it slow (tens of seconds)
  for large ones such as an SE(3) log.
* ``"dag"``: first CSE the *value* into a straight-line program, then propagate directional
  derivatives through it statement by statement (forward mode on the CSE DAG), each step a
  small SymPy ``diff``; a final global CSE merges everything. The seeds are the columns of
  ``storage_D_tangent`` (first-order retraction) or storage unit vectors followed by a product
  with ``storage_D_tangent`` (chain rule). Derivation time is linear in the program size.
* ``"reverse"``: vector reverse mode on the same program (adjoints of all residual entries),
  then ``(d res / d storage) storage_D_tangent``; shorter when the residual has fewer entries
  than there are tangent directions and little Lie structure (e.g. BAL: 291 vs 367 ops).

``"auto"`` (default) uses ``"tree"`` for small algebraic functions (no transcendental
functions or roots, at most :data:`TREE_MAX_OPS` operations in the flattened value), where
SymPy's whole-expression simplification gives the shortest code (e.g. ``pose.inverse() *
point``: 162 vs 273 ops); otherwise it derives with both ``"dag"`` and ``"reverse"`` and keeps
the program with fewer operations (the tree engine would take e.g. 26 s and 1357 ops for the
SE(3) prior, vs 0.6 s and 784 ops with ``"dag"``) (each takes about a second; numba's compile time grows with the
op count, about 3 ms per operation).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from .cse import Program, count_ops, optimize, temp_symbols, total_ops
from .jacobians import METHODS, output_storage, tangent_jacobians
from .ops import has_own_tangent, storage_D_tangent_of, storage_of, tangent_D_storage_of

ENGINES = ("auto", "tree", "dag", "reverse")
#: "auto" differentiates whole algebraic expression trees up to this many operations.
TREE_MAX_OPS = 400


def _s():
    from . import _sym

    return _sym


def linearization_program(output: Any, args: Sequence[Any], method: str = "retraction",
                          engine: str = "auto", hessian: bool = False,
                          value: Program | None = None) -> Program:
    """Program computing ``res`` and ``jac`` (and ``hess``/``rhs`` if ``hessian``).

    Args:
        output: the function value (vector, scalar, sequence, or a Lie group element, whose
            Jacobian is then taken in its tangent space).
        args: symbolic values (storage = distinct symbols) to differentiate by, in column order.
        method: ``"retraction"`` or ``"chain"``.
        engine: ``"auto"``, ``"tree"`` or ``"dag"``.
        hessian: also output ``J^T J`` (upper triangle and below, full) and ``J^T r``.
        value: ``optimize(Program([], {"res": output's storage}))`` if the caller has it.

    Example:

    >>> from fgopt.symbolic import V2, linearization_program
    >>> p = V2.symbolic("p")
    >>> linearization_program(p.squared_norm(), [p])
    Program(stmts=[], outputs={'res': [p_0**2 + p_1**2], 'jac': [2*p_0, 2*p_1]})
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    sp = _s().sp
    res = [_s().as_expr(e) for e in output_storage(output)]
    if engine == "auto" and _is_small_algebraic(res):
        engine = "tree"
    if engine != "tree" and value is None:
        value = optimize(Program([], {"res": res}))
    if engine == "tree":
        jacs = tangent_jacobians(output, args, method) if len(args) > 0 else []
        jac = sp.Matrix.hstack(*jacs) if len(jacs) > 0 else sp.zeros(len(res), 0)
        stmts, res_out = [], res
    elif engine == "auto":  # forward and reverse mode: keep the shorter program
        best = None
        for fn in (_dag_jacobian, _reverse_jacobian):
            cand = _finish(*fn(value, output, args, method), hessian)
            if best is None or total_ops(cand) < total_ops(best):
                best = cand
        return best
    elif engine == "dag":
        stmts, res_out, jac = _dag_jacobian(value, output, args, method)
    else:
        stmts, res_out, jac = _reverse_jacobian(value, output, args, method)
    return _finish(stmts, res_out, jac, hessian)


def _finish(stmts: list, res: list, jac: Any, hessian: bool) -> Program:
    prog = Program(list(stmts), {"res": list(res), "jac": list(jac)})
    if hessian:
        _add_hessian(prog, len(res), jac.shape[1])
    return optimize(prog)


def _is_small_algebraic(exprs: list) -> bool:
    """No function calls except ``sign_no_zero``, integer powers only, few operations."""
    sp = _s().sp
    seen: set = set()
    stack = list(exprs)
    while len(stack) > 0:
        node = stack.pop()
        if node in seen:
            continue
        seen.add(node)
        if len(seen) > 4 * TREE_MAX_OPS:
            return False
        if isinstance(node, sp.Function) and not isinstance(node, _s().SignNoZero):
            return False
        if node.is_Pow and not node.exp.is_Integer:
            return False
        stack.extend(node.args)
    return count_ops(exprs) <= TREE_MAX_OPS


def _add_hessian(prog: Program, r: int, dim: int) -> None:
    """Append ``hess = J^T J`` and ``rhs = J^T res`` (through temporaries, so CSE shares J)."""
    sp = _s().sp
    syms = temp_symbols("_lin")
    res_syms = [next(syms) for _ in range(r)]
    jac_syms = [next(syms) for _ in range(r * dim)]
    prog.stmts += list(zip(res_syms, prog.outputs["res"])) + list(zip(jac_syms, prog.outputs["jac"]))
    J = sp.Matrix(r, dim, jac_syms)
    e = sp.Matrix(res_syms)
    prog.outputs["res"] = list(res_syms)
    prog.outputs["jac"] = list(jac_syms)
    prog.outputs["hess"] = list(J.T * J)
    prog.outputs["rhs"] = list(J.T * e)


def _dag_jacobian(value: Program, output: Any, args: Sequence[Any], method: str):
    """Forward-mode propagation of tangent directions through the CSE'd value program."""
    sp = _s().sp
    remove = _s().remove_distributions
    seeds: dict = {}
    col_blocks = []  # (first direction, D) per argument, for the chain rule's final product
    ndir = 0
    for arg in args:
        s = storage_of(arg)
        D = storage_D_tangent_of(arg)
        if method == "retraction":
            for i, si in enumerate(s):
                seeds[si] = {ndir + j: D[i, j] for j in range(D.shape[1]) if D[i, j] != 0}
            col_blocks.append((ndir, D.shape[1]))
            ndir += D.shape[1]
        else:
            for i, si in enumerate(s):
                seeds[si] = {ndir + i: sp.S.One}
            col_blocks.append((ndir, D))
            ndir += len(s)
    deriv = dict(seeds)
    stmts = []
    dsyms = temp_symbols("_dd")

    def directional(e):
        deps = [x for x in e.free_symbols if x in deriv]
        if len(deps) == 0:
            return {}
        partials = [(x, remove(e.diff(x))) for x in deps]
        acc: dict = {}
        for x, p in partials:
            if p == 0:
                continue
            for j, dxj in deriv[x].items():
                acc.setdefault(j, []).append(p * dxj)
        return {j: sp.Add(*terms) for j, terms in acc.items()}

    for t, e in value.stmts:
        stmts.append((t, e))
        d = {}
        for j, de in directional(e).items():
            if de == 0:
                continue
            if de.is_Atom:
                d[j] = de
            else:
                sym = next(dsyms)
                stmts.append((sym, de))
                d[j] = sym
        if len(d) > 0:
            deriv[t] = d
    res = value.outputs["res"]
    rows = [directional(e) for e in res]
    J = sp.Matrix(len(res), ndir, lambda i, j: rows[i].get(j, sp.S.Zero))
    if method == "chain":
        blocks = [J[:, start:start + D.shape[0]] * D for start, D in col_blocks]
        J = sp.Matrix.hstack(*blocks) if len(blocks) > 0 else sp.zeros(len(res), 0)
    if has_own_tangent(output):
        J = tangent_D_storage_of(type(output).from_storage(res)) * J
    return stmts, res, J


def _reverse_jacobian(value: Program, output: Any, args: Sequence[Any], method: str):
    """Vector reverse mode: adjoints of all outputs propagated back through the value program.

    Gives ``d res / d storage`` for every argument, then ``J = (d res / d s) D`` per argument
    (``D = storage_D_tangent``; the first-order retraction and the chain rule coincide here).
    Fewer operations than forward mode when the residual has fewer entries than tangent
    directions.
    """
    sp = _s().sp
    remove = _s().remove_distributions
    res = value.outputs["res"]
    nres = len(res)
    storages = [storage_of(arg) for arg in args]
    active = {s for st in storages for s in st}
    for t, e in value.stmts:  # temporaries that depend on a differentiated argument
        if any(x in active for x in e.free_symbols):
            active.add(t)
    adj: dict = {}

    def push(e, seeds: dict) -> None:
        """Add ``d e / d x * seed_r`` to ``adj[x][r]`` for the active symbols x of e."""
        for x in e.free_symbols:
            if x not in active:
                continue
            p = remove(e.diff(x))
            if p == 0:
                continue
            slot = adj.setdefault(x, {})
            for r, seed in seeds.items():
                slot.setdefault(r, []).append(p * seed)

    for r, e in enumerate(res):
        push(e, {r: sp.S.One})
    stmts = list(value.stmts)
    asyms = temp_symbols("_adj")

    def finalize(x) -> dict:
        out = {}
        for r, terms in adj.pop(x, {}).items():
            a = sp.Add(*terms)
            if a == 0:
                continue
            if not a.is_Atom:
                sym = next(asyms)
                stmts.append((sym, a))
                a = sym
            out[r] = a
        return out

    for t, e in reversed(value.stmts):
        if t in adj:
            push(e, finalize(t))
    blocks = []
    for arg, st in zip(args, storages):
        G = sp.zeros(nres, len(st))
        for k, s in enumerate(st):
            for r, a in finalize(s).items():
                G[r, k] = a
        blocks.append(G * storage_D_tangent_of(arg))
    J = sp.Matrix.hstack(*blocks) if len(blocks) > 0 else sp.zeros(nres, 0)
    if has_own_tangent(output):
        J = tangent_D_storage_of(type(output).from_storage(res)) * J
    return stmts, res, J
